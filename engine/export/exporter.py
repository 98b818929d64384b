"""Export a fitted run for compositing: per-frame UV + alpha EXR passes at the plate's native
resolution, an atlas texture per layer, empty edit layers (never overwritten) and a manifest.

The networks are continuous, so passes are evaluated at every native pixel centre whatever the working
resolution of the fit. Each export goes to a new versioned folder (``exports/v001``, ``v002``, ...),
assembled under a hidden name and renamed into place when complete (new edit layers with it), holding the run
folder's lock, so an earlier export is never touched and a killed export leaves nothing a compositor could mistake
for a result. The manifest records every path relative to itself (``relative_path``): a run folder moved or
mounted elsewhere with its plate keeps working.

Atlas frame: each layer's texture covers the bounding box of the atlas cells the layer covers (aggregated
alpha > ``BOX_COVERAGE``: median over frames for foregrounds, maximum for the background) and, for a foreground,
of the atlas points of the pixels it owns in any frame (a limb's cells are owned in a few frames only), plus a
margin.
Once an edit layer exists, the box it was painted in is recorded in ``edits/layout.json`` and reused by
every later export, so paint never shifts against the object.
"""

from __future__ import annotations

import contextlib
import datetime
import json
import math
import os
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from tqdm import tqdm

from .. import contract as C
from ..errors import InputError
from ..fit.progress import Reporter
from ..fit.run_folder import ClipRecord, RunFolder
from ..fit.trainer import EVAL_CHUNK, FittedRun, load_fitted
from ..io.atomic import DISK_ERRORS, as_disk_full, atomic_write_text, move_into_place, signals_held
from ..io.colour import RAW, REC709_CHROMATICITIES, SCENE_LINEAR, srgb_to_linear
from ..io.images import exr_timing, write_exr, write_png
from ..model.atlas_model import AtlasModel
from .stage_record import STAGE_RECORD, STAGE_SCHEMA, changed_since, fit_source, other_fit_error
from .stage_record import read_stage as _read_stage

#: Atlas cells whose aggregated coverage exceeds this decide where the layer's atlas box lies (a foreground's
#: faint halo, seen in a few frames only, stays below it and does not inflate the box).
BOX_COVERAGE = 0.5
#: Fallback when no cell is covered: the pixels whose layer alpha exceeds this.
BOX_ALPHA = 0.25
#: A foreground's box also holds the atlas points of the pixels it owns (alpha > BOX_COVERAGE) in any frame, but
#: for this share at each end of each axis: a limb whose atlas cells are covered in a few frames only (a swinging
#: leg, a foot) has a median coverage below BOX_COVERAGE, and outside the box its pixels get no paint (Z = 0); the
#: trimmed share keeps a few stray pixels from stretching the texture.
BOX_OWNED_TRIM = 0.001
#: The box grows by this fraction of its extent on each side (plus BOX_MARGIN_CELLS cells), so soft
#: edges and slightly off-box pixels still land inside the texture.
BOX_MARGIN = 0.03
BOX_MARGIN_CELLS = 2.0
#: Coverage is accumulated on a grid over [-COVERAGE_DOMAIN, COVERAGE_DOMAIN]^2 of model atlas units, at
#: about one cell per working pixel; mappings that land farther out than this are clamped.
COVERAGE_DOMAIN = 1.5
#: Largest coverage grid side (cells), bounding memory for extreme atlas scales.
COVERAGE_MAX_CELLS = 2048
#: Smallest atlas box extent in model units (a layer that never shows gets this instead of a point).
MIN_BOX_EXTENT = 1e-3
DEFAULT_ATLAS_SIZE = C.ATLAS_SIZE_DEFAULT
#: An export is staged in ``exports/.vNNN.partial`` until it is renamed into place; the new files of ``edits/`` (a
#: new edit layer, the layout) wait in its ``.edits`` folder.
STAGING_SUFFIX = ".partial"
STAGED_EDITS = ".edits"
#: A staged export (``export --into vNNN --stage ...``) is assembled in ``exports/.vNNN.chunks``: its atlases, the
#: passes its chunks write (no lock: several hosts at once) and its record (``STAGE_RECORD``: frames, atlas size,
#: each layer's atlas frame, the fit it was made from: ``engine.export.stage_record``), until ``--stage publish``
#: renames it to ``vNNN``. A whole export never removes it and never takes its number.
CHUNKS_SUFFIX = C.EXPORT_CHUNKS_SUFFIX
#: A layer's pass channels (UV X, Y, Z, alpha and the STMap copy) and their bytes uncompressed: the disk-full
#: estimate of a frame of passes before any is written.
PASS_CHANNELS_PER_LAYER = len(C.UV_CHANNELS) + len(C.ALPHA_CHANNELS) + len(C.STMAP_CHANNELS)
PASS_BYTES_PER_CHANNEL = 4


@dataclass
class LayerFrame:
    """Where one layer's texture sits in the model's atlas space: [u0, u1] x [v0, v1] (v down)."""

    box: tuple[float, float, float, float]  # u0, v0, u1, v1 in model atlas units
    size: tuple[int, int]  # texture W, H

    def to_texture_uv(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Model uv [..., 2] -> texture (u, v) in [0, 1] with v up (bottom-left origin), and inside-mask."""
        u0, v0, u1, v1 = self.box
        u = (uv[..., 0] - u0) / (u1 - u0)
        v = (v1 - uv[..., 1]) / (v1 - v0)
        inside = (u >= 0.0) & (u <= 1.0) & (v >= 0.0) & (v <= 1.0)
        return np.stack((np.clip(u, 0.0, 1.0), np.clip(v, 0.0, 1.0)), -1).astype(np.float32), inside

    def texel_centres(self) -> np.ndarray:
        """Model uv of every texel centre, [H, W, 2], row 0 at the top (the image file's first row)."""
        u0, v0, u1, v1 = self.box
        w, h = self.size
        us = u0 + (np.arange(w) + 0.5) / w * (u1 - u0)
        vs = v0 + (np.arange(h) + 0.5) / h * (v1 - v0)
        uu, vv = np.meshgrid(us, vs)
        return np.stack((uu, vv), -1).astype(np.float32)


def layer_frame_for(box: tuple[float, float, float, float], atlas_size: int) -> LayerFrame:
    """Texture size for a box: ``atlas_size`` on the long side, square texels (paint is not stretched)."""
    u0, v0, u1, v1 = box
    eu, ev = max(u1 - u0, MIN_BOX_EXTENT), max(v1 - v0, MIN_BOX_EXTENT)
    if eu >= ev:
        size = (atlas_size, max(1, round(atlas_size * ev / eu)))
    else:
        size = (max(1, round(atlas_size * eu / ev)), atlas_size)
    return LayerFrame((u0, v0, u0 + eu, v0 + ev), size)


class _Coverage:
    """Per-layer accumulation of where the layer's mapping lands and with what alpha (paper Sec. 4:
    the atlas alpha is the median over frames for foregrounds, the maximum for the background)."""

    def __init__(self, uv_per_px: float, frames: int, foreground: bool) -> None:
        self.cells = int(min(COVERAGE_MAX_CELLS, math.ceil(2 * COVERAGE_DOMAIN / max(uv_per_px, 1e-9))))
        self.scale = self.cells / (2 * COVERAGE_DOMAIN)  # cells per model unit
        self.foreground = foreground
        n = self.cells * self.cells
        if foreground:
            self.stack = np.full((frames, n), np.nan, dtype=np.float16)
            self.owned = np.zeros(n, dtype=np.float64)
        else:
            self.max = np.full(n, -1.0, dtype=np.float32)
        self.lo = np.array([np.inf, np.inf])
        self.hi = np.array([-np.inf, -np.inf])
        self.any_lo = np.array([np.inf, np.inf])
        self.any_hi = np.array([-np.inf, -np.inf])

    def add(self, t: int, uv: np.ndarray, alpha: np.ndarray) -> None:
        own = alpha > BOX_ALPHA
        if own.any():
            self.lo = np.minimum(self.lo, uv[own].min(0))
            self.hi = np.maximum(self.hi, uv[own].max(0))
        some = alpha > 0.01
        if some.any():
            self.any_lo = np.minimum(self.any_lo, uv[some].min(0))
            self.any_hi = np.maximum(self.any_hi, uv[some].max(0))
        c = np.floor((uv + COVERAGE_DOMAIN) * self.scale).astype(np.int64)
        ok = (c >= 0).all(-1) & (c < self.cells).all(-1)
        idx = c[ok, 1] * self.cells + c[ok, 0]
        n = self.cells * self.cells
        total = np.bincount(idx, weights=alpha[ok], minlength=n)
        count = np.bincount(idx, minlength=n).astype(np.float64)
        grid = _fill_holes(total.reshape(self.cells, self.cells), count.reshape(self.cells, self.cells))
        if self.foreground:
            self.stack[t] = grid.reshape(-1).astype(np.float16)
            self.owned += np.bincount(idx[alpha[ok] > BOX_COVERAGE], minlength=n)
        else:
            g = grid.reshape(-1)
            hit = np.isfinite(g)
            self.max[hit] = np.maximum(self.max[hit], g[hit])

    def box(self) -> tuple[float, float, float, float]:
        """Bounding box of the cells whose aggregated coverage exceeds BOX_COVERAGE, else of the pixels with
        alpha > BOX_ALPHA, else of any faintly visible pixel, else the model's whole atlas square; plus a
        margin."""
        rows, cols = np.nonzero(self.grid() > BOX_COVERAGE)
        if len(rows):
            lo_cell, hi_cell = np.array([cols.min(), rows.min()]), np.array([cols.max(), rows.max()])
            owned = self._owned_cells()
            if owned is not None:
                lo_cell, hi_cell = np.minimum(lo_cell, owned[0]), np.maximum(hi_cell, owned[1])
            lo = lo_cell / self.scale - COVERAGE_DOMAIN
            hi = (hi_cell + 1.0) / self.scale - COVERAGE_DOMAIN
        elif np.isfinite(self.lo).all():
            lo, hi = self.lo, self.hi
        elif np.isfinite(self.any_lo).all():
            lo, hi = self.any_lo, self.any_hi
        else:
            lo, hi = np.array([-1.0, -1.0]), np.array([1.0, 1.0])
        lo = np.clip(lo, -COVERAGE_DOMAIN, COVERAGE_DOMAIN)
        hi = np.clip(hi, -COVERAGE_DOMAIN, COVERAGE_DOMAIN)
        pad = (hi - lo) * BOX_MARGIN + BOX_MARGIN_CELLS / self.scale
        lo, hi = lo - pad, hi + pad
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])

    def _owned_cells(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(lowest, highest) cell (column, row) of the atlas points a foreground owns in any frame, each axis
        trimmed by BOX_OWNED_TRIM of them at both ends; None for the background or a layer that owns nothing."""
        if not self.foreground or self.owned.sum() <= 0:
            return None
        counts = self.owned.reshape(self.cells, self.cells)
        ends = []
        for marginal in (counts.sum(0), counts.sum(1)):  # per column (u), per row (v)
            cum = np.cumsum(marginal) / marginal.sum()
            ends.append(
                (
                    int(np.searchsorted(cum, BOX_OWNED_TRIM, side="right")),
                    min(int(np.searchsorted(cum, 1.0 - BOX_OWNED_TRIM)), self.cells - 1),
                )
            )
        return np.array([ends[0][0], ends[1][0]]), np.array([ends[0][1], ends[1][1]])

    def grid(self) -> np.ndarray:
        """Coverage alpha over the domain grid [cells, cells] (row = v), 0 where nothing ever landed."""
        if self.foreground:
            with np.errstate(all="ignore"):
                import warnings

                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN cells: never hit
                    med = np.nanmedian(self.stack.astype(np.float32), axis=0)
            g = np.nan_to_num(med, nan=0.0)
        else:
            g = np.clip(self.max, 0.0, None)
        return g.reshape(self.cells, self.cells).astype(np.float32)

    def sample(self, frame: LayerFrame) -> np.ndarray:
        """Coverage at every texel centre of ``frame`` [H, W] (bilinear)."""
        uv = frame.texel_centres()
        map_xy = ((uv + COVERAGE_DOMAIN) * self.scale - 0.5).astype(np.float32)
        return cv2.remap(self.grid(), map_xy[..., 0], map_xy[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def _fill_holes(total: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Mean alpha per cell; cells no pixel hit but whose 3x3 neighbourhood was hit get the neighbours' mean
    (a frame zoomed in relative to the atlas leaves one-cell gaps between its pixels); NaN elsewhere."""
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / np.maximum(count, 1.0), np.nan)
    k = np.ones((3, 3), np.float32)
    hit = (count > 0).astype(np.float32)
    nsum = cv2.filter2D(np.nan_to_num(mean).astype(np.float32), -1, k, borderType=cv2.BORDER_CONSTANT)
    ncnt = cv2.filter2D(hit, -1, k, borderType=cv2.BORDER_CONSTANT)
    holes = (count == 0) & (ncnt > 0)
    mean[holes] = nsum[holes] / ncnt[holes]
    return mean


@torch.no_grad()
def _eval_pixels(model: AtlasModel, xy: torch.Tensor, t: int) -> tuple[list[np.ndarray], np.ndarray]:
    """Model uv of every layer [N, 2] and layer weights [N, L] at working-resolution points ``xy``."""
    n = xy.shape[0]
    uvs = [np.empty((n, 2), np.float32) for _ in range(model.num_layers)]
    wts = np.empty((n, model.num_layers), np.float32)
    for s in range(0, n, EVAL_CHUNK):
        sl = slice(s, s + EVAL_CHUNK)
        tt = torch.full((xy[sl].shape[0],), t, dtype=torch.long, device=xy.device)
        wts[sl] = model.alpha(xy[sl], tt).float().cpu().numpy()
        for i in range(model.num_layers):
            uvs[i][sl] = model.uv(i, xy[sl], tt).float().cpu().numpy()
    return uvs, wts


def _pixel_grid(size: tuple[int, int], scale: tuple[float, float], device: torch.device) -> torch.Tensor:
    """Pixel centres of a ``size`` frame, in working-resolution coordinates (x * sx, y * sy)."""
    w, h = size
    ys, xs = torch.meshgrid(
        torch.arange(h, device=device, dtype=torch.float32),
        torch.arange(w, device=device, dtype=torch.float32),
        indexing="ij",
    )
    return torch.stack(((xs.reshape(-1) + 0.5) * scale[0], (ys.reshape(-1) + 0.5) * scale[1]), -1)


@torch.no_grad()
def _atlas_colours(model: AtlasModel, layer: int, frame: LayerFrame, device: torch.device) -> np.ndarray:
    uv = torch.from_numpy(frame.texel_centres().reshape(-1, 2)).to(device)
    out = np.empty((uv.shape[0], 3), np.float32)
    for s in range(0, uv.shape[0], EVAL_CHUNK):
        out[s : s + EVAL_CHUNK] = model.color(layer, uv[s : s + EVAL_CHUNK]).float().cpu().numpy()
    w, h = frame.size
    return np.clip(out.reshape(h, w, 3), 0.0, 1.0)


def _read_layout(edits_dir: Path) -> dict[str, Any]:
    path = edits_dir / C.EDITS_LAYOUT
    if not path.exists():
        return {"schema": C.SCHEMA_VERSION, "layers": {}}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        raise InputError(path, "edit layout is not valid JSON", "restore it from a backup or delete it") from None
    if data.get("schema") != C.SCHEMA_VERSION or not isinstance(data.get("layers"), dict):
        raise InputError(path, "edit layout has an unknown schema", "restore it or delete it (paint may shift)")
    return data


def _next_version(exports: Path) -> tuple[Path, Path]:
    """The next free ``vNNN`` and its hidden staging folder (created). Called under the run folder's lock, so any
    staging folder already there is a killed export's leftover: it is removed first. A number a staged export holds
    (``.vNNN.chunks``, whose passes other hosts may be writing without the lock) is never taken, nor its folder
    removed."""
    exports.mkdir(parents=True, exist_ok=True)
    for leftover in exports.glob(f".*{STAGING_SUFFIX}"):
        _remove_leftover(leftover)
    final = exports / C.EXPORT_VERSION_FORMAT.format(_first_free(exports))
    return final, _fresh_staging(exports, final.name)


def _first_free(exports: Path) -> int:
    """The lowest version number neither published nor held by a staged export."""
    n = 1
    while _taken(exports, C.EXPORT_VERSION_FORMAT.format(n)):
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
    return (exports / version).exists() or _chunks_folder(exports, version).exists()


def _fresh_staging(exports: Path, version: str) -> Path:
    """``exports/.vNNN.partial``, created empty (a killed export's leftover of that name is removed first)."""
    exports.mkdir(parents=True, exist_ok=True)
    staging = exports / f".{version}{STAGING_SUFFIX}"
    _remove_leftover(staging)
    staging.mkdir()
    return staging


def _chunks_folder(exports: Path, version: str) -> Path:
    """The hidden folder a staged export (``--into vNNN --stage ...``) is assembled in until it is published."""
    return exports / f".{version}{CHUNKS_SUFFIX}"


def export_version(text: str) -> str:
    """``--into``'s version name, checked: ``v001``, ``v002``, ... (``contract.EXPORT_VERSION_FORMAT``)."""
    digits = text[1:]
    if text[:1] == "v" and digits.isdigit() and int(digits) > 0 and C.EXPORT_VERSION_FORMAT.format(int(digits)) == text:
        return text
    raise InputError(
        None,
        f"{C.EXPORT_INTO_ARG} {text!r} is not an export version",
        f"name it as the exports are named: {C.EXPORT_VERSION_FORMAT.format(1)}, {C.EXPORT_VERSION_FORMAT.format(2)}, "
        "...",
    )


def _selected(clip: ClipRecord, frames: tuple[int, int] | None) -> list[int]:
    """Run frame indices to export; ``frames`` are the plate's frame numbers, like `fit --frames`."""
    numbers = list(clip.frame_numbers)
    if frames is None:
        return list(range(clip.num_frames))
    a, b = frames
    if a > b or a not in numbers or b not in numbers:
        first, last = numbers[0], numbers[-1]
        raise InputError(
            None,
            f"--frames {a}-{b} is outside the fitted frames {first}-{last}",
            f"choose a range inside {first}-{last} (the plate's frame numbers)",
        )
    return list(range(numbers.index(a), numbers.index(b) + 1))


def export_run(
    run_dir: str | Path,
    atlas_size: int | None = DEFAULT_ATLAS_SIZE,
    frames: tuple[int, int] | None = None,
    device_name: str = "cpu",
    progress_bar: bool = True,
    stream: Any = None,
    into: str | None = None,
    stage: str | None = None,
) -> Path:
    """Export ``run_dir``; returns the path of the manifest.json written. Reads the run folder only (its
    ``clip.json`` says what export needs of the clip): the plate is not decoded. Holds the run folder's lock for
    the whole write; the export and any new edit layers appear together, or (a failure, a full disk, a cancel)
    nothing does and the edit layers and earlier exports are as they were.

    ``into`` (``vNNN``): that version rather than the next free one; already published with the same frames and
    atlas size, its manifest is returned at once (a retried farm task), with others it is a one-line error.
    ``stage`` (``contract.EXPORT_STAGES``, with ``into``) runs one part of that export, so a farm can split it:
    ``atlases`` (the layer frames and atlas textures, into ``exports/.vNNN.chunks``), ``passes`` (the passes of
    ``frames``, without the lock: chunks run at once on several hosts; returns the staging folder) and ``publish``
    (every pass present: edit layers, manifest and Nuke script as a whole export writes them, then the folder
    becomes ``vNNN``). The staged export's files are those of a whole export of the same run, byte for byte.
    ``atlas_size`` None: the default (publish: the staged one)."""
    run_dir = Path(run_dir).resolve()
    low, high = C.ATLAS_SIZE_RANGE
    if atlas_size is not None and not low <= atlas_size <= high:
        raise InputError(None, f"--atlas-size {atlas_size} is out of range", f"use {low}..{high} (paper: 1000)")
    version = None if into is None else export_version(into)
    if stage is not None and stage not in C.EXPORT_STAGES:
        raise InputError(None, f"unknown {C.EXPORT_STAGE_ARG} {stage!r}", f"use one of {', '.join(C.EXPORT_STAGES)}")
    if stage is not None and version is None:
        raise InputError(
            None,
            f"{C.EXPORT_STAGE_ARG} {stage} without {C.EXPORT_INTO_ARG}",
            f"name the version its stages share: {C.EXPORT_INTO_ARG} {C.EXPORT_VERSION_FORMAT.format(1)}",
        )
    RunFolder(run_dir).require_fit()
    job = _Job(run_dir, device_name, progress_bar, stream)
    if stage == C.EXPORT_STAGES[1]:
        assert version is not None
        return _export_passes(job, version, frames)  # no lock: its chunks run at once on several hosts
    publish = stage == C.EXPORT_STAGES[2]
    size = atlas_size if publish or atlas_size is not None else DEFAULT_ATLAS_SIZE  # publish: the staged one
    with C.run_lock(run_dir, C.VERB_EXPORT):
        if version is None:
            return _export_whole(job, DEFAULT_ATLAS_SIZE if size is None else size, frames, None)
        done = _published(run_dir, version, size, frames, any_frames=publish and frames is None)
        if done is not None:
            return done
        if publish:
            return _export_publish(job, version, size, frames)
        assert size is not None
        if stage == C.EXPORT_STAGES[0]:
            return _export_atlases(job, version, size, frames)
        chunks = _chunks_folder(run_dir / C.EXPORTS_DIR, version)
        if chunks.exists():
            raise InputError(
                chunks,
                f"holds a staged export of {version}",
                f"finish it ({C.EXPORT_STAGE_ARG} passes, then publish), or delete that folder to export {version} "
                "whole",
            )
        return _export_whole(job, size, frames, version)


@dataclass
class _Job:
    """What every part of an export is given: the run, the device, and where its progress goes."""

    run_dir: Path
    device_name: str
    progress_bar: bool
    stream: Any

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


@dataclass
class _Plan:
    """What every part of one export shares: the layers, the atlas frame of each and the frames exported."""

    names: list[str]
    frames_by_layer: list[LayerFrame]
    selected: list[int]  # run frame indices
    atlas_size: int

    def numbers(self, clip: ClipRecord) -> list[int]:
        return [clip.frame_numbers[t] for t in self.selected]

    def to_record(self, clip: ClipRecord, source: dict[str, str]) -> dict[str, Any]:
        """The staged export's record (``STAGE_RECORD``): JSON keeps each float exactly, so every pass a chunk
        writes from it is the whole export's; ``source`` (``stage_record.fit_source``) is the fit it is made from,
        which every later stage checks."""
        numbers = self.numbers(clip)
        layers = [
            {"name": n, "atlas_box": list(fr.box), "atlas_size": list(fr.size)}
            for n, fr in zip(self.names, self.frames_by_layer, strict=True)
        ]
        return {"schema": STAGE_SCHEMA, "frames": [numbers[0], numbers[-1]], "atlas_size": self.atlas_size,
                "layers": layers, "source": source}  # fmt: skip

    @classmethod
    def from_record(cls, data: dict[str, Any], clip: ClipRecord) -> _Plan:
        frames = (int(data["frames"][0]), int(data["frames"][1]))
        layers = data["layers"]
        return cls(
            [str(layer["name"]) for layer in layers],
            [LayerFrame(tuple(layer["atlas_box"]), tuple(layer["atlas_size"])) for layer in layers],  # type: ignore[arg-type]
            _selected(clip, frames),
            int(data["atlas_size"]),
        )


def _plan(
    job: _Job, fitted: FittedRun, atlas_size: int, frames: tuple[int, int] | None, bar: Any
) -> tuple[_Plan, list[_Coverage]]:
    """Where each layer's mapping lands (every frame, working resolution) and each layer's atlas frame: an existing
    edit layer's frame wins (its paint must not shift)."""
    model, clip = fitted.model, fitted.clip
    device = next(model.parameters()).device
    selected = _selected(clip, frames)
    names = [C.layer_name(i, model.num_layers) for i in range(model.num_layers)]
    job.reporter.emit(C.EVENT_STAGE, stage="atlas", message="atlas extent and coverage")
    cov = [_Coverage(model.uv_per_px(i), clip.num_frames, foreground=i > 0) for i in range(model.num_layers)]
    xy_work = _pixel_grid(clip.working_size, (1.0, 1.0), device)
    for t in range(clip.num_frames):
        uvs, wts = _eval_pixels(model, xy_work, t)
        for i in range(model.num_layers):
            cov[i].add(t, uvs[i], wts[:, i])
        bar.update(1)
    edits_dir = fitted.folder.edits
    layout = _read_layout(edits_dir)
    frames_by_layer: list[LayerFrame] = []
    for i, name in enumerate(names):
        rec = layout["layers"].get(name)
        painted = any((edits_dir / f"{name}{ext}").exists() for ext in (C.EDIT_LAYER_EXT, C.EDIT_LAYER_FLOAT_EXT))
        if rec is not None and painted:
            frames_by_layer.append(layer_frame_for(tuple(rec["atlas_box"]), atlas_size))  # type: ignore[arg-type]
        else:
            frames_by_layer.append(layer_frame_for(cov[i].box(), atlas_size))
    return _Plan(names, frames_by_layer, selected, atlas_size), cov


def _write_atlases(fitted: FittedRun, plan: _Plan, cov: list[_Coverage], dest: Path) -> None:
    """Atlas textures into ``dest/atlases``: colours from the atlas network, coverage from the alpha network."""
    model = fitted.model
    device = next(model.parameters()).device
    for i, name in enumerate(plan.names):
        fr = plan.frames_by_layer[i]
        rgb = _atlas_colours(model, i, fr, device)
        alpha = np.clip(cov[i].sample(fr), 0.0, 1.0)[..., None]
        write_png(dest / C.ATLASES_DIR / f"{name}{C.ATLAS_PNG_EXT}", np.concatenate((rgb, alpha), -1), 16)
        lin = srgb_to_linear(rgb) * alpha
        write_exr(
            dest / C.ATLASES_DIR / f"{name}{C.ATLAS_EXR_EXT}",
            {"R": lin[..., 0], "G": lin[..., 1], "B": lin[..., 2], "A": alpha[..., 0]},
            chromaticities=REC709_CHROMATICITIES,  # scene-linear Rec.709, Blender's compositing space
            attributes={C.EXR_COLORSPACE_ATTRIBUTE: SCENE_LINEAR},
        )


def _padding(clip: ClipRecord) -> int:
    """The digits of the pass files' frame numbers: the plate's own padding (``contract.frame_padding``)."""
    return C.frame_padding(clip.frame_files, clip.frame_numbers)


def _pass_file(dest: Path, number: int, clip: ClipRecord) -> Path:
    return dest / C.PASSES_DIR / C.pass_file_name(number, _padding(clip))


def _write_passes(
    job: _Job, fitted: FittedRun, plan: _Plan, todo: list[int], dest: Path, bar: Any, written: Any = None
) -> None:
    """The UV + alpha passes of the run frames ``todo`` at native resolution into ``dest/passes``, each file
    atomic (a frame's pass exists whole or not at all); ``written(path)`` is told of each."""
    model, clip = fitted.model, fitted.clip
    device = next(model.parameters()).device
    job.reporter.emit(C.EVENT_STAGE, stage="passes", message=f"{len(todo)} frames of UV + alpha passes")
    nw, nh = clip.native_size
    ww, wh = clip.working_size
    xy_native = _pixel_grid((nw, nh), (ww / nw, wh / nh), device)
    frame_numbers = list(clip.frame_numbers)
    started = time.perf_counter()
    for k, t in enumerate(todo):
        uvs, wts = _eval_pixels(model, xy_native, t)
        chans: dict[str, np.ndarray] = {}
        for i, name in enumerate(plan.names):
            tex_uv, inside = plan.frames_by_layer[i].to_texture_uv(uvs[i])
            a = wts[:, i]
            uv_pass, alpha_pass = C.uv_pass(name), C.alpha_pass(name)
            u_name, v_name, coverage_name = (C.channel_name(uv_pass, c) for c in C.UV_CHANNELS)
            chans[u_name] = tex_uv[:, 0].reshape(nh, nw)
            chans[v_name] = tex_uv[:, 1].reshape(nh, nw)
            chans[coverage_name] = (a * inside).reshape(nh, nw)
            chans[C.channel_name(alpha_pass, C.ALPHA_CHANNELS[0])] = a.reshape(nh, nw)
            for channel, values in zip(C.STMAP_CHANNELS, stmap_values(chans, uv_pass), strict=True):
                chans[C.stmap_channel_name(name, channel)] = values
        timing = exr_timing(clip.rate, clip.pixel_aspect, clip.timecode, frame_numbers[t] - frame_numbers[0])
        tags = {C.EXR_COLORSPACE_ATTRIBUTE: RAW, **timing}  # data, with the plate's timing
        path = write_exr(_pass_file(dest, frame_numbers[t], clip), chans, attributes=tags)
        if written is not None:
            written(path)
        bar.update(1)
        job.reporter.emit(C.EVENT_PROGRESS, step=k + 1, total=len(todo), psnr=None, elapsed=None, eta=None)
        # the export's own whole job (a fit's reader places it after the fit's share): its frames, at their rate
        left = (time.perf_counter() - started) / (k + 1) * (len(todo) - k - 1)
        fraction = round((k + 1) / len(todo), 4)
        job.reporter.emit(
            C.EVENT_JOB,
            stage="export",
            done=k + 1,
            total=len(todo),
            stage_eta=round(left, 1),
            job_fraction=fraction,
            job_eta=round(left, 1),
        )


def _export_whole(job: _Job, atlas_size: int, frames: tuple[int, int] | None, version: str | None) -> Path:
    """A whole export, under the lock: into the next free version, or ``version``."""
    fitted = job.load()
    clip = fitted.clip
    out = _Output(fitted.folder, clip.native_size, fitted.model.num_layers, len(_selected(clip, frames)))
    try:
        bar = job.bar(clip.num_frames + out.frames)
        plan, cov = _plan(job, fitted, atlas_size, frames, bar)
        final, staging = out.begin(version)
        _write_atlases(fitted, plan, cov, staging)
        _write_passes(job, fitted, plan, plan.selected, staging, bar, out.pass_written)
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


def _publish(job: _Job, fitted: FittedRun, plan: _Plan, out: _Output) -> None:
    """The end of every export (whole or staged; passes and atlases are in ``out.staging``): new edit layers,
    created once and never overwritten, their atlas frame recorded for later exports; the manifest and the Nuke
    script; then everything into place at once."""
    assert out.final is not None and out.staging is not None
    edits_dir = fitted.folder.edits
    layout = _read_layout(edits_dir)
    recorded = json.dumps(layout, indent=2)
    for i, name in enumerate(plan.names):
        path = edits_dir / f"{name}{C.EDIT_LAYER_EXT}"
        fr = plan.frames_by_layer[i]
        if not path.exists():  # a new (or deleted) edit layer: it is painted in this export's frame
            w, h = fr.size
            write_png(out.stage_edit(path), np.zeros((h, w, 4), np.float32), 8)
            layout["layers"][name] = {"atlas_box": list(fr.box), "atlas_size": list(fr.size)}
        elif name not in layout["layers"]:  # the artist's own image: record the frame it now lives in
            layout["layers"][name] = {"atlas_box": list(fr.box), "atlas_size": list(fr.size)}
    if json.dumps(layout, indent=2) != recorded or not (edits_dir / C.EDITS_LAYOUT).exists():
        atomic_write_text(out.stage_edit(edits_dir / C.EDITS_LAYOUT), json.dumps(layout, indent=2))
    manifest = _manifest(job.run_dir, out.final, fitted, plan.names, plan.frames_by_layer, plan.selected)
    C.validate_manifest(manifest)
    atomic_write_text(out.staging / C.MANIFEST_NAME, json.dumps(manifest, indent=2))
    _write_nuke_script(out.staging, manifest)
    out.publish()
    job.reporter.emit(C.EVENT_EXPORTED, manifest=str(out.final / C.MANIFEST_NAME))


# --- a staged export: atlases once, passes in chunks (no lock), publish once ---------------------------------------


def _published(
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
    wanted = done_frames if any_frames else [clip.frame_numbers[t] for t in _selected(clip, frames)]
    if wanted != done_frames or (atlas_size is not None and atlas_size != done_size):
        raise InputError(
            manifest_path,
            f"{version} is already exported with frames {done_frames[0]}-{done_frames[-1]} and atlas size "
            f"{done_size}, not {wanted[0]}-{wanted[-1]} and {done_size if atlas_size is None else atlas_size}",
            f"export into another {C.EXPORT_INTO_ARG} version (exports are never overwritten)",
        )
    return manifest_path


def _no_stage(version: str, chunks: Path) -> InputError:
    return InputError(
        chunks,
        f"no staged export of {version} here",
        f"run `export RUN {C.EXPORT_INTO_ARG} {version} {C.EXPORT_STAGE_ARG} atlases` first",
    )


def _own_chunks_folder(run_dir: Path, version: str) -> Path:
    """``exports/.vNNN.chunks``, refused in one line when it or a folder the stages write into is a symbolic link:
    the staging folders are the engine's own (``exports/`` itself may be a link), and the passes stage writes without
    the lock, so a link planted there would take its files out of the run's exports."""
    chunks = _chunks_folder(run_dir / C.EXPORTS_DIR, version)
    for path in (chunks, chunks / C.PASSES_DIR, chunks / C.ATLASES_DIR):
        if path.is_symlink():
            raise InputError(
                path,
                "is a symbolic link, and a staged export's folders are the engine's own (never written through a link)",
                f"delete the link, then run `export {C.EXPORT_INTO_ARG} {version} {C.EXPORT_STAGE_ARG} "
                f"{C.EXPORT_STAGES[0]}` again",
            )
    return chunks


def _require_same_fit(
    run_dir: Path, chunks: Path, version: str, record: dict[str, Any], source: dict[str, str] | None = None
) -> None:
    """One line unless the fit in ``run_dir`` now (``source``, default: read now) is the one the staged ``record``
    was made from: a version never mixes passes, atlases and a manifest of two fits."""
    changed = changed_since(record, fit_source(run_dir) if source is None else source)
    if changed:
        exports = run_dir / C.EXPORTS_DIR
        raise other_fit_error(chunks, version, changed, C.EXPORT_VERSION_FORMAT.format(_first_free(exports)))


def _export_atlases(job: _Job, version: str, atlas_size: int, frames: tuple[int, int] | None) -> Path:
    """Under the lock: the layer frames and atlas textures into ``exports/.vNNN.chunks``, its record written last
    (a killed stage leaves no record, and is redone). Already staged with these parameters: nothing to do."""
    chunks = _own_chunks_folder(job.run_dir, version)
    record = _read_stage(chunks)
    source = fit_source(job.run_dir)  # under the lock: the fit loaded below is this one
    if record is not None:
        _require_same_fit(job.run_dir, chunks, version, record, source)
        clip = RunFolder(job.run_dir).read_clip()
        numbers = [clip.frame_numbers[t] for t in _selected(clip, frames)]
        if [numbers[0], numbers[-1]] != list(record["frames"]) or atlas_size != record["atlas_size"]:
            first, last = record["frames"]
            raise InputError(
                chunks / STAGE_RECORD,
                f"{version} is staged with frames {first}-{last} and atlas size {record['atlas_size']}, not "
                f"{numbers[0]}-{numbers[-1]} and {atlas_size}",
                f"stage another {C.EXPORT_INTO_ARG} version, or delete that folder",
            )
        return chunks
    fitted = job.load()
    bar = job.bar(fitted.clip.num_frames)
    plan, cov = _plan(job, fitted, atlas_size, frames, bar)
    bar.close()
    shutil.rmtree(chunks, ignore_errors=True)  # a killed atlases stage's leftover (no record: no pass was written)
    chunks.mkdir(parents=True)
    try:
        _write_atlases(fitted, plan, cov, chunks)
        (chunks / C.PASSES_DIR).mkdir()
        atomic_write_text(chunks / STAGE_RECORD, json.dumps(plan.to_record(fitted.clip, source), indent=2))
    except BaseException:
        shutil.rmtree(chunks, ignore_errors=True)
        raise
    return chunks


def _export_passes(job: _Job, version: str, frames: tuple[int, int] | None) -> Path:
    """Without the lock: the passes of ``frames`` (default: the staged range) that the staging folder lacks, each
    file atomic, so a chunk cancelled or killed keeps its finished frames and its retry writes only the rest.
    Returns the staging folder (the manifest, once published)."""
    chunks = _own_chunks_folder(job.run_dir, version)
    record = _read_stage(chunks)
    clip = RunFolder(job.run_dir).read_clip()
    if record is None:
        done = _published(job.run_dir, version, None, None, any_frames=True)
        if done is not None and frames is not None:
            numbers = [clip.frame_numbers[t] for t in _selected(clip, frames)]
            published = json.loads(done.read_text(encoding="utf-8"))["passes"]["frames"]
            if not set(numbers) <= set(published):
                raise InputError(done, f"{version} is published without frames {frames[0]}-{frames[1]}",
                                 f"export them into another {C.EXPORT_INTO_ARG} version")  # fmt: skip
        if done is not None:
            return done
        raise _no_stage(version, chunks)
    plan = _Plan.from_record(record, clip)
    staged = plan.numbers(clip)
    if frames is not None and not (staged[0] <= frames[0] <= frames[1] <= staged[-1]):
        raise InputError(
            chunks / STAGE_RECORD,
            f"--frames {frames[0]}-{frames[1]} is outside the staged frames {staged[0]}-{staged[-1]}",
            f"choose a range inside {staged[0]}-{staged[-1]}",
        )
    chunk = plan.selected if frames is None else _selected(clip, frames)
    todo = [t for t in chunk if not _pass_file(chunks, clip.frame_numbers[t], clip).exists()]
    if todo:
        # no lock here (a refine may replace the checkpoint meanwhile): the fit is checked before and after loading,
        # so the model that writes these passes is the one the atlases were made from
        _require_same_fit(job.run_dir, chunks, version, record)
        fitted = job.load()
        _require_same_fit(job.run_dir, chunks, version, record)
        bar = job.bar(len(todo))
        _write_passes(job, fitted, plan, todo, chunks, bar)
        bar.close()
    return chunks


def _export_publish(job: _Job, version: str, atlas_size: int | None, frames: tuple[int, int] | None) -> Path:
    """Under the lock, once every chunk is done: what a whole export writes after its passes, then the staging
    folder becomes ``exports/vNNN``. A frame without its pass is a one-line refusal naming the chunk to run."""
    chunks = _own_chunks_folder(job.run_dir, version)
    record = _read_stage(chunks)
    if record is None:
        raise _no_stage(version, chunks)
    _require_same_fit(job.run_dir, chunks, version, record)
    clip = RunFolder(job.run_dir).read_clip()
    plan = _Plan.from_record(record, clip)
    numbers = plan.numbers(clip)
    given = None if frames is None else [clip.frame_numbers[t] for t in _selected(clip, frames)]
    if (given is not None and given != numbers) or (atlas_size is not None and atlas_size != plan.atlas_size):
        raise InputError(
            chunks / STAGE_RECORD,
            f"{version} is staged with frames {numbers[0]}-{numbers[-1]} and atlas size {plan.atlas_size}",
            f"publish it without --frames and --atlas-size, or stage another {C.EXPORT_INTO_ARG} version",
        )
    missing = [n for n in numbers if not _pass_file(chunks, n, clip).is_file()]
    if missing:
        raise InputError(
            _pass_file(chunks, missing[0], clip),
            f"frame {missing[0]} has no pass yet ({len(missing)} of {len(numbers)} frames missing)",
            f"run `export {job.run_dir} {C.EXPORT_INTO_ARG} {version} {C.EXPORT_STAGE_ARG} passes --frames "
            f"{missing[0]}-{missing[-1]}`, then publish again",
        )
    fitted = job.load()
    out = _Output(fitted.folder, clip.native_size, len(plan.names), len(numbers), keep_staging=True)
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


def _write_nuke_script(staging: Path, manifest: dict[str, Any]) -> None:
    """The Nuke script of the edit beside the manifest (its paths are the manifest's, relative to the same folder);
    a plate Nuke cannot read as one sequence, or an OCIO config that is gone, gets a warning instead (`engine nuke`
    says the same)."""
    from .nuke import NukeScriptError, nuke_script

    try:
        atomic_write_text(staging / C.NUKE_SCRIPT_NAME, nuke_script(manifest, str(staging / C.MANIFEST_NAME)))
    except (NukeScriptError, InputError) as exc:
        if isinstance(exc, DISK_ERRORS):  # a full disk fails the export, as any other file it writes would
            raise
        print(f"warning: no {C.NUKE_SCRIPT_NAME}: {exc}", file=sys.stderr)


class _Output:
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
        """The staging folder of the next free version, or of ``version``."""
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
            os.replace(self.staging, self.final)
            self.edits, self.staging = [], None

    def discard(self) -> None:
        if self.staging is not None:
            if self.keep_staging:
                shutil.rmtree(self.staging / STAGED_EDITS, ignore_errors=True)
                (self.staging / C.MANIFEST_NAME).unlink(missing_ok=True)
                (self.staging / C.NUKE_SCRIPT_NAME).unlink(missing_ok=True)
            else:
                shutil.rmtree(self.staging, ignore_errors=True)
        for folder, made in ((self.run.exports, self.made_exports), (self.run.edits, self.made_edits)):
            if made:
                with contextlib.suppress(OSError):
                    folder.rmdir()  # only when empty: nothing of the artist's is ever removed


def stmap_values(chans: dict[str, np.ndarray], uv_pass: str) -> tuple[np.ndarray, ...]:
    """A layer's STMap copy (contract.STMAP_CHANNELS: R, G, B, A) from its UV pass: u, v, zeros and the coverage,
    the same float32 values (not half: on a 1000-texel atlas half floats round u, v by up to a quarter texel)."""
    u, v, z = (chans[C.channel_name(uv_pass, c)] for c in C.UV_CHANNELS)
    return u, v, np.zeros_like(u), z


def layer_record(
    name: str, index: int, atlas_size: tuple[int, int], box: tuple[float, ...], edit_layer: str
) -> dict[str, Any]:
    """One layer's manifest entry (contract.MANIFEST_LAYER_KEYS); paths relative to the export folder."""
    return {
        "name": name,
        "index": index,
        "role": C.ROLE_BACKGROUND if index == 0 else C.ROLE_FOREGROUND,
        "uv_pass": C.uv_pass(name),
        "alpha_pass": C.alpha_pass(name),
        "uv_channels": list(C.UV_CHANNELS),
        "alpha_channels": list(C.ALPHA_CHANNELS),
        "channels": [C.channel_name(C.uv_pass(name), c) for c in C.UV_CHANNELS]
        + [C.channel_name(C.alpha_pass(name), c) for c in C.ALPHA_CHANNELS],
        "stmap_pass": C.stmap_pass(name),
        "stmap_channels": [C.stmap_channel_name(name, c) for c in C.STMAP_CHANNELS],
        "atlas_exr": f"{C.ATLASES_DIR}/{name}{C.ATLAS_EXR_EXT}",
        "atlas_png": f"{C.ATLASES_DIR}/{name}{C.ATLAS_PNG_EXT}",
        "atlas_size": list(atlas_size),
        "edit_layer": edit_layer,
        "atlas_box": [round(float(b), 7) for b in box],
    }


def relative_path(path: str | Path, start: Path) -> str:
    """``path`` relative to the folder ``start`` ("/" separated), both with their symlinks resolved: what a manifest
    records, so a run folder moved or mounted elsewhere with its plate keeps working. The absolute path where no
    relative one exists (another Windows drive)."""
    real = os.path.realpath(path)
    try:
        return os.path.relpath(real, os.path.realpath(start)).replace(os.sep, "/")
    except ValueError:
        return real


def clip_timing(clip: ClipRecord) -> dict[str, Any]:
    """The manifest clip's timing fields (``contract.MANIFEST_OPTIONAL_FIELDS``): exact rate, pixel aspect ratio,
    timecode of the first frame, a movie's first frame number."""
    return {
        "rate": None if clip.rate is None else list(clip.rate),
        "pixel_aspect": clip.pixel_aspect,
        "timecode": clip.timecode,
        "start_frame": clip.start_frame,
    }


def _manifest(
    run_dir: Path,
    final: Path,
    fitted: FittedRun,
    names: list[str],
    frames_by_layer: list[LayerFrame],
    selected: list[int],
) -> dict[str, Any]:
    clip, cfg, metrics = fitted.clip, fitted.cfg, fitted.metrics or {}
    numbers = list(clip.frame_numbers)
    rel_edits = relative_path(fitted.folder.edits, final)
    layers = [
        layer_record(name, i, fr.size, fr.box, f"{rel_edits}/{name}{C.EDIT_LAYER_EXT}")
        for i, (name, fr) in enumerate(zip(names, frames_by_layer, strict=True))
    ]
    return {
        C.MANIFEST_TAG: C.MANIFEST_VERSION,
        "engine_version": C.ENGINE_VERSION,
        "run_dir": relative_path(run_dir, final),
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "clip": {
            "source": relative_path(clip.source, final),
            "kind": clip.kind,
            "frame_files": [relative_path(f, final) for f in clip.frame_files],
            # where the relative paths name nothing (the run folder moved alone), readers take these
            "source_absolute": os.path.abspath(clip.source),
            "frame_files_absolute": [os.path.abspath(f) for f in clip.frame_files],
            "frame_numbers": numbers,
            "first_frame": numbers[0],
            "last_frame": numbers[-1],
            "fps": clip.fps,
            "resolution": list(clip.native_size),
            "working_resolution": list(clip.working_size),
            "colorspace": clip.colorspace,
            **({"colour_config": clip.colour_config} if clip.colour_config is not None else {}),
            **({"colour_source": clip.colour_source} if clip.colour_source is not None else {}),
            "masks": [relative_path(m, final) for m in clip.masks],
            **clip_timing(clip),
        },
        "passes": {
            "dir": C.PASSES_DIR,
            "pattern": C.pass_pattern(_padding(clip)),
            "blender_pattern": C.blender_pattern(_padding(clip)),
            "frames": [numbers[t] for t in selected],
            "exr_layer": C.EXR_LAYER,
            "resolution": list(clip.native_size),
        },
        "layers": layers,
        "fit": {
            "preset": cfg.preset,
            "model": cfg.model,
            "steps": int(metrics.get("steps", 0)),
            "train_seconds": float(metrics.get("train_seconds", 0.0)),
            "psnr": metrics.get("psnr"),
            "alpha_iou": metrics.get("alpha_iou"),
        },
        "scene": fitted.scene.to_dict(),
    }


__all__ = [
    "DEFAULT_ATLAS_SIZE",
    "LayerFrame",
    "export_run",
    "export_version",
    "layer_frame_for",
    "layer_record",
    "relative_path",
]
