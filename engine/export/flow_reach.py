"""How far a layer's UV follows the flow at export: over a few frames, or along whole trajectories, whichever lays the
plate's colours on the atlas more consistently.

Over a few frames (``follow_flow.SHORT_WEIGHT``) the filter takes out a mapping's frame-to-frame jitter and keeps
the atlas's own placement over longer gaps. Along whole trajectories (``LONG_WEIGHT``, the gaps filled) a point
keeps nearly one UV over all the frames the flow carries it through. Where the fitted mapping cannot follow the
body (a camel turning towards the camera, a cow's legs, a dancer's spin) the long reach is what makes paint stick;
where the flow itself is lost (a small dog blurred behind a fence) it carries the flow's errors into every frame,
and where the object turns its back (a point leaves the view and comes back) the atlas places it better than any
trajectory. Neither reach wins on every clip (docs/accuracy-vs-time.md).

Each layer gets the reach that passes a test needing no ground truth, the principle the atlas itself rests on: the
plate's colours at every pixel the layer owns, in every frame, are splatted (bilinear) through the candidate UV into
texels one working pixel wide (``plate_splat``), and read back at the same UVs. A UV that gives one point of the
object one texel in every frame gathers one colour per texel and reads back sharp; one that gives a point several
texels, or several points one, blurs. The reach read back with the higher PSNR is followed, with one guard: the flow
follows colour, so the splat test alone leans to the long reach where the flow drifts along similar colours, and
then the trajectories carry points far from where the fit placed them on its canvas. The atlas network's colours
read at the moved UV say so: where they show the plate more than ``MAX_TEXTURE_LOSS_DB`` worse than at the
few-frames reach's UV (a body turning 180 degrees: its trajectories' mean UV lies 21 px from the fitted one, the
network's colours there 13 dB worse, and its paint 0.64 -> 0.58 along whole trajectories), the layer keeps to a few
frames.

Conventions as in ``follow_flow``: working-size arrays, ``uv`` [T, H, W, 2] in the model's atlas units, ``owned``
[T, H, W] bool, ``frames`` [T, H, W, 3] the plate's values as the fit reads them (``prepare.to_fitting_values``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..data.flow import FlowField, sample_points
from .follow_flow import LONG_WEIGHT, SHORT_WEIGHT, follow_flow, uv_per_px
from .plate_splat import owned_points, splat

#: Reaches by name, as the export's messages say them.
SHORT, LONG = "over a few frames", "along whole trajectories"
#: A reconstruction error below this is taken as this (PSNR capped at 100 dB: identical colours).
MSE_FLOOR = 1e-10
#: The long reach is not followed where the plate read through the layer's atlas network at its UV loses more than
#: this against the few-frames reach (half the signal's power; measured where it is followed: 0.8-2.0 dB, on a body
#: turning 180 degrees: 12.8 dB; docs/bench/experiments.md).
MAX_TEXTURE_LOSS_DB = 3.0
#: The texture guard reads this many of the layer's pixels (a fixed sample: the same for both reaches).
TEXTURE_SAMPLES = 200_000
#: Seed of that sample.
TEXTURE_SAMPLE_SEED = 0

#: The layer's atlas colour [N, 3] at atlas points [N, 2] (the model's units): ``sampling.colours_at``.
Colours = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Reach:
    """One layer's choice: the correction it follows (``follow_flow``'s), the test's PSNR of each reach and, where
    the long reach read back sharper, the plate's PSNR through the atlas network's colours at each reach's UV."""

    correction: np.ndarray
    name: str
    short_db: float | None
    long_db: float | None
    short_texture_db: float | None = None
    long_texture_db: float | None = None
    held: bool = False
    """The long reach read back sharper but was not followed: the guard (``MAX_TEXTURE_LOSS_DB``)."""

    @property
    def said(self) -> str:
        """The choice in a few words, for the export's message."""
        if self.short_db is None or self.long_db is None:
            return f"following the flow {self.name}"
        said = (
            f"following the flow {self.name} (the plate read back through the atlas: {self.long_db:.2f} dB "
            f"{LONG}, {self.short_db:.2f} dB {SHORT}"
        )
        if self.held:
            said += (
                f"; {LONG} the points drift from where the fit placed them: its atlas shows the plate "
                f"{self.long_texture_db:.2f} dB against {self.short_texture_db:.2f} dB"
            )
        return said + ")"


def splat_psnr(
    uv: np.ndarray, correction: np.ndarray, owned: np.ndarray, frames: np.ndarray, scale: float
) -> float | None:
    """PSNR (dB) of the plate's colours at the ``owned`` pixels read back from the texture they make through
    ``uv + correction`` (``plate_splat.splat``: texels ``scale`` UV units wide, one working pixel), the texture the
    mean of what landed, read back bilinearly at the same UVs. Frame by frame, so what it holds beyond the texture is
    one frame's. None when no owned pixel has a finite UV."""
    laid = splat(uv, correction, owned, frames, scale)
    if laid is None:
        return None
    texture = laid.texture()
    squared, count = 0.0, 0
    for t in range(len(owned)):
        pts, cols = owned_points(uv, correction, owned, frames, t)
        back = sample_points(texture, laid.at(pts))
        squared += float(np.sum((back - cols) ** 2))
        count += cols.size
    mse = squared / count
    return 10.0 * math.log10(1.0 / max(mse, MSE_FLOOR))


def layer_scale(uv: np.ndarray, owned: np.ndarray) -> float | None:
    """The layer's UV units per working pixel, the median over its frames (``uv_per_px``; None: too few pixels)."""
    scales = [s for t in range(len(uv)) if (s := uv_per_px(uv[t], owned[t])) is not None]
    return float(np.median(scales)) if scales else None


def texture_psnr(
    uv: np.ndarray, correction: np.ndarray, owned: np.ndarray, frames: np.ndarray, colours: Colours
) -> float | None:
    """PSNR (dB) of the plate at a fixed sample of the ``owned`` pixels (``TEXTURE_SAMPLES``) against the layer's
    atlas network's colour at ``uv + correction`` there: how well the canvas the fit placed the object on shows the
    plate through that UV. None when no owned pixel has a finite UV."""
    t_idx, ys, xs = _sample(owned)
    pts = uv[t_idx, ys, xs] + correction[t_idx, ys, xs]
    keep = np.isfinite(pts).all(1)
    if not keep.any():
        return None
    seen = np.asarray(colours(pts[keep]), np.float64)
    mse = float(np.mean((seen - frames[t_idx[keep], ys[keep], xs[keep]]) ** 2))
    return 10.0 * math.log10(1.0 / max(mse, MSE_FLOOR))


def _sample(owned: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, y, x) of about ``TEXTURE_SAMPLES`` of the ``owned`` pixels, each frame's share in proportion to what it
    owns, drawn frame by frame (what it holds beyond the sample is one frame's indices); the same for the same
    ``owned``."""
    counts = owned.reshape(len(owned), -1).sum(1)
    share = min(1.0, TEXTURE_SAMPLES / max(int(counts.sum()), 1))
    rng = np.random.default_rng(TEXTURE_SAMPLE_SEED)
    picked = []
    for t, count in enumerate(counts.tolist()):
        if count == 0:
            continue
        flat = np.flatnonzero(owned[t])
        take = flat if share >= 1.0 else rng.choice(flat, max(1, round(share * count)), replace=False)
        ys, xs = np.divmod(np.sort(take), owned.shape[2])
        picked.append((np.full(len(ys), t), ys, xs))
    if not picked:
        return (np.zeros(0, np.int64),) * 3
    t_idx, ys, xs = (np.concatenate(parts) for parts in zip(*picked, strict=True))
    return t_idx, ys, xs


def choose_reach(
    uv: np.ndarray, owned: np.ndarray, flow: FlowField, frames: np.ndarray | None, colours: Colours | None = None
) -> Reach:
    """The correction of the reach whose UV lays ``frames`` on the atlas more consistently (``splat_psnr``), unless
    along whole trajectories the layer's atlas network (``colours``) would show the plate ``MAX_TEXTURE_LOSS_DB``
    worse; over a few frames when there are no ``frames`` (the plate could not be read) or nothing to test."""
    short = follow_flow(uv, owned, flow, SHORT_WEIGHT)
    scale = None if frames is None else layer_scale(uv, owned)
    if frames is None or scale is None:
        return Reach(short, SHORT, None, None)
    short_db = splat_psnr(uv, short, owned, frames, scale)
    long = follow_flow(uv, owned, flow, LONG_WEIGHT, fill=True)
    long_db = splat_psnr(uv, long, owned, frames, scale)
    if short_db is None or long_db is None or long_db <= short_db:
        return Reach(short, SHORT, short_db, long_db)
    if colours is None:
        return Reach(long, LONG, short_db, long_db)
    short_tex = texture_psnr(uv, short, owned, frames, colours)
    long_tex = texture_psnr(uv, long, owned, frames, colours)
    if short_tex is not None and long_tex is not None and long_tex < short_tex - MAX_TEXTURE_LOSS_DB:
        return Reach(short, SHORT, short_db, long_db, short_tex, long_tex, held=True)
    return Reach(long, LONG, short_db, long_db, short_tex, long_tex)


__all__ = [
    "LONG",
    "MAX_TEXTURE_LOSS_DB",
    "SHORT",
    "TEXTURE_SAMPLES",
    "Colours",
    "Reach",
    "choose_reach",
    "layer_scale",
    "splat_psnr",
    "texture_psnr",
]
