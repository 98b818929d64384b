"""The plate laid on a layer's atlas through its UV: every pixel given (the layer's owned pixels for the reach test,
its solid ones for the texture), in every frame, splatted (bilinearly) with its colour into texels one working pixel
wide.

Two things read it. ``flow_reach`` reads the plate back through the same UV: a UV that gives one point of the object
one texel in every frame gathers one colour per texel and reads back sharp, one that gives it several blurs. The
export writes it as the atlas texture of a layer whose UV it moves along the flow (``plate_texture``): the atlas
network's colours lie under the UV as fitted, not the moved one. The mean of what landed on a texel is the texture
that re-renders the plate through the exported UV with the least squared error at that resolution; where nothing (or
little) landed, the network's colour stays. Measured on a walking cow (``draft``, the long reach followed): the plate
re-rendered from the exported textures inside the mask 22.1 dB, from the network's colours at the same UV 18.7 dB,
from the fit's own networks 20.4 dB (docs/export.md, *Atlas textures*).

Conventions as in ``follow_flow``: working-size arrays, ``uv`` [T, H, W, 2] in the model's atlas units, ``owned``
[T, H, W] bool (the pixels laid), ``frames`` [T, H, W, 3] the plate's values as the fit reads them
(``prepare.to_fitting_values``). numpy and OpenCV only.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from .atlas_frame import LayerFrame
from .follow_flow import MIN_UV_PER_PX

#: The splat holds at most this many texels (64 MB per channel of float64 accumulators); a layer whose UVs spread
#: wider is laid on texels that many working pixels wide as it takes to fit.
MAX_TEXELS = 1 << 23
#: ... and at most this many on a side (OpenCV reads images under 32767 pixels a side).
MAX_SIDE = 1 << 14
#: A texel holds the plate's colour in full where this much weight landed on it (one frame's pixel, the bilinear
#: shares summed); less, and the network's colour makes up the rest in proportion (an edge seen in one frame, a
#: texel between the pixels of a stretched frame).
FULL_WEIGHT = 1.0
#: Below this weight a texel's colour is not divided out (it holds nothing of the plate).
MIN_WEIGHT = 1e-6


@dataclass
class Splat:
    """The plate's colours summed on texel corners: texel (row j, column i) sits at model UV ``origin + cell * (i,
    j)``; ``weight`` [h, w] the bilinear shares that landed there, ``colour`` [h, w, C] the colours times them."""

    origin: np.ndarray
    cell: float
    weight: np.ndarray
    colour: np.ndarray

    def texture(self) -> np.ndarray:
        """The mean colour that landed on each texel [h, w, C] (float32), 0 where nothing did."""
        return (self.colour / np.maximum(self.weight, MIN_WEIGHT)[..., None]).astype(np.float32)

    def at(self, pts: np.ndarray) -> np.ndarray:
        """Model UV points [N, 2] in texel coordinates (x, y) of this splat."""
        return (pts - self.origin) / self.cell


def owned_points(
    uv: np.ndarray, correction: np.ndarray | None, owned: np.ndarray, frames: np.ndarray, t: int
) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``t``'s owned pixels with a finite UV: their model UV (``uv + correction``) [N, 2] and plate colour
    [N, C] (non-finite colours as 0), float64."""
    ys, xs = np.nonzero(owned[t])
    pts = uv[t, ys, xs].astype(np.float64)
    if correction is not None:
        pts += correction[t, ys, xs]
    keep = np.isfinite(pts).all(1)
    cols = np.nan_to_num(frames[t, ys[keep], xs[keep]].astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    return pts[keep], cols


def splat(
    uv: np.ndarray, correction: np.ndarray | None, owned: np.ndarray, frames: np.ndarray, step: float
) -> Splat | None:
    """The plate's colours at the ``owned`` pixels laid through ``uv + correction`` on texels ``step`` UV units wide
    (one working pixel: ``flow_reach.layer_scale``; wider where the layer's UVs spread over more than
    ``MAX_TEXELS``), frame by frame (what it holds beyond the texels is one frame's points). None when no owned pixel
    has a finite UV."""
    step = max(step, MIN_UV_PER_PX)
    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    for pts, _ in _frames(uv, correction, owned, frames):
        if len(pts):
            lo, hi = np.minimum(lo, pts.min(0)), np.maximum(hi, pts.max(0))
    if not np.isfinite(lo).all():
        return None
    start = np.floor(lo / step) - 1.0
    span = np.ceil(hi / step - start) + 2.0
    widen = max(1.0, math.sqrt(float(span[0] * span[1]) / MAX_TEXELS), float(span.max()) / (MAX_SIDE - 3))
    cell = step * widen
    w, h = (int(v) for v in np.ceil(span / widen) + 2)
    out = Splat(start * step, cell, np.zeros(h * w), np.zeros((h * w, frames.shape[-1])))
    for pts, cols in _frames(uv, correction, owned, frames):
        corner, frac = _corners(out.at(pts))
        for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
            share = (frac[:, 0] if dx else 1.0 - frac[:, 0]) * (frac[:, 1] if dy else 1.0 - frac[:, 1])
            at = (corner[:, 1] + dy) * w + corner[:, 0] + dx
            out.weight += np.bincount(at, share, h * w)
            for c in range(cols.shape[1]):
                out.colour[:, c] += np.bincount(at, share * cols[:, c], h * w)
    out.weight, out.colour = out.weight.reshape(h, w), out.colour.reshape(h, w, -1)
    return out


def _frames(
    uv: np.ndarray, correction: np.ndarray | None, owned: np.ndarray, frames: np.ndarray
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    for t in range(len(owned)):
        yield owned_points(uv, correction, owned, frames, t)


def _corners(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each point's texel corner (int) and where in the texel it lies ([0, 1) both ways)."""
    corner = np.floor(pts)
    return corner.astype(np.int64), pts - corner


def plate_texture(laid: Splat, frame: LayerFrame, network: np.ndarray) -> tuple[np.ndarray, float]:
    """The layer's atlas texture [H, W, 3] over ``frame``: at each texel centre the plate's mean colour that
    landed there (``laid``, read bilinearly as weighted sums, so a texel between two corners takes both in proportion
    to what landed on each), blended with the ``network``'s colour [H, W, 3] where less than ``FULL_WEIGHT`` landed,
    clipped to [0, 1] as the network's texture is written; and the share of texels that hold the plate in full."""
    centres = laid.at(frame.texel_centres().reshape(-1, 2)).astype(np.float32).reshape(*network.shape[:2], 2)
    mx, my = np.ascontiguousarray(centres[..., 0]), np.ascontiguousarray(centres[..., 1])

    def read(grid: np.ndarray) -> np.ndarray:  # 0 beyond the splat: nothing landed there
        return cv2.remap(grid.astype(np.float32), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    weight = read(laid.weight)
    colour = np.stack([read(laid.colour[..., c]) for c in range(laid.colour.shape[-1])], -1)
    mean = colour / np.maximum(weight, MIN_WEIGHT)[..., None]
    full = np.clip(weight / FULL_WEIGHT, 0.0, 1.0)[..., None]
    out = np.clip(full * mean + (1.0 - full) * network, 0.0, 1.0).astype(np.float32)
    return out, float(np.mean(full >= 1.0))


__all__ = [
    "FULL_WEIGHT",
    "MAX_SIDE",
    "MAX_TEXELS",
    "MIN_WEIGHT",
    "Splat",
    "owned_points",
    "plate_texture",
    "splat",
]
