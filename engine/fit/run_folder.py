"""The run folder: the one module that knows its layout and reads and writes its files.

A fit writes ``config.json`` (the config), ``clip.json`` (what was fitted: ``ClipRecord``), ``scene.json`` (the
scene analysis), ``checkpoint.pt``, ``metrics.json`` and ``fit.log`` into RUN_DIR; ``fit --resume``, ``export``,
the demo and the bench read them back through ``RunFolder``. Every JSON file is checked against its versioned
schema (``run_files.validate_run_file``) when it is read and before it is written; a file that
does not follow it is a one-line ``InputError`` naming the file and the fix. Every file is written atomically
(temp file + rename); the checkpoint is checked against the clip record and the config it was saved with.
A writer holds the folder's lock (``RunFolder.lock``) for its whole write.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

import torch

from .. import contract as C
from ..config import LATER_FIELDS, RESUMABLE_FIELDS, START_FIELDS, FitConfig, same_phases
from ..data.scene_analysis import SceneAnalysis
from ..errors import InputError
from ..io.atomic import atomic_write_text
from ..io.clip_info import NumberedFrames
from ..terms.export_names import EDITS_DIR
from ..terms.run_folder import (
    AUTO_PARTS_DIR,
    FLOW_CACHE_DIR,
    RUN_CHECKPOINT_KEYS,
    RUN_CHECKPOINT_SCHEMA,
    RUN_CHECKPOINT_SCHEMA_WITHOUT_CONFIG,
    RUN_CLIP,
    RUN_CLIP_SCHEMA,
    RUN_CONFIG,
    RUN_FILE_DAMAGED_FIX,
    RUN_FILE_OTHER_VERSION_FIX,
    RUN_LOG,
    RUN_METRICS_SCHEMA,
    SCENE_FILE,
)
from .checkpoint import CHECKPOINT_DAMAGED_FIX, load_checkpoint, nonfinite_entries, save_checkpoint
from .run_files import RunFileError, validate_run_file

#: The fix for a checkpoint that does not belong with the run folder's other files.
FOREIGN_CHECKPOINT_FIX = "copy back this run's own checkpoint, or fit again with --refit (edits and exports are kept)"


@dataclass(frozen=True)
class ClipRecord(NumberedFrames):
    """``clip.json``: what was fitted, and everything a reader of the run needs of the clip without decoding
    it (export: the native and working sizes, the frames and their numbers, the layers)."""

    source: str
    kind: str
    frame_range: tuple[int, int]
    frame_numbers: tuple[int, ...]
    frame_files: tuple[str, ...]
    native_size: tuple[int, int]
    working_size: tuple[int, int]
    fps: float | None
    colorspace: str
    masks: tuple[str, ...]
    scribbles: str | None
    layers: int
    fingerprint: str
    colour_config: str | None = None
    """The OCIO config naming ``colorspace``; None in runs made before colour management (legacy "sRGB"/"linear")."""
    rate: tuple[int, int] | None = None
    """The plate's exact frame rate (num, den); None: none stated (and in records written before it was kept)."""
    pixel_aspect: float = 1.0
    timecode: str | None = None
    """SMPTE timecode of the first fitted frame."""
    start_frame: int = 0
    """A movie's number of its first frame (``fit --start-frame``)."""
    colour_source: str | None = dataclasses.field(default=None, compare=False)
    """How ``colorspace`` was decided (``terms.colour.COLOUR_SOURCES``; "assumed": nothing in the file said it); None in
    records written before it was kept."""
    source_relative: str | None = dataclasses.field(default=None, compare=False)
    """``source`` relative to the run folder ("/" separated; None where there is none, another drive): a run folder
    moved or mounted elsewhere together with its plate finds it there (``located``). The same for the frame files,
    the masks and the scribbles; all None in records written before they were kept. The same paths in another
    form: records that differ only in them are equal."""
    frame_files_relative: tuple[str | None, ...] | None = dataclasses.field(default=None, compare=False)
    masks_relative: tuple[str | None, ...] | None = dataclasses.field(default=None, compare=False)
    scribbles_relative: str | None = dataclasses.field(default=None, compare=False)
    scribbles_fingerprint: str | None = None
    """The fingerprint of the strokes the fit split its object by (``scribbles``, read at the working size): a resume
    continues on the same strokes; None without scribbles, and in records written before it was kept."""
    flow_key: str | None = None
    """The key of the adjacent-pair flow the fit learnt from in ``RUN_DIR/flow_cache`` (``flow.FlowField.key``): the
    export follows that flow and no other; None in records written before it was kept, and for a single frame."""

    @property
    def exact_rate(self) -> Fraction | None:
        """``rate`` as the fraction ``open_clip(fps=...)`` takes (None: none recorded)."""
        return None if self.rate is None else Fraction(*self.rate)

    @property
    def movie_start(self) -> int | None:
        """The number a movie's frames were counted from, as ``open_clip(start_frame=...)`` takes it; None for a
        sequence (its frames are numbered by their file names, and ``open_clip`` refuses a start frame for it)."""
        return self.start_frame if self.kind == C.CLIP_KINDS[1] else None

    def relative_to(self, run_dir: str | Path) -> ClipRecord:
        """This record with its paths also relative to ``run_dir`` (what ``RunFolder.write_clip`` records)."""
        return dataclasses.replace(
            self,
            source_relative=_relative(self.source, run_dir),
            frame_files_relative=tuple(_relative(f, run_dir) for f in self.frame_files),
            masks_relative=tuple(_relative(m, run_dir) for m in self.masks),
            scribbles_relative=None if self.scribbles is None else _relative(self.scribbles, run_dir),
        )

    def located(self, run_dir: str | Path) -> ClipRecord:
        """This record with each path where it is now (``_locate``): its relative form resolved against where the
        run folder ``run_dir`` is now when the run folder moved or was copied with it, else as given
        (``missing_input`` names what is missing)."""
        ff = self.frame_files_relative or (None,) * len(self.frame_files)
        mr = self.masks_relative or (None,) * len(self.masks)
        source = _locate(self.source, self.source_relative, run_dir)
        if source != self.source:  # the plate's frames go where the plate went: one plate, never a mix of two
            frames = tuple(_relocated(f, r, run_dir) for f, r in zip(self.frame_files, ff, strict=False))
        else:  # the plate stayed: a frame moves to its relative place only where it is missing
            frames = tuple(
                f if _exists(f) else _locate(f, r, run_dir) for f, r in zip(self.frame_files, ff, strict=False)
            )
        return dataclasses.replace(
            self,
            source=source,
            frame_files=frames,
            masks=tuple(_locate(m, r, run_dir) for m, r in zip(self.masks, mr, strict=False)),
            scribbles=None if self.scribbles is None else _locate(self.scribbles, self.scribbles_relative, run_dir),
        )

    def missing_input(self, run_dir: str | Path) -> InputError | None:
        """The one line for a located record whose plate, a mask folder or the scribbles are neither where they were
        given nor where they were relative to the run folder (None when all are there): it names the path and the
        ways to remap it."""
        masks_relative = self.masks_relative or (None,) * len(self.masks)
        inputs = [("plate", self.source, self.source_relative)]
        inputs += [("mask folder", m, r) for m, r in zip(self.masks, masks_relative, strict=False)]
        if self.scribbles is not None:
            inputs.append(("scribbles folder", self.scribbles, self.scribbles_relative))
        for what, path, rel in inputs:
            if not _exists(path):
                beside = "" if rel is None else f" or the run folder where the {what} is at {rel} from it,"
                return InputError(
                    path,
                    f"the {what} this run fitted is not here, nor where it was relative to the run folder",
                    f"move the {what} to this path,{beside} or mount the storage at the path it was fitted from",
                )
        return None

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        for key, value in data.items():
            if isinstance(value, tuple):
                data[key] = list(value)
        if data["colour_config"] is None:
            del data["colour_config"]
        if data["colour_source"] is None:
            del data["colour_source"]
        for key in ("flow_key", "scribbles_fingerprint"):
            if data[key] is None:
                del data[key]
        if self.frame_files_relative is None:  # a record from before the relative paths were kept
            for key in RELATIVE_FIELDS:
                del data[key]
        return {"schema": RUN_CLIP_SCHEMA, **data}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ClipRecord:
        """From a record that passed ``run_files.validate_run_file`` (``ClipFile``, which declares the same fields:
        ``tests/engine/fit/test_record_declarations.py``): each of its lists as a tuple; a field it lacks (a record
        written before the field was kept) takes its default here."""
        return cls(**{f.name: _tuple_of(data[f.name]) for f in dataclasses.fields(cls) if f.name in data})


def _tuple_of(value: Any) -> Any:
    """A JSON list as a tuple (the record is frozen and compared by value); anything else as it is."""
    return tuple(value) if isinstance(value, list) else value


#: clip.json's fields that say the paths relative to the run folder (``ClipRecord.located``).
RELATIVE_FIELDS = ("source_relative", "frame_files_relative", "masks_relative", "scribbles_relative")


def _relative(path: str, run_dir: str | Path) -> str | None:
    """``path`` relative to the run folder, "/" separated, without resolving symlinks (a plate folder linked beside
    the run folder moves with it); None where there is no relative path (another Windows drive)."""
    try:
        return os.path.relpath(os.path.abspath(path), os.path.abspath(run_dir)).replace(os.sep, "/")
    except ValueError:
        return None


def _exists(path: str) -> bool:
    """Whether ``path`` is there: a file or folder, or a sequence pattern's folder (plate.####.exr)."""
    from ..io.clip import is_sequence_pattern

    return os.path.exists(path) or (is_sequence_pattern(path) and os.path.isdir(os.path.dirname(path) or "."))


#: Bytes of a file compared to tell a copy of an input from another input (``_same_input``).
SAME_INPUT_BYTES = 1 << 16


def _locate(given: str, relative: str | None, run_dir: str | Path) -> str:
    """Where an input of the run is now. ``relative`` resolved against the run folder when the run folder is no
    longer where it was fitted and that place holds the input: where only it exists (moved or mounted elsewhere
    with its plate), or where both do and it is a copy of the input (a shot folder copied whole keeps to its own
    plate and masks, so a refine there never reaches back to the original). Else ``given``."""
    if relative is None:
        return given
    here = os.path.normpath(os.path.join(os.path.abspath(run_dir), relative))
    if here == os.path.normpath(os.path.abspath(given)) or not _exists(here):
        return given
    if not _exists(given) or _same_input(given, here):
        return here
    return given  # another input at the same place relative to the run: the run was copied beside it, not with it


def _relocated(given: str, relative: str | None, run_dir: str | Path) -> str:
    """``relative`` resolved against the run folder (``given`` when there is no relative form)."""
    return given if relative is None else os.path.normpath(os.path.join(os.path.abspath(run_dir), relative))


def _same_input(a: str, b: str) -> bool:
    """Whether ``b`` looks like a copy of ``a``: the same file names in a folder (a sequence pattern: its folder)
    and, for the first file, the same size and first SAME_INPUT_BYTES bytes. Cheap, and enough to tell a copied
    plate from another shot's: anything more is the fingerprint's job on a resume."""
    from ..io.clip import is_sequence_pattern

    if is_sequence_pattern(a) and is_sequence_pattern(b):
        a, b = os.path.dirname(a) or ".", os.path.dirname(b) or "."
    if os.path.isdir(a) != os.path.isdir(b):
        return False
    if os.path.isdir(a):
        try:
            names_a, names_b = sorted(os.listdir(a)), sorted(os.listdir(b))
        except OSError:
            return False
        files = [n for n in names_a if os.path.isfile(os.path.join(a, n))]
        if names_a != names_b or not files:
            return names_a == names_b
        a, b = os.path.join(a, files[0]), os.path.join(b, files[0])
    try:
        if os.path.getsize(a) != os.path.getsize(b):
            return False
        with open(a, "rb") as fa, open(b, "rb") as fb:
            return fa.read(SAME_INPUT_BYTES) == fb.read(SAME_INPUT_BYTES)
    except OSError:
        return False


def _entry(name: str) -> property:
    """A path inside the run folder (read-only)."""
    return property(lambda self: self.path / name)


class RunFolder:
    """RUN_DIR: its files' paths, and their reading (validated) and writing (validated, atomic)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    # --- layout: each entry's name is the contract's
    config = _entry(RUN_CONFIG)
    clip = _entry(RUN_CLIP)
    metrics = _entry(C.RUN_METRICS)
    scene = _entry(SCENE_FILE)
    checkpoint = _entry(C.RUN_CHECKPOINT)
    log = _entry(RUN_LOG)
    flow_cache = _entry(FLOW_CACHE_DIR)
    auto_masks = _entry(C.AUTO_MASKS_DIR)
    auto_parts = _entry(AUTO_PARTS_DIR)
    exports = _entry(C.EXPORTS_DIR)
    edits = _entry(EDITS_DIR)

    # --- the lock
    @contextlib.contextmanager
    def lock(self, what: str) -> Iterator[None]:
        """Hold this folder's exclusive lock (``contract.run_lock``) for the ``with`` block, creating the folder:
        every writer of a run folder (fit, export, project-frame, preview) holds it for its whole write, and a
        second one is refused at once with one line (``contract.RunLocked``) naming the holder ``what``."""
        with C.run_lock(self.path, what):
            yield

    # --- checks
    def fit_contents(self) -> list[str]:
        """What of a fit this folder holds, by name: its checkpoint, its metrics, and its edits/ and exports/
        folders when they hold anything (the artist's paint and the exports made from the fit). A folder with
        only config, clip record, scene analysis and flow cache (a fit stopped before its first checkpoint)
        holds none: a plain ``fit`` may start it over."""
        held = [p.name for p in (self.checkpoint, self.metrics) if p.exists()]
        return held + [f"{p.name}/" for p in (self.edits, self.exports) if _has_entries(p)]

    def refuse_plain_fit(self) -> None:
        """One line when this folder holds a fit (``fit_contents``): it names what, and the ways out."""
        held = self.fit_contents()
        if held:
            raise InputError(
                self.path,
                f"this folder already holds a fit ({', '.join(held)})",
                "pass --resume to continue it, --refit to fit it again (edits/ and exports/ are kept), "
                "or choose a new --out",
            )

    def clear_fit(self) -> None:
        """Before a --refit writes its own files: the earlier fit's metrics and checkpoint go (first the metrics,
        so no moment shows a finished fit without its checkpoint); edits/ and exports/ stay as they are."""
        for path in (self.metrics, self.checkpoint):
            path.unlink(missing_ok=True)

    def require_fit(self) -> None:
        """One-line error unless this is the folder of a fit that checkpointed (what export reads)."""
        for path in (self.config, self.clip, self.checkpoint):
            if not path.exists():
                raise InputError(path, "this is not a fitted run folder", "pass the --out folder of a `fit`")

    def own_folder(self, folder: Path, what: str) -> Path:
        """``folder`` (an entry the engine finds things in and writes into: ``auto_masks/``, ``parts/``), refused in
        one line when it is a symbolic link: unlike the run folder itself, ``exports/`` and ``edits/``, which the user
        may link to another disk, these are the engine's own, and a link planted there would take its files out of
        the run folder."""
        if folder.is_symlink():
            raise InputError(
                folder,
                f"is a symbolic link, and the run folder's {folder.name}/ is the engine's own (never written through a "
                "link)",
                f"delete the link (move any {what} you want used into a real folder there), then run the fit again",
            )
        return folder

    def check_writable(self) -> None:
        """One-line error if the folder (or the nearest folder that exists above it) cannot be written."""
        probe = self.path
        while not probe.exists() and probe != probe.parent:
            probe = probe.parent
        if not (probe.is_dir() and os.access(probe, os.W_OK | os.X_OK)):
            raise InputError(self.path, "output folder is not writable", "choose a folder you can write to with --out")

    # --- config.json
    def read_config(self) -> FitConfig:
        """The run's config: its schema, every field's type and range checked (``FitConfig.from_json``)."""
        text = self._read_text(self.config, "no fit to resume here", "run `fit` without --resume first")
        self._validated(self.config, text)
        return FitConfig.from_json(text, self.config)

    def write_config(self, cfg: FitConfig) -> None:
        text = cfg.to_json()
        self._validated(self.config, text)
        atomic_write_text(self.config, text)

    # --- clip.json
    def read_clip(self) -> ClipRecord:
        """The clip record, its paths located (``ClipRecord.located``): where the plate, masks and scribbles are now,
        also when the run folder was moved or mounted elsewhere together with them."""
        text = self._read_text(
            self.clip, "this run folder has no record of its clip", "resume a folder written by `fit`"
        )
        return ClipRecord.from_dict(self._validated(self.clip, text)).located(self.path)

    def write_clip(self, record: ClipRecord) -> None:
        """``record``, its paths recorded as given and relative to this folder."""
        self._write_json(self.clip, record.relative_to(self.path).to_dict())

    # --- metrics.json
    def read_metrics(self) -> dict[str, Any] | None:
        """The finished fit's metrics; None while the fit has not finished."""
        if not self.metrics.exists():
            return None
        return self._validated(self.metrics, self._read_text(self.metrics, "no metrics", "let the fit finish"))

    def write_metrics(self, metrics: dict[str, Any]) -> None:
        self._write_json(self.metrics, {"schema": RUN_METRICS_SCHEMA, **metrics})

    # --- scene.json
    def read_scene(self, record: ClipRecord | None = None) -> SceneAnalysis:
        """The run's scene analysis (every fit writes it before its first step), checked against its schema and,
        given the run's clip ``record``, against its layer count (both files must be of the same fit)."""
        text = self._read_text(self.scene, "the run has no scene analysis", "restore it or fit into a new --out")
        scene = SceneAnalysis.from_dict(self._validated(self.scene, text))
        if record is not None and scene.num_layers != record.layers:
            problem = f"scene analysis has {scene.num_layers} layers but {RUN_CLIP} records {record.layers}"
            raise InputError(self.scene, problem, RUN_FILE_DAMAGED_FIX)
        return scene

    def write_scene(self, scene: SceneAnalysis) -> None:
        self._write_json(self.scene, scene.to_dict())

    # --- checkpoint.pt
    def load_checkpoint(self, device: torch.device) -> dict[str, Any]:
        """The checkpoint, loaded safely (weights only), with every key of its schema and the types a resume and
        an export read from it; a checkpoint of another engine version or a damaged one is one line."""
        state = load_checkpoint(self.checkpoint, device)
        old = isinstance(state, dict) and state.get("schema") == RUN_CHECKPOINT_SCHEMA_WITHOUT_CONFIG
        if old and "config" not in state:
            # a fit from before checkpoints recorded their config: the fingerprint still ties it to its clip
            state = {**state, "schema": RUN_CHECKPOINT_SCHEMA, "config": None}
        missing = [k for k in RUN_CHECKPOINT_KEYS if k not in state] if isinstance(state, dict) else ["schema"]
        if missing:
            raise InputError(self.checkpoint, f"checkpoint has no {missing[0]!r}", RUN_FILE_OTHER_VERSION_FIX)
        if state["schema"] != RUN_CHECKPOINT_SCHEMA:
            problem = (
                f"checkpoint schema {state['schema']!r} is not supported (this engine writes {RUN_CHECKPOINT_SCHEMA})"
            )
            raise InputError(self.checkpoint, problem, RUN_FILE_OTHER_VERSION_FIX)
        kinds = {"model": dict, "optim": dict, "sched": dict, "gen": torch.Tensor, "fingerprint": str}
        kinds["config"] = (dict, type(None))  # None: a checkpoint of the schema without it
        kinds |= {"step": int, "train_seconds": (int, float), "motions": (list, type(None))}
        for key, kind in kinds.items():
            if not isinstance(state[key], kind) or isinstance(state[key], bool):
                raise InputError(self.checkpoint, f"checkpoint {key!r} is damaged", CHECKPOINT_DAMAGED_FIX)
        bad = nonfinite_entries(state)
        if bad:
            raise InputError(self.checkpoint, f"checkpoint holds NaN/Inf values ({bad[0]})", CHECKPOINT_DAMAGED_FIX)
        return state

    def save_checkpoint(self, state: dict[str, Any]) -> None:
        save_checkpoint(self.checkpoint, {"schema": RUN_CHECKPOINT_SCHEMA, **state})

    def check_checkpoint_belongs(self, state: dict[str, Any], cfg: FitConfig, record: ClipRecord) -> None:
        """One line unless the checkpoint ``state`` was saved by this folder's fit: the clip it fitted (its
        fingerprint in clip.json) and every field of config.json that decides what the loaded model computes
        (``RESUMABLE_FIELDS`` may differ: a resume records its new schedule in config.json before the next
        checkpoint; ``START_FIELDS`` too: the checkpoint carries what they decided; a loss phase that lasts the whole
        fit in both, ``same_phases``: a refine carries it to its new last step)."""
        if state["fingerprint"] != record.fingerprint:
            raise InputError(
                self.checkpoint,
                f"checkpoint is of another clip than {RUN_CLIP} records (fingerprint {state['fingerprint']!r}, "
                f"not {record.fingerprint!r})",
                FOREIGN_CHECKPOINT_FIX,
            )
        saved = state["config"]
        if saved is None:  # a checkpoint of the schema that did not record its config: config.json is its config
            return
        ours = dataclasses.asdict(cfg)
        free = (*RESUMABLE_FIELDS, *START_FIELDS)
        # a field the checkpoint predates (LATER_FIELDS): it was fitted with the value that reproduces the old engine
        missing = object()
        theirs = {k: saved.get(k, LATER_FIELDS.get(k, missing)) for k in ours}
        differ = [k for k in ours if k not in free and theirs[k] != ours[k] and not same_phases(theirs, ours, k)]
        if differ:
            raise InputError(
                self.checkpoint,
                f"checkpoint was saved with another config than {RUN_CONFIG} ({differ[0]} "
                f"{saved.get(differ[0])!r}, not {ours[differ[0]]!r})",
                FOREIGN_CHECKPOINT_FIX,
            )

    # --- helpers
    @staticmethod
    def _read_text(path: Path, missing_problem: str, missing_fix: str) -> str:
        try:
            return path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise InputError(path, missing_problem, missing_fix) from None
        except UnicodeDecodeError:
            raise InputError(path, "not a text file", RUN_FILE_DAMAGED_FIX) from None
        except OSError as exc:
            raise InputError(path, f"cannot be read ({exc.strerror or type(exc).__name__})", "check it") from None

    @staticmethod
    def _validated(path: Path, text: str) -> dict[str, Any]:
        try:
            return validate_run_file(path.name, json.loads(text))
        except (json.JSONDecodeError, RecursionError):
            raise InputError(path, "not valid JSON", RUN_FILE_DAMAGED_FIX) from None
        except RunFileError as exc:
            raise InputError(path, exc.problem, exc.fix) from None

    @staticmethod
    def _write_json(path: Path, data: dict[str, Any]) -> None:
        text = json.dumps(data, indent=2)
        RunFolder._validated(path, text)
        atomic_write_text(path, text)


def _has_entries(folder: Path) -> bool:
    """Whether ``folder`` holds anything but hidden bookkeeping (a dead export's ``.vNNN.partial``)."""
    try:
        return any(not entry.name.startswith(".") for entry in folder.iterdir())
    except (FileNotFoundError, NotADirectoryError):
        return False


__all__ = ["ClipRecord", "RunFolder"]
