"""Export a fitted run for compositing: per-frame UV + alpha EXR passes at the plate's native
resolution, an atlas texture per layer, empty edit layers (never overwritten) and a manifest.

The networks are continuous, so passes are evaluated at every native pixel centre whatever the working
resolution of the fit. Each export goes to a new versioned folder (``exports/v001``, ``v002``, ...),
assembled under a hidden name and renamed into place when complete (new edit layers with it), holding the run
folder's lock, so an earlier export is never touched and a killed export leaves nothing a compositor could mistake
for a result. The manifest records every path relative to itself (``relative_path``): a run folder moved or
mounted elsewhere with its plate keeps working.

Atlas frame: each layer's texture covers the bounding box of the atlas cells the layer covers (aggregated
alpha > ``BOX_COVERAGE``: median over frames for foregrounds, maximum for the background), plus a margin.
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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from tqdm import tqdm

from engine import contract as C
from engine.errors import InputError
from engine.fit.progress import Reporter
from engine.fit.run_folder import ClipRecord, RunFolder
from engine.fit.trainer import EVAL_CHUNK, FittedRun, load_fitted
from engine.io.atomic import DISK_ERRORS, as_disk_full, atomic_write_text, move_into_place, signals_held
from engine.io.colour import RAW, REC709_CHROMATICITIES, SCENE_LINEAR, srgb_to_linear
from engine.io.images import exr_timing, write_exr, write_png
from engine.model.atlas_model import AtlasModel

#: Atlas cells whose aggregated coverage exceeds this decide where the layer's atlas box lies (a foreground's
#: faint halo, seen in a few frames only, stays below it and does not inflate the box).
BOX_COVERAGE = 0.5
#: Fallback when no cell is covered: the pixels whose layer alpha exceeds this.
BOX_ALPHA = 0.25
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
            lo = np.array([cols.min(), rows.min()]) / self.scale - COVERAGE_DOMAIN
            hi = (np.array([cols.max(), rows.max()]) + 1.0) / self.scale - COVERAGE_DOMAIN
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
    staging folder already there is a killed export's leftover: it is removed first."""
    exports.mkdir(parents=True, exist_ok=True)
    for leftover in exports.glob(f".*{STAGING_SUFFIX}"):
        shutil.rmtree(leftover, ignore_errors=True)
    n = 1
    while (exports / C.EXPORT_VERSION_FORMAT.format(n)).exists():
        n += 1
    final = exports / C.EXPORT_VERSION_FORMAT.format(n)
    staging = exports / f".{final.name}{STAGING_SUFFIX}"
    staging.mkdir()
    return final, staging


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
    atlas_size: int = DEFAULT_ATLAS_SIZE,
    frames: tuple[int, int] | None = None,
    device_name: str = "cpu",
    progress_bar: bool = True,
    stream: Any = None,
) -> Path:
    """Export ``run_dir``; returns the path of the manifest.json written. Reads the run folder only (its
    ``clip.json`` says what export needs of the clip): the plate is not decoded. Holds the run folder's lock for
    the whole write; the export and any new edit layers appear together, or (a failure, a full disk, a cancel)
    nothing does and the edit layers and earlier exports are as they were."""
    run_dir = Path(run_dir).resolve()
    low, high = C.ATLAS_SIZE_RANGE
    if not low <= atlas_size <= high:
        raise InputError(None, f"--atlas-size {atlas_size} is out of range", f"use {low}..{high} (paper: 1000)")
    RunFolder(run_dir).require_fit()
    with C.run_lock(run_dir, C.VERB_EXPORT):
        return _export_locked(run_dir, atlas_size, frames, device_name, progress_bar, stream)


def _export_locked(
    run_dir: Path,
    atlas_size: int,
    frames: tuple[int, int] | None,
    device_name: str,
    progress_bar: bool,
    stream: Any,
) -> Path:
    reporter = Reporter(stream=stream)
    reporter.emit(C.EVENT_STAGE, stage="load", message=f"loading the fit in {run_dir}")
    fitted = load_fitted(run_dir, device_name)
    model, clip = fitted.model, fitted.clip
    device = next(model.parameters()).device
    if fitted.metrics is None:
        print(f"warning: {run_dir} has no {C.RUN_METRICS}: exporting an unfinished fit", file=sys.stderr)
    selected = _selected(clip, frames)
    t_count = clip.num_frames
    names = [C.layer_name(i, model.num_layers) for i in range(model.num_layers)]

    # 1. where each layer's mapping lands, and with what alpha (every frame, working resolution)
    reporter.emit(C.EVENT_STAGE, stage="atlas", message="atlas extent and coverage")
    cov = [_Coverage(model.uv_per_px(i), t_count, foreground=i > 0) for i in range(model.num_layers)]
    xy_work = _pixel_grid(clip.working_size, (1.0, 1.0), device)
    bar = tqdm(total=t_count + len(selected), disable=not progress_bar, file=sys.stderr, unit="frame")
    for t in range(t_count):
        uvs, wts = _eval_pixels(model, xy_work, t)
        for i in range(model.num_layers):
            cov[i].add(t, uvs[i], wts[:, i])
        bar.update(1)

    # 2. the atlas frame of every layer: an existing edit layer's frame wins (its paint must not shift)
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

    out = _Output(fitted.folder, clip.native_size, len(names), len(selected))
    try:
        final, staging = out.begin()
        # 3. atlas textures: colours from the atlas network, coverage from the alpha network
        for i, name in enumerate(names):
            fr = frames_by_layer[i]
            rgb = _atlas_colours(model, i, fr, device)
            alpha = np.clip(cov[i].sample(fr), 0.0, 1.0)[..., None]
            write_png(staging / C.ATLASES_DIR / f"{name}{C.ATLAS_PNG_EXT}", np.concatenate((rgb, alpha), -1), 16)
            lin = srgb_to_linear(rgb) * alpha
            write_exr(
                staging / C.ATLASES_DIR / f"{name}{C.ATLAS_EXR_EXT}",
                {"R": lin[..., 0], "G": lin[..., 1], "B": lin[..., 2], "A": alpha[..., 0]},
                chromaticities=REC709_CHROMATICITIES,  # scene-linear Rec.709, Blender's compositing space
                attributes={C.EXR_COLORSPACE_ATTRIBUTE: SCENE_LINEAR},
            )

        # 4. passes at native resolution
        reporter.emit(C.EVENT_STAGE, stage="passes", message=f"{len(selected)} frames of UV + alpha passes")
        nw, nh = clip.native_size
        ww, wh = clip.working_size
        xy_native = _pixel_grid((nw, nh), (ww / nw, wh / nh), device)
        frame_numbers = list(clip.frame_numbers)
        for k, t in enumerate(selected):
            uvs, wts = _eval_pixels(model, xy_native, t)
            chans: dict[str, np.ndarray] = {}
            for i, name in enumerate(names):
                tex_uv, inside = frames_by_layer[i].to_texture_uv(uvs[i])
                a = wts[:, i]
                uv_pass, alpha_pass = C.uv_pass(name), C.alpha_pass(name)
                chans[C.channel_name(uv_pass, "X")] = tex_uv[:, 0].reshape(nh, nw)
                chans[C.channel_name(uv_pass, "Y")] = tex_uv[:, 1].reshape(nh, nw)
                chans[C.channel_name(uv_pass, "Z")] = (a * inside).reshape(nh, nw)
                chans[C.channel_name(alpha_pass, C.ALPHA_CHANNELS[0])] = a.reshape(nh, nw)
                for channel, values in zip(C.STMAP_CHANNELS, stmap_values(chans, uv_pass), strict=True):
                    chans[C.stmap_channel_name(name, channel)] = values
            timing = exr_timing(clip.rate, clip.pixel_aspect, clip.timecode, frame_numbers[t] - frame_numbers[0])
            pass_file = staging / C.PASSES_DIR / C.pass_file_name(frame_numbers[t])
            tags = {C.EXR_COLORSPACE_ATTRIBUTE: RAW, **timing}  # data, with the plate's timing
            out.pass_written(write_exr(pass_file, chans, attributes=tags))
            bar.update(1)
            reporter.emit(C.EVENT_PROGRESS, step=k + 1, total=len(selected), psnr=None, elapsed=None, eta=None)
        bar.close()

        # 5. edit layers: created once, never overwritten; their atlas frame recorded for later exports
        recorded = json.dumps(layout, indent=2)
        for i, name in enumerate(names):
            path = edits_dir / f"{name}{C.EDIT_LAYER_EXT}"
            fr = frames_by_layer[i]
            if not path.exists():  # a new (or deleted) edit layer: it is painted in this export's frame
                w, h = fr.size
                write_png(out.stage_edit(path), np.zeros((h, w, 4), np.float32), 8)
                layout["layers"][name] = {"atlas_box": list(fr.box), "atlas_size": list(fr.size)}
            elif name not in layout["layers"]:  # the artist's own image: record the frame it now lives in
                layout["layers"][name] = {"atlas_box": list(fr.box), "atlas_size": list(fr.size)}
        if json.dumps(layout, indent=2) != recorded or not (edits_dir / C.EDITS_LAYOUT).exists():
            atomic_write_text(out.stage_edit(edits_dir / C.EDITS_LAYOUT), json.dumps(layout, indent=2))

        manifest = _manifest(run_dir, final, fitted, names, frames_by_layer, selected)
        C.validate_manifest(manifest)
        atomic_write_text(staging / C.MANIFEST_NAME, json.dumps(manifest, indent=2))
        _write_nuke_script(staging, manifest)
        out.publish()
    except BaseException as exc:
        need = out.need()
        out.discard()
        full = as_disk_full(exc, fitted.folder.path, need) if isinstance(exc, DISK_ERRORS) else None
        if full is not None:
            raise full from None
        raise
    manifest_path = final / C.MANIFEST_NAME
    reporter.emit(C.EVENT_EXPORTED, manifest=str(manifest_path))
    return manifest_path


def _write_nuke_script(staging: Path, manifest: dict[str, Any]) -> None:
    """The Nuke script of the edit beside the manifest (its paths are the manifest's, relative to the same folder);
    a plate Nuke cannot read as one sequence gets a warning instead (`engine nuke` says the same)."""
    from engine.export.nuke import NukeScriptError, nuke_script

    try:
        atomic_write_text(staging / C.NUKE_SCRIPT_NAME, nuke_script(manifest, str(staging / C.MANIFEST_NAME)))
    except NukeScriptError as exc:
        print(f"warning: no {C.NUKE_SCRIPT_NAME}: {exc}", file=sys.stderr)


class _Output:
    """What one export writes: its hidden staging folder under ``exports/``, holding the new edit layer files and
    layout too. ``publish`` moves them all into place (signals held); ``discard`` removes whatever was made (and the
    ``exports``/``edits`` folders when this export created them)."""

    def __init__(self, run: RunFolder, native_size: tuple[int, int], layers: int, frames: int) -> None:
        self.run = run
        self.made_exports = not run.exports.exists()
        self.made_edits = not run.edits.exists()
        self.staging: Path | None = None
        self.final: Path | None = None
        self.edits: list[tuple[Path, Path]] = []  # (staged file, final name)
        self.frames = frames
        self.pass_bytes: list[int] = []
        w, h = native_size
        self.pass_estimate = w * h * layers * PASS_CHANNELS_PER_LAYER * PASS_BYTES_PER_CHANNEL

    def begin(self) -> tuple[Path, Path]:
        self.final, self.staging = _next_version(self.run.exports)
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
            os.replace(self.staging, self.final)
            self.edits, self.staging = [], None

    def discard(self) -> None:
        if self.staging is not None:
            shutil.rmtree(self.staging, ignore_errors=True)
        for folder, made in ((self.run.exports, self.made_exports), (self.run.edits, self.made_edits)):
            if made:
                with contextlib.suppress(OSError):
                    folder.rmdir()  # only when empty: nothing of the artist's is ever removed


def stmap_values(chans: dict[str, np.ndarray], uv_pass: str) -> tuple[np.ndarray, ...]:
    """A layer's STMap copy (contract.STMAP_CHANNELS: R, G, B, A) from its UV pass: u, v, zeros and the coverage Z,
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
    ext = C.PASS_FILE_EXT
    return {
        C.MANIFEST_TAG: C.MANIFEST_VERSION,
        "engine_version": C.ENGINE_VERSION,
        "run_dir": relative_path(run_dir, final),
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "clip": {
            "source": relative_path(clip.source, final),
            "kind": clip.kind,
            "frame_files": [relative_path(f, final) for f in clip.frame_files],
            "frame_numbers": numbers,
            "first_frame": numbers[0],
            "last_frame": numbers[-1],
            "fps": clip.fps,
            "resolution": list(clip.native_size),
            "working_resolution": list(clip.working_size),
            "colorspace": clip.colorspace,
            **({"colour_config": clip.colour_config} if clip.colour_config is not None else {}),
            "masks": [relative_path(m, final) for m in clip.masks],
            **clip_timing(clip),
        },
        "passes": {
            "dir": C.PASSES_DIR,
            "pattern": f"{C.PASS_FILE_PREFIX}{{frame:0{C.PASS_FILE_DIGITS}d}}{ext}",
            "blender_pattern": f"{C.PASS_FILE_PREFIX}{'#' * C.PASS_FILE_DIGITS}{ext}",
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


__all__ = ["DEFAULT_ATLAS_SIZE", "LayerFrame", "export_run", "layer_frame_for", "layer_record", "relative_path"]
