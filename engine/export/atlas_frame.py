"""Where each layer's texture sits in the model's atlas space (its atlas frame), found from where the layer's
mapping lands in every frame.

Texture coverage: the alpha a layer's atlas texture is premultiplied by. A background texel's is its maximum over
frames; a foreground texel's is its median over the frames where the texel is seen (alpha > ``SEEN_ALPHA``, in at
least ``SEEN_MIN_FRAMES`` frames), else its median over all frames. The plain median (the paper's rule) gives 0 to
every texel hidden in more than half of the frames: the body behind a swinging limb, a limb seen in a few frames, the
far side of a turning object; their colours were lost from the texture although the passes show them.

Atlas frame: each layer's texture covers the bounding box of the atlas cells the layer covers (aggregated
alpha > ``BOX_COVERAGE``: median over frames for foregrounds, maximum for the background) and, for a foreground,
of the atlas points of the pixels it owns in any frame (a limb's cells are owned in a few frames only), plus a
margin.
Once an edit layer exists, the box it was painted in is recorded in ``edits/layout.json`` and reused by
every later export, so paint never shifts against the object (``engine.export.plan``).

Torch-free: it works on the mapped points the networks gave (``engine.export.sampling``).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import cv2
import numpy as np

#: Atlas cells whose aggregated coverage exceeds this decide where the layer's atlas box lies (a foreground's
#: faint halo, seen in a few frames only, stays below it and does not inflate the box).
BOX_COVERAGE = 0.5
#: A foreground texel counts as seen in a frame where the alpha landing on it exceeds this (the texture coverage is
#: the median over those frames).
SEEN_ALPHA = 0.25
#: ... in at least this many frames (or every frame of a shorter clip); a texel seen less often (a fleck of alpha in
#: one frame) keeps the plain median over all frames.
SEEN_MIN_FRAMES = 2
#: Cells per chunk of the per-frame stack when taking medians over frames (bounds the float32 copy to
#: frames x MEDIAN_CHUNK_CELLS x 4 bytes).
MEDIAN_CHUNK_CELLS = 1 << 16
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
        """Coverage alpha over the domain grid [cells, cells] (row = v), 0 where nothing ever landed: the median over
        frames for a foreground (what decides its atlas box), the maximum for the background."""
        g = _median_over_frames(self.stack, seen_only=False) if self.foreground else np.clip(self.max, 0.0, None)
        return g.reshape(self.cells, self.cells).astype(np.float32)

    def texture_grid(self) -> np.ndarray:
        """The texture's coverage over the domain grid [cells, cells]: for a foreground, the median over the frames
        where the cell is seen (see the module docstring), else as ``grid``."""
        if not self.foreground:
            return self.grid()
        return _median_over_frames(self.stack, seen_only=True).reshape(self.cells, self.cells).astype(np.float32)

    def sample(self, frame: LayerFrame) -> np.ndarray:
        """Texture coverage at every texel centre of ``frame`` [H, W] (bilinear)."""
        uv = frame.texel_centres()
        map_xy = ((uv + COVERAGE_DOMAIN) * self.scale - 0.5).astype(np.float32)
        grid = self.texture_grid()
        return cv2.remap(grid, map_xy[..., 0], map_xy[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def _median_over_frames(stack: np.ndarray, seen_only: bool) -> np.ndarray:
    """Per cell of ``stack`` [frames, cells] (NaN: nothing landed there that frame), the median over frames, 0 where
    nothing ever landed. ``seen_only``: over the frames where the cell is seen (> SEEN_ALPHA) when it is seen in at
    least SEEN_MIN_FRAMES frames (every frame of a shorter clip). Taken in chunks of cells to bound memory."""
    frames, cells = stack.shape
    need = min(SEEN_MIN_FRAMES, frames)
    out = np.zeros(cells, np.float32)
    for lo in range(0, cells, MEDIAN_CHUNK_CELLS):
        part = stack[:, lo : lo + MEDIAN_CHUNK_CELLS].astype(np.float32)
        hit = np.isfinite(part).any(0)
        if not hit.any():
            continue
        part = part[:, hit]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # no NaN-free frame in a column: handled below
            med = np.nanmedian(part, axis=0)
            if seen_only:
                seen = part > SEEN_ALPHA  # NaN compares False
                use = seen.sum(0) >= need
                if use.any():
                    med[use] = np.nanmedian(np.where(seen[:, use], part[:, use], np.nan), axis=0)
        out[lo : lo + MEDIAN_CHUNK_CELLS][hit] = np.nan_to_num(med, nan=0.0)
    return out


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


__all__ = [
    "BOX_ALPHA",
    "BOX_COVERAGE",
    "MIN_BOX_EXTENT",
    "SEEN_ALPHA",
    "SEEN_MIN_FRAMES",
    "LayerFrame",
    "layer_frame_for",
]
