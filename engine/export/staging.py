"""Where an export is assembled until it is complete, and the folders it is published as.

Each export goes to a new versioned folder (``exports/v001``, ``v002``, ...), assembled under a hidden name and
renamed into place when complete (new edit layers with it), so an earlier export is never touched and a killed
export leaves nothing a compositor could mistake for a result (``ExportOutput``). A staged export (``--into vNNN
--stage ...``) is assembled in ``exports/.vNNN.chunks`` by stages that run at different times on different hosts;
what each of them checks there first (the folder is the engine's own, made from this fit, not published yet) is
here too.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from pathlib import Path

from .. import contract as C
from ..errors import InputError
from ..fit.run_folder import RunFolder
from ..io.atomic import move_into_place, signals_held
from ..terms.cli import EXPORT_INTO_ARG, EXPORT_STAGE_ARG, EXPORT_STAGES
from ..terms.export_names import ATLASES_DIR, EXPORT_CHUNKS_SUFFIX, EXPORT_VERSION_FORMAT, NUKE_SCRIPT_NAME, PASSES_DIR
from .pass_files import PASS_BYTES_PER_CHANNEL, PASS_CHANNELS_PER_LAYER
from .plan import selected_frames
from .stage_record import STAGE_RECORD, StageFile, changed_since, fit_source, other_fit_error

#: An export is staged in ``exports/.vNNN.partial`` until it is renamed into place; the new files of ``edits/`` (a
#: new edit layer, the layout) wait in its ``.edits`` folder.
STAGING_SUFFIX = ".partial"
STAGED_EDITS = ".edits"
#: A staged export (``export --into vNNN --stage ...``) is assembled in ``exports/.vNNN.chunks``: its atlases, the
#: passes its chunks write (no lock: several hosts at once) and its record (``STAGE_RECORD``: frames, atlas size,
#: each layer's atlas frame, the fit it was made from: ``engine.export.stage_record``), until ``--stage publish``
#: renames it to ``vNNN``. A whole export never removes it and never takes its number.
CHUNKS_SUFFIX = EXPORT_CHUNKS_SUFFIX


#: In a staged export's folder: the flow-following UV correction of each layer that has one
#: (``<layer index>.npy``, float32 [frames, working height, working width, 2]), made by the atlases stage and read
#: by every passes chunk, so their passes are a whole export's; removed when the version is published.
FOLLOW_FLOW_DIR = "follow_flow"


def _next_version(exports: Path) -> tuple[Path, Path]:
    """The next free ``vNNN`` and its hidden staging folder (created). Called under the run folder's lock, so any
    staging folder already there is a killed export's leftover: it is removed first. A number a staged export holds
    (``.vNNN.chunks``, whose passes other hosts may be writing without the lock) is never taken, nor its folder
    removed."""
    exports.mkdir(parents=True, exist_ok=True)
    for leftover in exports.glob(f".*{STAGING_SUFFIX}"):
        _remove_leftover(leftover)
    final = exports / EXPORT_VERSION_FORMAT.format(_first_free(exports))
    return final, _fresh_staging(exports, final.name)


def _first_free(exports: Path) -> int:
    """The lowest version number neither published nor held by a staged export."""
    n = 1
    while _taken(exports, EXPORT_VERSION_FORMAT.format(n)):
        n += 1
    return n


def _remove_leftover(path: Path) -> None:
    """Remove a killed export's hidden staging entry: a symbolic link planted under its name is removed itself (never
    the folder it points to, which rmtree would refuse and the next mkdir trip over)."""
    if path.is_symlink() or not path.is_dir():
        path.unlink(missing_ok=True)
    else:
        shutil.rmtree(path, ignore_errors=True)


def _taken(exports: Path, version: str) -> bool:
    """Whether ``version`` is published, or held by a staged export."""
    return (exports / version).exists() or chunks_folder(exports, version).exists()


def _fresh_staging(exports: Path, version: str) -> Path:
    """``exports/.vNNN.partial``, created empty (a killed export's leftover of that name is removed first)."""
    exports.mkdir(parents=True, exist_ok=True)
    staging = exports / f".{version}{STAGING_SUFFIX}"
    _remove_leftover(staging)
    staging.mkdir()
    return staging


def chunks_folder(exports: Path, version: str) -> Path:
    """The hidden folder a staged export (``--into vNNN --stage ...``) is assembled in until it is published."""
    return exports / f".{version}{CHUNKS_SUFFIX}"


def export_version(text: str) -> str:
    """``--into``'s version name, checked: ``v001``, ``v002``, ... (``terms.export_names.EXPORT_VERSION_FORMAT``)."""
    digits = text[1:]
    if text[:1] == "v" and digits.isdigit() and int(digits) > 0 and EXPORT_VERSION_FORMAT.format(int(digits)) == text:
        return text
    raise InputError(
        None,
        f"{EXPORT_INTO_ARG} {text!r} is not an export version",
        f"name it as the exports are named: {EXPORT_VERSION_FORMAT.format(1)}, {EXPORT_VERSION_FORMAT.format(2)}, ...",
    )


class ExportOutput:
    """What one export writes: its hidden staging folder under ``exports/``, holding the new edit layer files and
    layout too. ``publish`` moves them all into place (signals held); ``discard`` removes whatever was made (and the
    ``exports``/``edits`` folders when this export created them). A staged export's folder (``keep_staging``) is
    kept by ``discard``: its chunks' passes stay for the next publish."""

    def __init__(
        self, run: RunFolder, native_size: tuple[int, int], layers: int, frames: int, keep_staging: bool = False
    ) -> None:
        self.run = run
        self.made_exports = not run.exports.exists()
        self.made_edits = not run.edits.exists()
        self.staging: Path | None = None
        self.final: Path | None = None
        self.keep_staging = keep_staging
        self.edits: list[tuple[Path, Path]] = []  # (staged file, final name)
        self.frames = frames
        self.pass_bytes: list[int] = []
        w, h = native_size
        self.pass_estimate = w * h * layers * PASS_CHANNELS_PER_LAYER * PASS_BYTES_PER_CHANNEL

    def begin(self, version: str | None = None) -> tuple[Path, Path]:
        """The staging folder of the next free version, or of ``version``. Signals are held while it is made, so a
        cancel can never fall between the folder's creation and ``discard`` knowing of it."""
        with signals_held():
            if version is None:
                self.final, self.staging = _next_version(self.run.exports)
            else:
                self.final, self.staging = self.run.exports / version, _fresh_staging(self.run.exports, version)
        return self.final, self.staging

    def stage_edit(self, path: Path) -> Path:
        """Where to write the new file ``path`` of ``edits/`` (in the staging folder) until ``publish`` moves it
        into place: nothing appears in ``edits/`` before the export is complete."""
        assert self.staging is not None
        staged = self.staging / STAGED_EDITS / path.name
        staged.parent.mkdir(exist_ok=True)
        self.edits.append((staged, path))
        return staged

    def pass_written(self, path: Path) -> None:
        self.pass_bytes.append(path.stat().st_size)

    def need(self) -> int:
        """Bytes the whole export needs: what it has staged, plus the passes still to write at the average size of
        those written (their uncompressed size before any is)."""
        staged = 0
        if self.staging is not None and self.staging.exists():
            staged = sum(p.stat().st_size for p in self.staging.rglob("*") if p.is_file())
        per_pass = sum(self.pass_bytes) // len(self.pass_bytes) if self.pass_bytes else self.pass_estimate
        return staged + per_pass * (self.frames - len(self.pass_bytes))

    def publish(self) -> None:
        assert self.staging is not None and self.final is not None
        with signals_held():
            if self.edits:
                self.run.edits.mkdir(exist_ok=True)
            for staged, path in self.edits:
                move_into_place(staged, path)
            shutil.rmtree(self.staging / STAGED_EDITS, ignore_errors=True)
            (self.staging / STAGE_RECORD).unlink(missing_ok=True)
            shutil.rmtree(self.staging / FOLLOW_FLOW_DIR, ignore_errors=True)
            os.replace(self.staging, self.final)
            self.edits, self.staging = [], None

    def discard(self) -> None:
        if self.staging is not None:
            if self.keep_staging:
                shutil.rmtree(self.staging / STAGED_EDITS, ignore_errors=True)
                (self.staging / C.MANIFEST_NAME).unlink(missing_ok=True)
                (self.staging / NUKE_SCRIPT_NAME).unlink(missing_ok=True)
            else:
                shutil.rmtree(self.staging, ignore_errors=True)
        for folder, made in ((self.run.exports, self.made_exports), (self.run.edits, self.made_edits)):
            if made:
                with contextlib.suppress(OSError):
                    folder.rmdir()  # only when empty: nothing of the artist's is ever removed


def published_manifest(
    run_dir: Path, version: str, atlas_size: int | None, frames: tuple[int, int] | None, any_frames: bool = False
) -> Path | None:
    """The manifest of ``version`` when it is published with these frames (None: every fitted frame; any with
    ``any_frames``) and atlas size (None: any), so a retried task is done at once; None when it is not published; a
    one-line error when it is, with other parameters."""
    final = run_dir / C.EXPORTS_DIR / version
    manifest_path = final / C.MANIFEST_NAME
    if not final.exists():
        return None
    if not manifest_path.is_file():
        raise InputError(final, "is an export folder without its manifest", "export into another --into version")
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
        done_frames = [int(n) for n in manifest["passes"]["frames"]]
        done_size = max(max(int(s) for s in layer["atlas_size"]) for layer in manifest["layers"])
    except (OSError, ValueError, KeyError, TypeError):
        raise InputError(manifest_path, "is not a manifest this engine wrote", "export into another version") from None
    clip = RunFolder(run_dir).read_clip()
    wanted = done_frames if any_frames else [clip.frame_numbers[t] for t in selected_frames(clip, frames)]
    if wanted != done_frames or (atlas_size is not None and atlas_size != done_size):
        raise InputError(
            manifest_path,
            f"{version} is already exported with frames {done_frames[0]}-{done_frames[-1]} and atlas size "
            f"{done_size}, not {wanted[0]}-{wanted[-1]} and {done_size if atlas_size is None else atlas_size}",
            f"export into another {EXPORT_INTO_ARG} version (exports are never overwritten)",
        )
    return manifest_path


def no_stage_error(version: str, chunks: Path) -> InputError:
    return InputError(
        chunks,
        f"no staged export of {version} here",
        f"run `export RUN {EXPORT_INTO_ARG} {version} {EXPORT_STAGE_ARG} atlases` first",
    )


def own_chunks_folder(run_dir: Path, version: str) -> Path:
    """``exports/.vNNN.chunks``, refused in one line when it or a folder the stages write into is a symbolic link:
    the staging folders are the engine's own (``exports/`` itself may be a link), and the passes stage writes without
    the lock, so a link planted there would take its files out of the run's exports."""
    chunks = chunks_folder(run_dir / C.EXPORTS_DIR, version)
    for path in (chunks, chunks / PASSES_DIR, chunks / ATLASES_DIR):
        if path.is_symlink():
            raise InputError(
                path,
                "is a symbolic link, and a staged export's folders are the engine's own (never written through a link)",
                f"delete the link, then run `export {EXPORT_INTO_ARG} {version} {EXPORT_STAGE_ARG} "
                f"{EXPORT_STAGES[0]}` again",
            )
    return chunks


def require_same_fit(
    run_dir: Path, chunks: Path, version: str, record: StageFile, source: dict[str, str] | None = None
) -> None:
    """One line unless the fit in ``run_dir`` now (``source``, default: read now) is the one the staged ``record``
    was made from: a version never mixes passes, atlases and a manifest of two fits."""
    changed = changed_since(record, fit_source(run_dir) if source is None else source)
    if changed:
        exports = run_dir / C.EXPORTS_DIR
        raise other_fit_error(chunks, version, changed, EXPORT_VERSION_FORMAT.format(_first_free(exports)))


__all__ = [
    "CHUNKS_SUFFIX",
    "FOLLOW_FLOW_DIR",
    "STAGED_EDITS",
    "STAGING_SUFFIX",
    "ExportOutput",
    "chunks_folder",
    "export_version",
    "no_stage_error",
    "own_chunks_folder",
    "published_manifest",
    "require_same_fit",
]
