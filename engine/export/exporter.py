"""Export a fitted run for compositing: per-frame UV + alpha EXR passes at the plate's native
resolution, an atlas texture per layer, empty edit layers (never overwritten) and a manifest.

The networks are continuous, so passes are evaluated at every native pixel centre whatever the working
resolution of the fit. Each export goes to a new versioned folder (``exports/v001``, ``v002``, ...),
assembled under a hidden name and renamed into place when complete (new edit layers with it), holding the run
folder's lock, so an earlier export is never touched and a killed export leaves nothing a compositor could mistake
for a result. The manifest records every path relative to itself (``manifest_writer.relative_path``): a run folder
moved or mounted elsewhere with its plate keeps working.

Each layer's texture covers its atlas frame (``engine.export.atlas_frame``); an edit layer's frame, once painted,
is kept by every later export, so paint never shifts against the object. A staged export (``--into vNNN --stage
...``) runs the same steps in parts, so a farm can split them: the atlases once, the passes in chunks on several
hosts, the publish once.
"""

from __future__ import annotations

import json
import shutil
import sys
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from .. import contract as C
from ..data.flow import DISFlow, FlowField, cached_flow, compute_flow
from ..errors import InputError
from ..fit.fitted_run import FittedRun, load_fitted
from ..fit.prepare import fingerprint_of, fitted_plate
from ..fit.progress import Reporter
from ..fit.run_folder import RunFolder
from ..io.atomic import DISK_ERRORS, as_disk_full, atomic_write_text
from ..io.colour import REC709_CHROMATICITIES, SCENE_LINEAR, srgb_to_linear
from ..io.images import write_exr, write_png
from ..model.atlas_model import AtlasModel
from ..terms.cli import (
    EXPORT_FOLLOW_FLOW_FLAG,
    EXPORT_INTO_ARG,
    EXPORT_PASS_PRECISION_ARG,
    EXPORT_STAGE_ARG,
    EXPORT_STAGES,
    EXPORT_STMAP_FLAG,
)
from ..terms.colour import EXR_COLORSPACE_ATTRIBUTE
from ..terms.export_names import (
    ATLAS_EXR_EXT,
    ATLAS_PNG_EXT,
    ATLAS_SIZE_DEFAULT,
    ATLAS_SIZE_RANGE,
    ATLASES_DIR,
    EDIT_LAYER_EXT,
    EDITS_LAYOUT,
    EXPORT_VERSION_FORMAT,
    PASS_PRECISIONS,
    PASSES_DIR,
)
from ..terms.manifest import validate_manifest
from .atlas_frame import _Coverage
from .flow_reach import choose_reach, layer_scale
from .follow_flow import (
    FOLLOW_FLOW_PRESET,
    MEMORY_SHARE,
    MIN_SLIP_PX,
    available_memory,
    extended,
    layer_slip_px,
    memory_needed,
)
from .manifest_writer import _write_nuke_script, build_manifest
from .pass_files import pass_file
from .pass_writer import write_passes
from .plan import Plan, plan_export, read_layout, selected_frames
from .plate_splat import Splat, plate_texture, splat
from .sampling import atlas_colours, colours_at
from .stage_record import DAMAGED_FIX, STAGE_RECORD, StageFile, fit_source
from .stage_record import read_stage as _read_stage
from .staging import (
    FOLLOW_FLOW_DIR,
    ExportOutput,
    chunks_folder,
    export_version,
    no_stage_error,
    own_chunks_folder,
    published_manifest,
    require_same_fit,
)

DEFAULT_ATLAS_SIZE = ATLAS_SIZE_DEFAULT
#: ``follow_flow``: a pixel belongs to a layer where its weight is above this (the layers' weights sum to one, so
#: above one half is also the highest).
OWNED_ALPHA = 0.5
#: The plate is laid on a layer's atlas texture from the pixels where the layer's weight is at least this: at an
#: outline the plate mixes the layers (a swan's edge holds the water behind it), and the texture is composited by the
#: weight again, so the mixed colour would count twice; the outline's texels keep the network's colours.
SOLID_ALPHA = 0.9


def export_run(
    run_dir: str | Path,
    atlas_size: int | None = DEFAULT_ATLAS_SIZE,
    frames: tuple[int, int] | None = None,
    device_name: str = "cpu",
    progress_bar: bool = True,
    stream: Any = None,
    into: str | None = None,
    stage: str | None = None,
    follow_flow: bool | None = None,
    precision: str | None = None,
    stmap: bool | None = None,
) -> Path:
    """Export ``run_dir``; returns the path of the manifest.json written. Rebuilds the model from the run folder alone
    (its ``clip.json`` says what export needs of the clip); the plate is read at the working size only to follow the
    flow (never the masks). Holds the run folder's lock for
    the whole write; the export and any new edit layers appear together, or (a failure, a full disk, a cancel)
    nothing does and the edit layers and earlier exports are as they were.

    ``into`` (``vNNN``): that version rather than the next free one; already published with the same frames and
    atlas size, its manifest is returned at once (a retried farm task), with others it is a one-line error.
    ``stage`` (``terms.cli.EXPORT_STAGES``, with ``into``) runs one part of that export, so a farm can split it:
    ``atlases`` (the layer frames and atlas textures, into ``exports/.vNNN.chunks``), ``passes`` (the passes of
    ``frames``, without the lock: chunks run at once on several hosts; returns the staging folder) and ``publish``
    (every pass present: edit layers, manifest and Nuke script as a whole export writes them, then the folder
    becomes ``vNNN``). The staged export's files are those of a whole export of the same run, byte for byte.
    ``atlas_size`` None: the default (publish: the staged one). ``follow_flow``: each layer's UV averaged
    along optical flow where it slips against it (``engine.export.follow_flow``; the flow: ``_follow_source``): None
    (the default) where there is flow to follow, True insists (refused without it), False exports the UV as fitted. A
    staged export decides it in its atlases stage; its passes and publish follow the record (asked otherwise:
    refused). A
    version ``into`` already holds is returned as it is, whatever is asked. ``precision``
    (``terms.export_names.PASS_PRECISIONS``; None: compact, or a staged export's record): the bits the pass files keep
    (``pass_files.kept_precision``), decided with the flow in the atlases stage. ``stmap``: each pass file also
    holds an STMap copy of each layer's UV (None: not, or a staged export's record), decided there too.

    Eleven parameters: ``engine export``'s flags one for one, and where its progress goes (``stream``); the CLI, the
    demo, the bench and the farm's tasks each pass the few they need by name.
    """
    run_dir = Path(run_dir).resolve()
    low, high = ATLAS_SIZE_RANGE
    if atlas_size is not None and not low <= atlas_size <= high:
        raise InputError(None, f"--atlas-size {atlas_size} is out of range", f"use {low}..{high} (paper: 1000)")
    version = None if into is None else export_version(into)
    if stage is not None and stage not in EXPORT_STAGES:
        raise InputError(None, f"unknown {EXPORT_STAGE_ARG} {stage!r}", f"use one of {', '.join(EXPORT_STAGES)}")
    if stage is not None and version is None:
        raise InputError(
            None,
            f"{EXPORT_STAGE_ARG} {stage} without {EXPORT_INTO_ARG}",
            f"name the version its stages share: {EXPORT_INTO_ARG} {EXPORT_VERSION_FORMAT.format(1)}",
        )
    if precision is not None and precision not in PASS_PRECISIONS:
        raise InputError(
            None, f"unknown {EXPORT_PASS_PRECISION_ARG} {precision!r}", f"use one of {', '.join(PASS_PRECISIONS)}"
        )
    RunFolder(run_dir).require_fit()
    job = _Job(run_dir, device_name, progress_bar, stream, follow_flow, precision, stmap)
    if stage == EXPORT_STAGES[1]:
        assert version is not None
        return _export_passes(job, version, frames)  # no lock: its chunks run at once on several hosts
    publish = stage == EXPORT_STAGES[2]
    size = atlas_size if publish or atlas_size is not None else DEFAULT_ATLAS_SIZE  # publish: the staged one
    with C.run_lock(run_dir, C.VERB_EXPORT):
        if version is None:
            return _export_whole(job, DEFAULT_ATLAS_SIZE if size is None else size, frames, None)
        done = published_manifest(run_dir, version, size, frames, any_frames=publish and frames is None)
        if done is not None:
            return done
        if publish:
            return _export_publish(job, version, size, frames)
        assert size is not None
        if stage == EXPORT_STAGES[0]:
            return _export_atlases(job, version, size, frames)
        chunks = chunks_folder(run_dir / C.EXPORTS_DIR, version)
        if chunks.exists():
            raise InputError(
                chunks,
                f"holds a staged export of {version}",
                f"finish it ({EXPORT_STAGE_ARG} passes, then publish), or delete that folder to export {version} whole",
            )
        return _export_whole(job, size, frames, version)


@dataclass
class _Job:
    """What every part of an export is given: the run, the device, and where its progress goes."""

    run_dir: Path
    device_name: str
    progress_bar: bool
    stream: Any
    follow_flow: bool | None = None
    precision: str | None = None  # None: compact (a staged export: its record's)
    stmap: bool | None = None  # None: no STMap copy (a staged export: its record's)

    def __post_init__(self) -> None:
        self.reporter = Reporter(stream=self.stream)

    def load(self) -> FittedRun:
        self.reporter.emit(C.EVENT_STAGE, stage="load", message=f"loading the fit in {self.run_dir}")
        fitted = load_fitted(self.run_dir, self.device_name)
        if fitted.metrics is None:
            print(f"warning: {self.run_dir} has no {C.RUN_METRICS}: exporting an unfinished fit", file=sys.stderr)
        return fitted

    def bar(self, total: int) -> Any:
        return tqdm(total=total, disable=not self.progress_bar, file=sys.stderr, unit="frame")


def _write_atlases(job: _Job, fitted: FittedRun, planned: _Planned, dest: Path) -> None:
    """Atlas textures into ``dest/atlases``: colours from the plate laid through the exported UV where the export
    moved a layer's UV along the flow and read the plate (``plate_splat.plate_texture``), else the atlas network's;
    coverage from the alpha network."""
    model, plan = fitted.model, planned.plan
    device = next(model.parameters()).device
    for i, name in enumerate(plan.names):
        fr = plan.frames_by_layer[i]
        rgb = atlas_colours(model, i, fr, device)
        if i in planned.splats:
            rgb, full = plate_texture(planned.splats[i], fr, rgb)
            said = f"{name}: the atlas texture from the plate ({full:.0%} of its texels in full)"
            job.reporter.emit(C.EVENT_STAGE, stage="atlas", message=said)
        alpha = np.clip(planned.cov[i].sample(fr), 0.0, 1.0)[..., None]
        write_png(dest / ATLASES_DIR / f"{name}{ATLAS_PNG_EXT}", np.concatenate((rgb, alpha), -1), 16)
        lin = srgb_to_linear(rgb) * alpha
        write_exr(
            dest / ATLASES_DIR / f"{name}{ATLAS_EXR_EXT}",
            {"R": lin[..., 0], "G": lin[..., 1], "B": lin[..., 2], "A": alpha[..., 0]},
            chromaticities=REC709_CHROMATICITIES,  # scene-linear Rec.709, Blender's compositing space
            attributes={EXR_COLORSPACE_ATTRIBUTE: SCENE_LINEAR},
        )


class _WorkingUV:
    """Every layer's UV, ownership and solid pixels at working size, every frame, kept from the evaluation the atlas
    plan makes anyway (``plan_export``'s ``on_frame``): what ``follow_flow`` filters and ``plate_splat`` lays the
    plate through. Memory: 10 bytes per working pixel per frame per layer."""

    def __init__(self, frames: int, size: tuple[int, int], layers: int) -> None:
        w, h = size
        self.size = (h, w)
        self.uv = {i: np.empty((frames, h, w, 2), np.float32) for i in range(layers)}
        self.owned = {i: np.empty((frames, h, w), bool) for i in range(layers)}
        self.solid = {i: np.empty((frames, h, w), bool) for i in range(layers)}

    def add(self, t: int, uvs: list[np.ndarray], wts: np.ndarray) -> None:
        for i in self.uv:
            self.uv[i][t] = uvs[i].reshape(*self.size, 2)
            self.owned[i][t] = (wts[:, i] > OWNED_ALPHA).reshape(self.size)
            self.solid[i][t] = (wts[:, i] >= SOLID_ALPHA).reshape(self.size)


@dataclass
class _FollowSource:
    """What following the flow reads: the flow (``_follow_source``), the layers' UV at working size (filled by the
    atlas plan) and the plate at working size (None: unreadable or changed since the fit; the layers then keep to a
    few frames)."""

    flow: FlowField
    working: _WorkingUV
    frames: np.ndarray | None


def _working_plate(fitted: FittedRun) -> np.ndarray | None:
    """The plate at the working size as the fit read it (``prepare.fitted_plate``), checked against the fit's
    fingerprint: what ``flow_reach`` tests each reach with. None, with a warning line, where it cannot be read or
    is not the plate the fit read: then every layer follows the flow over a few frames."""
    clip = fitted.clip
    problem = "has changed since the fit"
    try:
        frames: np.ndarray | None = fitted_plate(clip)
    except InputError as exc:
        frames, problem = None, f"cannot be read ({exc.problem})"
    except (OSError, ValueError) as exc:
        frames, problem = None, f"cannot be read ({' '.join(str(exc).split())[:120]})"
    if frames is not None and fingerprint_of(frames) == clip.fingerprint:
        return frames
    print(
        f"warning: {clip.source}: the plate {problem}: the layers follow the flow over a few frames, not along whole "
        "trajectories (which needs the plate to choose)",
        file=sys.stderr,
    )
    return None


def _follow_source(job: _Job, fitted: FittedRun) -> _FollowSource | None:
    """The flow the paint follows, an empty ``_WorkingUV`` and the plate at working size when this export follows
    the flow; None when it does not: asked not to, nothing to follow (one frame), or (unless it was insisted on:
    refused in one line) no flow of this plate can be had or following it would not fit in the memory available
    (``follow_flow.memory_needed``: a long clip).

    The flow is the export's own (``FOLLOW_FLOW_PRESET`` on the plate as the fit read it, cached in
    ``RUN_DIR/flow_cache`` beside the fit's; the fit's own when it is that preset), not the one the fit learnt from:
    paint follows the flow point by point, where a sub-pixel error chained over a clip's frames is the paint's error
    (docs/bench/experiments.md). Where the plate cannot be read or has changed since the fit, the fit's flow (by the
    key its clip record names) stands in, over a few frames."""
    model, clip, cfg = fitted.model, fitted.clip, fitted.cfg
    if job.follow_flow is False or clip.num_frames < 2:
        return None
    need, have = memory_needed(clip.num_frames, clip.working_size, model.num_layers), available_memory()
    if have is not None and need > MEMORY_SHARE * have:
        said = f"following the flow needs about {need / 2**30:.1f} GiB of memory, {have / 2**30:.1f} GiB is available"
        return _not_followed(job, job.run_dir, said, "free memory first")
    (ww, wh), cache, threshold = clip.working_size, fitted.folder.flow_cache, cfg.flow_threshold_px
    frames = _working_plate(fitted)
    if frames is not None:
        backend = DISFlow(FOLLOW_FLOW_PRESET)
        said = f"the flow the paint follows ({backend.name}, {clip.num_frames - 1} frame pairs)"
        job.reporter.emit(C.EVENT_STAGE, stage="follow-flow", message=said)
        flow = compute_flow(frames.clip(0.0, 1.0), backend, cache_dir=cache, threshold_px=threshold)
        return _FollowSource(flow, _WorkingUV(clip.num_frames, clip.working_size, model.num_layers), frames)
    key = clip.flow_key
    name = DISFlow(cfg.flow_preset).name
    flow = None if key is None else cached_flow(cache, key, clip.num_frames, wh, ww, name, threshold)
    if flow is None:
        return _not_followed(job, cache, "holds no flow of this fit", "fit the run again (it writes its flow there)")
    return _FollowSource(flow, _WorkingUV(clip.num_frames, clip.working_size, model.num_layers), None)


def _not_followed(job: _Job, where: Path, problem: str, remedy: str) -> None:
    """This export cannot follow the flow (``problem``, of ``where``): refused in one line when it was insisted on
    (``remedy``, or exporting as fitted), else a warning and the UV as fitted (None, ``_follow_source``'s answer)."""
    if job.follow_flow:
        raise InputError(where, problem, f"{remedy}, or export with {C.EXPORT_NO_FOLLOW_FLOW_FLAG}")
    print(f"warning: {where}: {problem}: the layers' UV is exported as fitted", file=sys.stderr)


def split_parts(scribbled: bool, insisted: bool | None, layers: int) -> frozenset[int]:
    """The layers (of ``layers``, the background first) that following the flow leaves as fitted: the foreground
    layers of a fit whose one object was split by scribbles, unless the export insists on the flow (``insisted``:
    the export's ``follow_flow``)."""
    return frozenset(range(1, layers)) if scribbled and not insisted else frozenset()


def _flow_corrections(
    job: _Job,
    names: list[str],
    flow: FlowField,
    working: _WorkingUV,
    parts: frozenset[int] = frozenset(),
    frames: np.ndarray | None = None,
    model: AtlasModel | None = None,
) -> dict[int, np.ndarray]:
    """The UV correction [T, h, w, 2] at working resolution of each layer whose UV slips against the
    flow by more than ``MIN_SLIP_PX``, by layer index (``names``: the layers' names, for the messages), over the
    reach ``flow_reach.choose_reach`` tests with ``frames`` (the plate at working size; None: a few frames) and the
    ``model``'s atlas colours (its texture guard; None: no guard). ``parts``: layers that are parts of one object
    split by scribbles, left as fitted: where the parts cross, the flow follows neither (measured:
    ``docs/export.md``)."""
    out = {}
    for i in working.uv:
        slip = layer_slip_px(working.uv[i], working.owned[i], flow)
        follows = slip is not None and slip > MIN_SLIP_PX and i not in parts
        said = "no pixel to judge" if slip is None else f"slips {slip:.2f} px against the flow"
        if i in parts and slip is not None:
            said += f" (a part of one object: {EXPORT_FOLLOW_FLOW_FLAG} follows it)"
        done = "left as fitted"
        if follows:
            colours = None if model is None else partial(_colours, model, i)
            reach = choose_reach(working.uv[i], working.owned[i], flow, frames, colours)
            out[i], done = extended(reach.correction, working.owned[i]), reach.said
        job.reporter.emit(C.EVENT_STAGE, stage="follow-flow", message=f"{names[i]}: {said}: {done}")
    return out


def _colours(model: AtlasModel, layer: int, uv: np.ndarray) -> np.ndarray:
    """The layer's atlas colours at ``uv`` (``flow_reach.Colours``), on the model's device."""
    return colours_at(model, layer, uv, next(model.parameters()).device)


@dataclass
class _Planned:
    """What the passes and atlases are written from: the atlas plan and coverage, the flow-following UV corrections
    by layer (``_flow_corrections``) and, where the export read the plate, each followed layer's plate laid through
    its exported UV at working size (``plate_splat.splat``: its atlas texture)."""

    plan: Plan
    cov: list[_Coverage]
    corrections: dict[int, np.ndarray]
    splats: dict[int, Splat]


def _plan(job: _Job, fitted: FittedRun, atlas_size: int, frames: tuple[int, int] | None, bar: Any) -> _Planned:
    """The atlas plan, and, when the export follows the flow (``plan.follow_flow``, ``plan.follows``), the UV
    corrections and the plate laid through each layer's exported UV."""
    source = _follow_source(job, fitted)
    on_frame = None if source is None else source.working.add  # keep each frame's UV for the flow to follow
    plan, cov = plan_export(job.reporter, fitted, atlas_size, frames, bar, on_frame)
    plan.precision = job.precision or plan.precision
    plan.stmap = bool(job.stmap)
    if source is None:
        return _Planned(plan, cov, {}, {})
    parts = split_parts(fitted.clip.scribbles is not None, job.follow_flow, len(plan.names))
    corrections = _flow_corrections(job, plan.names, source.flow, source.working, parts, source.frames, fitted.model)
    plan.follow_flow, plan.follows = True, frozenset(corrections)
    return _Planned(plan, cov, corrections, _plate_splats(source, corrections))


def _plate_splats(source: _FollowSource, corrections: dict[int, np.ndarray]) -> dict[int, Splat]:
    """Each layer that follows the flow (``corrections``), its plate laid through its exported UV (the fitted one
    plus its correction) on texels one working pixel wide: the network's colours lie under the fitted UV, not the
    moved one. A layer left as fitted keeps them (its UV is the one they were fitted through: measured, the plate laid
    there re-renders the object no better and its outline worse). No entry where the plate could not be read or a
    layer owns too little to measure its scale."""
    out: dict[int, Splat] = {}
    if source.frames is None:
        return out
    working = source.working
    for i in corrections:
        uv, owned = working.uv[i], working.owned[i]
        scale = layer_scale(uv, owned)
        laid = None if scale is None else splat(uv, corrections[i], working.solid[i], source.frames, scale)
        if laid is not None:
            out[i] = laid
    return out


def _export_whole(job: _Job, atlas_size: int, frames: tuple[int, int] | None, version: str | None) -> Path:
    """A whole export, under the lock: into the next free version, or ``version``."""
    fitted = job.load()
    clip = fitted.clip
    out = ExportOutput(fitted.folder, clip.native_size, fitted.model.num_layers, len(selected_frames(clip, frames)))
    try:
        bar = job.bar(clip.num_frames + out.frames)
        planned = _plan(job, fitted, atlas_size, frames, bar)
        plan = planned.plan
        final, staging = out.begin(version)
        _write_atlases(job, fitted, planned, staging)
        write_passes(job.reporter, fitted, plan, plan.selected, staging, bar, out.pass_written, planned.corrections)
        bar.close()
        _publish(job, fitted, plan, out)
    except BaseException as exc:
        need = out.need()
        out.discard()
        full = as_disk_full(exc, fitted.folder.path, need) if isinstance(exc, DISK_ERRORS) else None
        if full is not None:
            raise full from None
        raise
    return final / C.MANIFEST_NAME


def _publish(job: _Job, fitted: FittedRun, plan: Plan, out: ExportOutput) -> None:
    """The end of every export (whole or staged; passes and atlases are in ``out.staging``): new edit layers,
    created once and never overwritten, their atlas frame recorded for later exports; the manifest and the Nuke
    script; then everything into place at once."""
    assert out.final is not None and out.staging is not None
    edits_dir = fitted.folder.edits
    layout = read_layout(edits_dir)
    recorded = json.dumps(layout, indent=2)
    for i, name in enumerate(plan.names):
        path = edits_dir / f"{name}{EDIT_LAYER_EXT}"
        fr = plan.frames_by_layer[i]
        if not path.exists():  # a new (or deleted) edit layer: it is painted in this export's frame
            w, h = fr.size
            write_png(out.stage_edit(path), np.zeros((h, w, 4), np.float32), 8)
            layout["layers"][name] = {"atlas_box": list(fr.box), "atlas_size": list(fr.size)}
        elif name not in layout["layers"]:  # the artist's own image: record the frame it now lives in
            layout["layers"][name] = {"atlas_box": list(fr.box), "atlas_size": list(fr.size)}
    if json.dumps(layout, indent=2) != recorded or not (edits_dir / EDITS_LAYOUT).exists():
        atomic_write_text(out.stage_edit(edits_dir / EDITS_LAYOUT), json.dumps(layout, indent=2))
    manifest = build_manifest(job.run_dir, out.final, fitted, plan)
    validate_manifest(manifest)
    atomic_write_text(out.staging / C.MANIFEST_NAME, json.dumps(manifest, indent=2))
    _write_nuke_script(out.staging, manifest)
    out.publish()
    job.reporter.emit(C.EVENT_EXPORTED, manifest=str(out.final / C.MANIFEST_NAME))


# --- a staged export: atlases once, passes in chunks (no lock), publish once ---------------------------------------


def _export_atlases(job: _Job, version: str, atlas_size: int, frames: tuple[int, int] | None) -> Path:
    """Under the lock: the layer frames and atlas textures into ``exports/.vNNN.chunks``, its record written last
    (a killed stage leaves no record, and is redone). Already staged with these parameters: nothing to do."""
    chunks = own_chunks_folder(job.run_dir, version)
    record = _read_stage(chunks)
    source = fit_source(job.run_dir)  # under the lock: the fit loaded below is this one
    if record is not None:
        require_same_fit(job.run_dir, chunks, version, record, source)
        clip = RunFolder(job.run_dir).read_clip()
        numbers = [clip.frame_numbers[t] for t in selected_frames(clip, frames)]
        _require_same_choices(job, chunks, version, record)
        if [numbers[0], numbers[-1]] != list(record.frames) or atlas_size != record.atlas_size:
            first, last = record.frames
            raise InputError(
                chunks / STAGE_RECORD,
                f"{version} is staged with frames {first}-{last} and atlas size {record.atlas_size}, not "
                f"{numbers[0]}-{numbers[-1]} and {atlas_size}",
                f"stage another {EXPORT_INTO_ARG} version, or delete that folder",
            )
        return chunks
    fitted = job.load()
    bar = job.bar(fitted.clip.num_frames)
    planned = _plan(job, fitted, atlas_size, frames, bar)
    plan = planned.plan
    bar.close()
    shutil.rmtree(chunks, ignore_errors=True)  # a killed atlases stage's leftover (no record: no pass was written)
    chunks.mkdir(parents=True)
    try:
        _write_atlases(job, fitted, planned, chunks)
        if planned.corrections:
            (chunks / FOLLOW_FLOW_DIR).mkdir()
            for i, correction in planned.corrections.items():
                np.save(chunks / FOLLOW_FLOW_DIR / f"{i}.npy", correction)
        (chunks / PASSES_DIR).mkdir()
        atomic_write_text(chunks / STAGE_RECORD, json.dumps(plan.to_record(fitted.clip, source), indent=2))
    except BaseException:
        shutil.rmtree(chunks, ignore_errors=True)
        raise
    return chunks


def _require_same_choices(job: _Job, chunks: Path, version: str, record: StageFile) -> None:
    """A stage asked explicitly to follow the flow, or not to, or for a pass precision or the STMap copy, continues
    only a staged export that decided the same in its atlases stage (asked nothing: it follows the record)."""
    precision = record.precision
    if job.precision is not None and job.precision != precision:
        raise InputError(
            chunks / STAGE_RECORD,
            f"{version} is staged with {EXPORT_PASS_PRECISION_ARG} {precision}, not {job.precision}",
            f"run this stage without {EXPORT_PASS_PRECISION_ARG}, or stage another {EXPORT_INTO_ARG} version",
        )
    if job.stmap is not None and job.stmap != record.stmap:
        raise InputError(
            chunks / STAGE_RECORD,
            f"{version} is staged without the STMap copy, not as {EXPORT_STMAP_FLAG} asks",
            f"run this stage without {EXPORT_STMAP_FLAG}, or stage another {EXPORT_INTO_ARG} version",
        )
    staged = record.follow_flow
    if job.follow_flow is not None and job.follow_flow != staged:
        flag = EXPORT_FOLLOW_FLOW_FLAG if job.follow_flow else C.EXPORT_NO_FOLLOW_FLOW_FLAG
        said = "following" if staged else "not following"
        raise InputError(
            chunks / STAGE_RECORD,
            f"{version} is staged {said} the flow, not as {flag} asks",
            f"run this stage without {flag}, or stage another {EXPORT_INTO_ARG} version",
        )


def _staged_corrections(chunks: Path, plan: Plan) -> dict[int, np.ndarray]:
    """The atlases stage's flow-following UV corrections of ``plan.follows``, memory-mapped (a chunk reads only its
    own frames); a missing or damaged file is one line."""
    out = {}
    for i in sorted(plan.follows):
        path = chunks / FOLLOW_FLOW_DIR / f"{i}.npy"
        try:
            out[i] = np.load(path, mmap_mode="r")
        except (OSError, ValueError):
            raise InputError(path, "staged flow correction is missing or damaged", DAMAGED_FIX) from None
    return out


def _export_passes(job: _Job, version: str, frames: tuple[int, int] | None) -> Path:
    """Without the lock: the passes of ``frames`` (default: the staged range) that the staging folder lacks, each
    file atomic, so a chunk cancelled or killed keeps its finished frames and its retry writes only the rest.
    Returns the staging folder (the manifest, once published)."""
    chunks = own_chunks_folder(job.run_dir, version)
    record = _read_stage(chunks)
    clip = RunFolder(job.run_dir).read_clip()
    if record is None:
        done = published_manifest(job.run_dir, version, None, None, any_frames=True)
        if done is not None and frames is not None:
            numbers = [clip.frame_numbers[t] for t in selected_frames(clip, frames)]
            published = json.loads(done.read_text(encoding="utf-8"))["passes"]["frames"]
            if not set(numbers) <= set(published):
                raise InputError(done, f"{version} is published without frames {frames[0]}-{frames[1]}",
                                 f"export them into another {EXPORT_INTO_ARG} version")  # fmt: skip
        if done is not None:
            return done
        raise no_stage_error(version, chunks)
    _require_same_choices(job, chunks, version, record)
    plan = Plan.from_record(record, clip)
    staged = plan.numbers(clip)
    if frames is not None and not (staged[0] <= frames[0] <= frames[1] <= staged[-1]):
        raise InputError(
            chunks / STAGE_RECORD,
            f"--frames {frames[0]}-{frames[1]} is outside the staged frames {staged[0]}-{staged[-1]}",
            f"choose a range inside {staged[0]}-{staged[-1]}",
        )
    chunk = plan.selected if frames is None else selected_frames(clip, frames)
    todo = [t for t in chunk if not pass_file(chunks, clip.frame_numbers[t], clip).exists()]
    if todo:
        # no lock here (a refine may replace the checkpoint meanwhile): the fit is checked before and after loading,
        # so the model that writes these passes is the one the atlases were made from
        require_same_fit(job.run_dir, chunks, version, record)
        fitted = job.load()
        require_same_fit(job.run_dir, chunks, version, record)
        bar = job.bar(len(todo))
        write_passes(job.reporter, fitted, plan, todo, chunks, bar, corrections=_staged_corrections(chunks, plan))
        bar.close()
    return chunks


def _export_publish(job: _Job, version: str, atlas_size: int | None, frames: tuple[int, int] | None) -> Path:
    """Under the lock, once every chunk is done: what a whole export writes after its passes, then the staging
    folder becomes ``exports/vNNN``. A frame without its pass is a one-line refusal naming the chunk to run."""
    chunks = own_chunks_folder(job.run_dir, version)
    record = _read_stage(chunks)
    if record is None:
        raise no_stage_error(version, chunks)
    require_same_fit(job.run_dir, chunks, version, record)
    _require_same_choices(job, chunks, version, record)
    clip = RunFolder(job.run_dir).read_clip()
    plan = Plan.from_record(record, clip)
    numbers = plan.numbers(clip)
    given = None if frames is None else [clip.frame_numbers[t] for t in selected_frames(clip, frames)]
    if (given is not None and given != numbers) or (atlas_size is not None and atlas_size != plan.atlas_size):
        raise InputError(
            chunks / STAGE_RECORD,
            f"{version} is staged with frames {numbers[0]}-{numbers[-1]} and atlas size {plan.atlas_size}",
            f"publish it without --frames and --atlas-size, or stage another {EXPORT_INTO_ARG} version",
        )
    missing = [n for n in numbers if not pass_file(chunks, n, clip).is_file()]
    if missing:
        raise InputError(
            pass_file(chunks, missing[0], clip),
            f"frame {missing[0]} has no pass yet ({len(missing)} of {len(numbers)} frames missing)",
            f"run `export {job.run_dir} {EXPORT_INTO_ARG} {version} {EXPORT_STAGE_ARG} passes --frames "
            f"{missing[0]}-{missing[-1]}`, then publish again",
        )
    fitted = job.load()
    out = ExportOutput(fitted.folder, clip.native_size, len(plan.names), len(numbers), keep_staging=True)
    out.final, out.staging = job.run_dir / C.EXPORTS_DIR / version, chunks
    for leftover in chunks.rglob(".*"):  # a killed chunk's temporary file
        if leftover.is_file():
            leftover.unlink()
    try:
        _publish(job, fitted, plan, out)
    except BaseException:
        out.discard()
        raise
    return out.final / C.MANIFEST_NAME


__all__ = [
    "DEFAULT_ATLAS_SIZE",
    "export_run",
]
