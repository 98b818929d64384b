"""A clip ready to fit: its frames at working resolution, masks, scribbles, optical flow and fingerprint.

``prepare_clip`` opens and decodes the clip once. With ``auto_masks`` (``fit --auto-masks``) the masks are
found in the same pass: the motion analysis reuses the decoded frames and, where it runs at the fit's working
size and flow settings, the fit's own flow; the masks it finds go to the fit in memory and are written to
RUN_DIR/auto_masks for the artist to check (and to fix, then fit again with ``--mask``).
"""

from __future__ import annotations

import hashlib
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from .. import contract as C
from ..config import FitConfig
from ..data.auto_masks import AutoMaskConfig, auto_masks, mask_folder, resize_masks, write_mask_files
from ..data.flow import DISFlow, FlowField, compute_flow
from ..data.long_flow import LongFlow, compute_long_flow, long_flow_gaps, long_flow_pairs
from ..data.mask_snap import MaskSnap, snap_masks
from ..data.scene_analysis import SceneAnalysis, analyse_scene
from ..data.scribbles import propagate_labels, read_scribbles, scribble_layers
from ..data.video import VideoTensors, build_video_tensors
from ..errors import InputError
from ..io.atomic import atomic_write_text
from ..io.clip import ClipInfo, open_clip, read_frames, read_frames_at, read_masks, working_size
from ..io.colour import legacy_linear_to_srgb, recorded_space, to_working
from ..terms.colour import COLORSPACES
from ..terms.run_folder import SCENE_LAYERS_AUTO
from .auto_parts import PartsSearch, check_run_strokes, is_run_strokes
from .fit_inputs import FitInputs
from .progress import Reporter
from .run_folder import ClipRecord, RunFolder

#: Characters of the frames' SHA-256 kept as the clip's fingerprint.
FINGERPRINT_CHARS = 32
#: A single frame has no motion: the message ``fit --auto-masks`` records instead of looking for masks.
SINGLE_FRAME_NOTE = "a single frame has no motion to find an object by"
#: Beside the masks a fit found (RUN_DIR/auto_masks): the fingerprint of the frames they were found on, so a later
#: fit reuses them only on those frames (hidden: mask readers skip it).
AUTO_MASKS_PLATE = ".plate_fingerprint"


@dataclass
class PreparedClip:
    info: ClipInfo
    size: tuple[int, int]
    frames: np.ndarray  # float32 [T, H, W, 3], working resolution, fitting values in [0, 1]-ish
    masks: np.ndarray  # bool [F, T, H, W]
    mask_dirs: list[str]
    flow: FlowField
    fingerprint: str
    scribbles: np.ndarray | None = None  # int8 [T, H, W]: 0-based foreground layer, -1 = no scribble
    scribble_dir: str | None = None
    frame_range: tuple[int, int] | None = None  # inclusive positions in the source; None: the whole clip
    layers_source: str | None = None  # terms.run_folder.SCENE_LAYERS_*; None: given masks (or none)
    masks_note: str | None = None  # what --auto-masks found, for the scene record
    long_flow: LongFlow | None = None  # long-range correspondences (``long_flow_max_gap``); None: off
    #: what ``mask_snap_px`` did to each given mask layer (engine.data.mask_snap); empty: nothing was searched
    mask_snaps: tuple[MaskSnap, ...] = ()

    @property
    def mask_layers(self) -> tuple[tuple[int, ...], ...] | None:
        """Model layers each mask covers (None: one layer per mask); scribbles split the one mask."""
        if self.scribbles is None:
            return None
        return (tuple(range(1, 1 + scribble_layers(self.scribbles))),)

    @property
    def num_foreground(self) -> int:
        return self.masks.shape[0] if self.scribbles is None else scribble_layers(self.scribbles)

    def tensors(self, cfg: FitConfig, device: torch.device) -> VideoTensors:
        """The clip as training tensors on ``device`` under ``cfg`` (its mask prior's margin): what ``fit``, the
        bench, the estimate and the speed table train on, one set shared by every config tried on the clip."""
        scribbles = self.scribbles
        if scribbles is not None and cfg.scribble_carry:
            scribbles = propagate_labels(scribbles, self.flow, self.masks[0])
        return build_video_tensors(
            self.frames,
            self.masks,
            self.flow,
            cfg.mask_prior_margin_px,
            device,
            scribbles,
            self.mask_layers,
            long_flow=self.long_flow,
        )

    def analyse(self, cfg: FitConfig) -> SceneAnalysis:
        """The scene analysis of this clip under ``cfg``: what the model computes (engine.data.scene_analysis)."""
        scribbled = 0 if self.scribbles is None else int((self.scribbles >= 0).any((1, 2)).sum())
        return analyse_scene(
            self.frames.shape[0],
            self.flow,
            self.masks,
            cfg,
            layers_source=self.layers_source,
            scribbles=scribbled,
            masks_note=self.masks_note,
            foreground_layers=self.num_foreground,
        )

    def record(self) -> ClipRecord:
        """What the run folder records of this clip (``clip.json``)."""
        info = self.info
        first = self.frame_range[0] if self.frame_range else 0
        return ClipRecord(
            source=info.source,
            kind=info.kind,
            frame_range=(first, first + info.num_frames - 1),
            frame_numbers=tuple(info.frame_numbers),
            frame_files=tuple(info.frame_files),
            native_size=(info.width, info.height),
            working_size=self.size,
            fps=info.fps,
            colorspace=info.colorspace,
            colour_config=info.colour_config,
            colour_source=info.colour_source,
            masks=tuple(self.mask_dirs),
            scribbles=self.scribble_dir,
            layers=1 + self.num_foreground,
            fingerprint=self.fingerprint,
            scribbles_fingerprint=None if self.scribbles is None else fingerprint_of(self.scribbles),
            rate=None if info.rate is None else (info.rate.numerator, info.rate.denominator),
            pixel_aspect=info.pixel_aspect,
            timecode=info.timecode,
            start_frame=info.start_frame,
            flow_key=self.flow.key,
        )


#: The largest plate value taken as it is: the largest finite half float, the format of most HDR plates. Suns and
#: speculars of thousands are legitimate HDR values and pass unchanged; a value beyond this cannot come from a
#: half-float EXR and is an artefact (a firefly of a renderer, a broken conversion, 1e30 in a float EXR). Such
#: values are clamped to +-PLATE_VALUE_LIMIT (and reported): the objective compares with its ``TARGET_RANGE``
#: anyway, so only what the flow and the PSNR see changes, and one absurd pixel no longer decides them.
PLATE_VALUE_LIMIT = 65504.0


@dataclass
class PlateFaults:
    """What ``to_fitting_values`` repaired, by frame (positions in the decoded clip)."""

    nonfinite: list[int]
    """Frames with NaN/Inf pixels (NaN and -Inf became 0, +Inf 1)."""
    absurd: list[int]
    """Frames with finite values beyond +-PLATE_VALUE_LIMIT (clamped to it)."""


def fingerprint_of(frames: np.ndarray) -> str:
    """The fitted frames' fingerprint (``clip.json``): a resume, and an export that reads the plate again, check that
    the clip is still the one fitted."""
    return hashlib.sha256(memoryview(np.ascontiguousarray(frames)).cast("B")).hexdigest()[:FINGERPRINT_CHARS]


def to_fitting_values(
    frames: np.ndarray, colorspace: str, source: str = "", colour_config: str | None = None
) -> tuple[np.ndarray, PlateFaults]:
    """Frames as the values the model fits: in the working encoding (sRGB-encoded Rec.709, converted from the
    plate's ``colorspace`` by OCIO; docs/colour.md), finite, within +-PLATE_VALUE_LIMIT before encoding, and what
    was repaired. Values within the limit of a plate already in the working encoding (every sRGB 8/16-bit plate)
    are unchanged bit for bit; the clamp runs in place on the one copy this makes anyway. A clip without a single
    finite value is a one-line ``InputError`` naming ``source``: there is nothing to fit."""
    per_frame = len(frames), -1
    finite = np.isfinite(frames).reshape(per_frame)
    if frames.size and not finite.any():
        raise InputError(
            source,
            "every pixel of the clip is NaN or Inf (no value to fit)",
            "re-export the plate: its frames hold no numbers",
        )
    bad = [int(i) for i in np.nonzero(~finite.all(1))[0]]
    del finite
    out = np.nan_to_num(frames, nan=0.0, posinf=1.0, neginf=0.0)
    absurd: list[int] = []
    if out.size and (float(out.max()) > PLATE_VALUE_LIMIT or float(out.min()) < -PLATE_VALUE_LIMIT):
        flat = out.reshape(per_frame)
        beyond = (flat.max(1) > PLATE_VALUE_LIMIT) | (flat.min(1) < -PLATE_VALUE_LIMIT)
        absurd = [int(i) for i in np.nonzero(beyond)[0]]
        np.clip(out, -PLATE_VALUE_LIMIT, PLATE_VALUE_LIMIT, out=out)
    if colour_config is None and colorspace == "linear":  # a run made before colour management: its own curve
        encoded = legacy_linear_to_srgb(np.clip(out, 0.0, None))
    else:
        encoded = to_working(out, colorspace, colour_config)
    if encoded is not out:
        out = np.clip(encoded, 0.0, None)  # negative light (out of the Rec.709 gamut) is no colour the atlas holds
    return out.astype(np.float32), PlateFaults(bad, absurd)


def _fit_flow(
    frames: np.ndarray,
    preset: str,
    threshold_px: float,
    cache_dir: Path,
    progress: Callable[[int, int], None] | None = None,
) -> FlowField:
    """Flow of display-encoded ``frames`` (cached per content); a single frame has none (nothing is cached).
    ``progress(done_pairs, total_pairs)`` after each pair (``compute_flow``)."""
    if len(frames) < 2:
        h, w = frames.shape[1:3]
        empty = np.zeros((0, h, w, 2), np.float32)
        ok = np.zeros((0, h, w), bool)
        return FlowField(empty, empty.copy(), ok, ok.copy(), DISFlow(preset).name, threshold_px)
    return compute_flow(
        frames.clip(0.0, 1.0), DISFlow(preset), cache_dir=cache_dir, threshold_px=threshold_px, progress=progress
    )


def prepare_clip(
    inputs: FitInputs,
    cfg: FitConfig,
    run_dir: Path,
    reporter: Reporter | None = None,
    expect: ClipRecord | None = None,
    before_writing: Callable[[], None] | None = None,
) -> PreparedClip:
    """Read, validate and sanitise the clip and masks, and compute (or load from RUN_DIR/flow_cache) its flow.

    ``expect`` (a resume: the record it continues): a clip whose frames changed, or scribbles that changed since the
    fit started, are refused before the flow is computed, so the refusal is quick and writes nothing into the run
    folder. Strokes in RUN_DIR/parts that an earlier fit left (``inputs.scribbles`` is that folder) must lie on a
    new fit's frames and mask (``auto_parts.check_run_strokes``). ``inputs.auto_masks``: no masks are given; find
    them from motion (written to RUN_DIR/auto_masks) and fit with them; nothing found: background only.
    ``before_writing``: called once everything is read and checked, before the first write into the run folder
    (the flow cache, the auto masks): ``fit`` takes the run folder's lock there, so bad input creates no folder.
    ``inputs.parts``: split the one mask (no scribbles given) into the parts that move apart, found from the fit's
    own snapped mask and flow once it is computed (``auto_parts.PartsSearch``; the strokes go to RUN_DIR/parts and
    are the fit's scribbles); an object that moves as one piece is fitted as without it.
    """
    reporter = reporter or Reporter.null()
    info, legacy_space = open_plate(inputs)
    size = working_size(info.width, info.height, cfg.long_edge)
    run = RunFolder(run_dir)
    mask_dirs, scribble_dir = inputs.masks, inputs.scribbles
    finder = _AutoMasks(info, run) if inputs.auto_masks else None
    search = None if inputs.parts is None else PartsSearch(inputs.parts, info, run, mask_dirs[0])
    reporter.emit(C.EVENT_STAGE, stage="read", message=f"reading {info.num_frames} frames at {size[0]}x{size[1]}")
    frames, raw, analysis_raw = _read_plate(info, size, finder, legacy_space)
    masks, snaps = _read_masks(mask_dirs, info, size, frames, cfg)
    if search is not None:
        search.check(masks[0])
    scribbles = None
    if scribble_dir is not None and expect is None and is_run_strokes(run, scribble_dir):
        scribbles = check_run_strokes(scribble_dir, info, size, masks)
    elif scribble_dir is not None:
        scribbles = _read_scribbles(scribble_dir, info, size)
    if scribbles is not None and finder is None:
        _check_one_mask(scribble_dir, len(mask_dirs))  # type: ignore[arg-type]
    fingerprint = fingerprint_of(frames)
    if expect is not None:
        _check_unchanged(expect, fingerprint, scribbles, scribble_dir, info)
    if info.colour_note:  # the colour space was assumed: said once, once the input is accepted (bad input: one line)
        print(info.colour_note, file=sys.stderr)
    if before_writing is not None:
        before_writing()
    if len(frames) >= 2:
        reporter.emit(C.EVENT_STAGE, stage="flow", message="optical flow (cached per clip content)")
    # the whole job's clock: what evaluation (working size) and export (native size) will reconstruct
    reporter.job.eval_pixels = len(frames) * size[0] * size[1]
    reporter.job.export_pixels = len(frames) * info.width * info.height
    flow, long_flow = _clip_flow(frames, cfg, run, reporter)
    found = None if search is None else search.find(masks[0], flow, reporter)
    if found is not None:
        scribbles, scribble_dir = found
    prepared = PreparedClip(
        info,
        size,
        frames,
        masks,
        [str(Path(m).resolve()) for m in mask_dirs],
        flow,
        fingerprint,
        scribbles,
        None if scribble_dir is None else str(Path(scribble_dir).resolve()),
        inputs.frames,
        long_flow=long_flow,
        mask_snaps=tuple(snaps),
    )
    if finder is not None:
        finder.find(prepared, cfg, analysis_raw if analysis_raw is not raw else None, reporter)
        if scribbles is not None:
            _check_one_mask(scribble_dir, len(prepared.mask_dirs))  # type: ignore[arg-type]
    return prepared


def open_plate(inputs: FitInputs) -> tuple[ClipInfo, str | None]:
    """The plate opened in its colour space (``fit --colorspace``, or the one a run recorded) and, for a run made
    before colour management ("sRGB"/"linear", no config), that legacy space: it is read with the values it fitted
    (``_read_plate``); None otherwise."""
    legacy = inputs.colour_config is None and inputs.colorspace in COLORSPACES
    space, config = recorded_space(inputs.colorspace, None) if legacy else (inputs.colorspace, inputs.colour_config)
    info = open_clip(inputs.plate, inputs.frames, space, config, fps=inputs.fps, start_frame=inputs.start_frame)
    return info, inputs.colorspace if legacy else None


def fitted_plate(record: ClipRecord) -> np.ndarray:
    """The plate of a run at its working size, as its fit read it (its recorded colour space, rate and movie
    numbering; ``fingerprint_of`` it to check it is still the plate fitted). The faults it repairs were said by the
    fit: not again. An ``InputError`` where it cannot be read."""
    info, legacy_space = open_plate(FitInputs.of_record(record))
    frames, _, _ = _read_plate(info, record.working_size, None, legacy_space, say_faults=False)
    return frames


def _read_plate(
    info: ClipInfo,
    size: tuple[int, int],
    finder: _AutoMasks | None,
    legacy_space: str | None,
    say_faults: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The plate's frames at the working ``size`` as the fit's values (a warning line for each kind of value
    replaced, unless not ``say_faults``), the frames as read, and those at the auto masks' analysis size (the same
    array when that is the working size). ``legacy_space``: a run made before colour management, fitted with the
    values it had."""
    if finder is not None and finder.size not in (None, size):
        raw, analysis_raw = read_frames_at(info, [size, finder.size])
    else:
        raw = analysis_raw = read_frames(info, size)
    if legacy_space is not None:
        frames, faults = to_fitting_values(raw, str(legacy_space), info.source, None)
    else:
        frames, faults = to_fitting_values(raw, info.colorspace, info.source, info.colour_config)
    if faults.nonfinite and say_faults:
        print(f"warning: NaN/Inf pixels replaced in frames {faults.nonfinite} of {info.source}", file=sys.stderr)
    if faults.absurd and say_faults:
        print(
            f"warning: values beyond +-{PLATE_VALUE_LIMIT:g} clamped in frames {faults.absurd} of {info.source}",
            file=sys.stderr,
        )
    return frames, raw, analysis_raw


def _read_masks(
    mask_dirs: list[str | Path], info: ClipInfo, size: tuple[int, int], frames: np.ndarray, cfg: FitConfig
) -> tuple[np.ndarray, list[MaskSnap]]:
    """The mask folders at the working size [F, T, H, W], their outlines snapped to the clip's edges (a note line
    for each folder moved), and each folder's snap."""
    masks = (
        np.stack([read_masks(m, info, size) for m in mask_dirs])
        if mask_dirs
        else np.zeros((0, len(frames), size[1], size[0]), dtype=bool)
    )
    snaps: list[MaskSnap] = []
    if mask_dirs and cfg.mask_snap_px >= 2:
        masks, snaps = snap_masks(frames, masks, cfg.mask_snap_px)
        for folder, snap in zip(mask_dirs, snaps, strict=True):
            if snap.offset_px:
                print(
                    f"note: masks {folder}: outline moved {snap.offset_px:+d} px to the clip's edges "
                    "(--set mask_snap_px=0 fits them as drawn)",
                    file=sys.stderr,
                )
    return masks, snaps


def _clip_flow(
    frames: np.ndarray, cfg: FitConfig, run: RunFolder, reporter: Reporter
) -> tuple[FlowField, LongFlow | None]:
    """The clip's optical flow and, where the config asks for them, its long-range correspondences (both from
    RUN_DIR/flow_cache when cached), reported as one flow stage."""
    flow_start = time.perf_counter()

    # the long-range pairs are part of the flow stage: one progress count over both, so its fraction only grows
    gaps = long_flow_gaps(cfg.long_flow_max_gap, len(frames))
    adjacent_pairs, long_pairs = max(len(frames) - 1, 0), long_flow_pairs(gaps, len(frames))
    total_pairs = adjacent_pairs + long_pairs

    def flow_progress(done: int, total: int, offset: int = 0) -> None:
        done = offset + done
        left = reporter.job.flow(time.perf_counter() - flow_start, done, total_pairs)
        reporter.job_event("flow", done, total_pairs, left)

    flow = _fit_flow(frames, cfg.flow_preset, cfg.flow_threshold_px, run.flow_cache, flow_progress)
    long_flow = None
    if gaps:
        long_flow = compute_long_flow(
            frames.clip(0.0, 1.0),
            flow,
            gaps,
            DISFlow(cfg.flow_preset),
            cache_dir=run.flow_cache,
            threshold_px=cfg.flow_threshold_px,
            stride=cfg.long_flow_stride,
            progress=lambda done, total: flow_progress(done, total, adjacent_pairs),
        )
    return flow, long_flow


def _check_unchanged(
    expect: ClipRecord, fingerprint: str, scribbles: np.ndarray | None, scribble_dir: str | Path | None, info: ClipInfo
) -> None:
    """A resume continues on the frames and the strokes its fit started with: either changed is one line (a record
    written before the strokes' fingerprint was kept checks the frames only)."""
    if fingerprint != expect.fingerprint:
        raise InputError(
            info.source, "the clip changed since this run started", "fit it into a new --out instead of --resume"
        )
    recorded = expect.scribbles_fingerprint
    if scribbles is not None and recorded is not None and fingerprint_of(scribbles) != recorded:
        raise InputError(
            scribble_dir,
            "the strokes changed since this fit started",
            "put them back to continue it, or fit with them by --refit (edits/ and exports/ are kept)",
        )


def _read_scribbles(scribble_dir: str | Path, info: ClipInfo, size: tuple[int, int]) -> np.ndarray:
    scribbles = read_scribbles(scribble_dir, info, size)
    if scribble_layers(scribbles) < 2:
        raise InputError(
            scribble_dir,
            "the scribbles use only the first colour (red), so they split nothing",
            "scribble the object's other part in green",
        )
    return scribbles


def _check_one_mask(scribble_dir: str | Path, masks: int) -> None:
    if masks != 1:
        raise InputError(
            scribble_dir,
            f"scribbles split one object, but {masks} mask folders were given",
            "pass exactly one --mask (the whole object) with --scribbles",
        )


class _AutoMasks:
    """``fit --auto-masks`` within ``prepare_clip``: the masks of one moving object, found from motion at the
    analysis resolution (``AutoMaskConfig.long_edge``) in the frames already decoded."""

    def __init__(self, info: ClipInfo, run: RunFolder, cfg: AutoMaskConfig | None = None) -> None:
        self.info = info
        self.cfg = cfg or AutoMaskConfig()
        self.shown = run.own_folder(run.auto_masks, "masks")  # the folder as messages name it
        self.cache = run.flow_cache
        #: the analysis size; None: a single frame, nothing to analyse
        self.size = working_size(info.width, info.height, self.cfg.long_edge) if info.num_frames >= 2 else None
        # checked before anything is decoded: a folder that holds some of the masks already is refused at once;
        # one that holds every one of them (``masks`` wrote them, a farm's masks task, or the artist fixed an
        # earlier fit's) is used as it is, never searched again or overwritten
        self.folder, self.names = (
            mask_folder(info, self.shown, whole_set=True) if self.size is not None else (self.shown, [])
        )
        self.reuse = bool(self.names) and all((self.folder / n).exists() for n in self.names)

    def find(self, prepared: PreparedClip, fit_cfg: FitConfig, raw: np.ndarray | None, reporter: Reporter) -> None:
        """Set ``prepared``'s masks from motion. ``raw``: the frames decoded at the analysis size (None: the
        analysis size is the working size: ``prepared.frames`` are the frames to analyse)."""
        prepared.layers_source = SCENE_LAYERS_AUTO
        if self.size is None:
            prepared.masks_note = SINGLE_FRAME_NOTE
            return
        if self.reuse:
            self._use_written(prepared, reporter)
            return
        cfg = self.cfg
        reporter.emit(C.EVENT_STAGE, stage="masks", message=f"finding moving objects; masks go to {self.shown}")
        if raw is None:
            frames = prepared.frames
            shared = (fit_cfg.flow_preset, fit_cfg.flow_threshold_px) == (cfg.flow_preset, cfg.flow_threshold_px)
        else:
            info = self.info
            frames, shared = to_fitting_values(raw, info.colorspace, info.source, info.colour_config)[0], False
        flow = prepared.flow if shared else _fit_flow(frames, cfg.flow_preset, cfg.flow_threshold_px, self.cache)
        result = auto_masks(frames, cfg, flow=flow)
        native = resize_masks(result.masks, (self.info.width, self.info.height))
        write_mask_files(self.folder, self.names, native)
        atomic_write_text(self.folder / AUTO_MASKS_PLATE, prepared.fingerprint)
        print(f"auto masks: {result.message} ({self.shown})", file=sys.stderr)
        prepared.masks_note = result.message
        if result.found:
            # in memory, what reading the written files back at the working size gives (read_masks: the files'
            # 0/1 values shrunk with INTER_AREA, then above contract.MASK_THRESHOLD)
            w, h = prepared.size
            matte = native.astype(np.float32)
            if native.shape[1:] != (h, w):
                matte = np.stack([cv2.resize(m, (w, h), interpolation=cv2.INTER_AREA) for m in matte])
            prepared.masks = (matte > C.MASK_THRESHOLD)[None]
            prepared.mask_dirs = [str(self.folder)]

    def _use_written(self, prepared: PreparedClip, reporter: Reporter) -> None:
        """The masks already in the folder, read as ``--mask`` reads a folder; all of them empty is what a search
        that found nothing writes: a background-only fit, as then. Masks a search found on other frames (the
        fingerprint beside them) are refused in one line; masks without one (the artist's) are used as they are."""
        found_on = self.folder / AUTO_MASKS_PLATE
        if found_on.is_file() and found_on.read_text(encoding="utf-8").strip() != prepared.fingerprint:
            raise InputError(
                self.shown,
                "the masks an earlier fit found here are of other frames (another plate, range or colour space)",
                "delete the folder to have them found again, or pass the masks you want with --mask",
            )
        reporter.emit(C.EVENT_STAGE, stage="masks", message=f"using the masks already in {self.shown}")
        masks = read_masks(self.folder, self.info, prepared.size)
        if masks.any():
            prepared.masks = masks[None]
            prepared.mask_dirs = [str(self.folder)]
            prepared.masks_note = f"the masks already in {self.shown}"
        else:
            prepared.masks_note = f"no foreground in the masks already in {self.shown}: a background-only fit"
        print(f"auto masks: {prepared.masks_note}", file=sys.stderr)


__all__ = [
    "AUTO_MASKS_PLATE",
    "PLATE_VALUE_LIMIT",
    "PlateFaults",
    "PreparedClip",
    "fingerprint_of",
    "fitted_plate",
    "open_plate",
    "prepare_clip",
    "to_fitting_values",
]
