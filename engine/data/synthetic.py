"""Synthetic "plate with an object" clips with exact ground truth, for tests and the embedded demo.

A panning camera over an infinite analytic background texture, and an elliptical sprite with its own
texture sliding across the frame. Both textures are smooth closed-form functions evaluated at the exact
(possibly sub-pixel) texture coordinate of every pixel, so a texture point has the same colour in every
frame that shows it: no resampling error, which makes tracking and atlas tests exact. They are
band-limited (wavelengths >= 8 px, compact C2 bumps of radius >= 4 px) so optical flow sees clean motion.

Conventions: pixel centres are at integer coordinates (pixel ``[y, x]`` is the point ``(x, y)``).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .. import contract as C
from ..io.images import cv2_write

#: Bump when the textures or the file layout change: write_scene then rewrites existing demo folders.
SYNTHETIC_VERSION = 1
SCENE_JSON = "scene.json"
_FRAME_NAME = re.compile(r"^\d{5}\.png$")
#: Band limits of both textures (so optical flow sees clean motion): no wave shorter than this...
MIN_WAVELENGTH_PX = 8.0
#: ...and no bump (a spot on the sprite) narrower than this radius.
MIN_BUMP_RADIUS_PX = 4.0
#: Background blobs: about one per square of this side, scattered over every texture point a frame shows and a
#: margin of this many pixels around them.
BLOB_SPACING_PX = 44.0
BLOB_MARGIN_PX = 30.0
#: The random streams of the background and of the sprite, each seeded with (spec.seed, stream), so a change to
#: one texture's draws leaves the other as it was.
BACKGROUND_STREAM = 0x5CE4E
SPRITE_STREAM = 0x5941


@dataclass(frozen=True)
class SceneSpec:
    """Everything that decides a synthetic clip (the same spec always gives the same pixels)."""

    width: int = 192
    height: int = 108
    frames: int = 12
    #: Camera pan in px/frame: frame t shows the background shifted by ``t * bg_velocity``, so background
    #: content moves by ``-bg_velocity`` in the frame (its true flow).
    bg_velocity: tuple[float, float] = (2.0, 0.5)
    fg_start: tuple[float, float] = (50.0, 40.0)  # sprite bounding box top-left at frame 0 (px)
    fg_velocity: tuple[float, float] = (3.0, 1.0)  # sprite motion in the frame (its true flow), px/frame
    fg_size: tuple[int, int] = (40, 30)  # sprite ellipse bounding box w, h (px)
    seed: int = 0


def demo_spec() -> SceneSpec:
    """The embedded demo clip: a textured plate panning under an object a compositor would want out."""
    return SceneSpec(
        width=320,
        height=180,
        frames=24,
        bg_velocity=(2.5, 0.6),
        fg_start=(60.0, 50.0),
        fg_velocity=(4.0, 1.2),
        fg_size=(70, 50),
        seed=7,
    )


# --- analytic textures -------------------------------------------------------------------------------------


def _bump(x: np.ndarray, y: np.ndarray, cx: float, cy: float, r: float) -> np.ndarray:
    """Compact C2 bump (1 - d^2/r^2)^3: smooth, yet exactly 0 outside r, so culling it changes nothing."""
    d2 = ((x - cx) ** 2 + (y - cy) ** 2) / (r * r)
    return np.clip(1.0 - d2, 0.0, None) ** 3


def _squash(v: np.ndarray) -> np.ndarray:
    """Smoothly map any value into (0.1, 0.9) (0.5 -> 0.5) so colours never clip."""
    return 0.5 + 0.4 * np.tanh(2.0 * (v - 0.5))


@dataclass(frozen=True)
class _Waves:
    freq: np.ndarray  # [K, 2] radians per px
    phase: np.ndarray  # [K]
    amp: np.ndarray  # [K, 3]

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        out = np.zeros((*x.shape, 3))
        for (fx, fy), ph, amp in zip(self.freq, self.phase, self.amp, strict=True):
            out += np.sin(fx * x + fy * y + ph)[..., None] * amp
        return out


def _random_waves(rng: np.random.Generator, k: int, wl: tuple[float, float], amp: float) -> _Waves:
    wavelength = rng.uniform(*wl, size=k)
    angle = rng.uniform(0.0, np.pi, size=k)
    freq = np.stack((np.cos(angle), np.sin(angle)), -1) * (2.0 * np.pi / wavelength)[:, None]
    tint = 1.0 + rng.uniform(-0.25, 0.25, size=(k, 3))  # mostly luminance, a little colour
    return _Waves(freq, rng.uniform(0.0, 2.0 * np.pi, size=k), amp * tint * rng.uniform(0.5, 1.0, (k, 1)))


# Muted plate palette (moss, ochre, slate, terracotta, sand) vs. a saturated sprite palette.
_BG_PALETTE = np.array(
    [[0.33, 0.45, 0.25], [0.72, 0.58, 0.30], [0.35, 0.42, 0.55], [0.66, 0.38, 0.28], [0.80, 0.74, 0.60]]
)
_FG_STRIPES = np.array([[0.98, 0.52, 0.05], [0.85, 0.08, 0.55]])  # orange / magenta
_FG_SPOTS = np.array([[0.05, 0.85, 0.95], [0.98, 0.95, 0.10]])  # cyan / yellow


@dataclass(frozen=True)
class _Background:
    base: np.ndarray  # [3]
    waves: _Waves
    blobs: np.ndarray  # [N, 4]: cx, cy, radius, weight
    blob_rgb: np.ndarray  # [N, 3]

    def __call__(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Colour at arbitrary texture points ``x``, ``y`` (any matching shapes) -> [..., 3]."""
        c = self.base + self.waves(x, y)
        for (cx, cy, r, wgt), rgb in zip(self.blobs, self.blob_rgb, strict=True):
            g = (wgt * _bump(x, y, cx, cy, r))[..., None]
            c = c * (1.0 - g) + rgb * g
        return _squash(c)

    def grid(self, xv: np.ndarray, yv: np.ndarray) -> np.ndarray:
        """Same values as ``self(*meshgrid(xv, yv))`` ([len(yv), len(xv), 3]) for increasing ``xv``,
        ``yv``, but each bump is only evaluated in its bounding box (exact: it is 0 outside)."""
        x, y = np.meshgrid(xv, yv)
        c = self.base + self.waves(x, y)
        for (cx, cy, r, wgt), rgb in zip(self.blobs, self.blob_rgb, strict=True):
            i0, i1 = np.searchsorted(xv, cx - r, "left"), np.searchsorted(xv, cx + r, "right")
            j0, j1 = np.searchsorted(yv, cy - r, "left"), np.searchsorted(yv, cy + r, "right")
            if i0 >= i1 or j0 >= j1:
                continue
            win = c[j0:j1, i0:i1]
            g = (wgt * _bump(x[j0:j1, i0:i1], y[j0:j1, i0:i1], cx, cy, r))[..., None]
            c[j0:j1, i0:i1] = win * (1.0 - g) + rgb * g
        return _squash(c)


@dataclass(frozen=True)
class _Sprite:
    size: tuple[int, int]
    stripe_freq: np.ndarray  # [2] radians per px
    stripe_phase: float
    spots: np.ndarray  # [N, 3]: cx, cy, radius
    spot_rgb: np.ndarray  # [N, 3]
    stripes: tuple[tuple[float, float, float], ...] = tuple(map(tuple, _FG_STRIPES))

    def color(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        s = 0.5 + 0.5 * np.sin(self.stripe_freq[0] * u + self.stripe_freq[1] * v + self.stripe_phase)
        stripes = np.asarray(self.stripes)
        c = stripes[0] * (1.0 - s[..., None]) + stripes[1] * s[..., None]
        for (cx, cy, r), rgb in zip(self.spots, self.spot_rgb, strict=True):
            g = _bump(u, v, cx, cy, r)[..., None]
            c = c * (1.0 - g) + rgb * g
        # Gentle shading towards the rim reads as a rounded object; stays well inside [0, 1].
        shade = 1.0 - 0.25 * np.clip(self._q(u, v), 0.0, 1.0)
        return np.clip(c * shade[..., None], 0.0, 1.0)

    def _q(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        a, b = self.size[0] / 2.0, self.size[1] / 2.0
        return ((u - a) / a) ** 2 + ((v - b) / b) ** 2

    def coverage(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Anti-aliased ellipse coverage: a smooth step over ~1 px of (approximate) signed distance, centred on
        the outline: coverage is above one half (``contract.MASK_THRESHOLD``) exactly where the pixel centre is
        inside the ellipse."""
        a, b = self.size[0] / 2.0, self.size[1] / 2.0
        f = self._q(u, v) - 1.0
        grad = 2.0 * np.hypot((u - a) / (a * a), (v - b) / (b * b))
        dist = -f / np.maximum(grad, 1e-9)  # > 0 inside
        c = np.clip(dist + 0.5, 0.0, 1.0)
        return c * c * (3.0 - 2.0 * c)


@lru_cache(maxsize=16)
def _textures(spec: SceneSpec) -> tuple[_Background, _Sprite]:
    """Texture parameters, deterministic from the spec (the seed, and the pan for where blobs go)."""
    rng = np.random.default_rng([spec.seed, BACKGROUND_STREAM])
    base = _BG_PALETTE[rng.integers(len(_BG_PALETTE))] * 0.6 + 0.2
    waves_lo = _random_waves(rng, 5, (50.0, 160.0), 0.09)
    waves_mid = _random_waves(rng, 6, (MIN_WAVELENGTH_PX, 24.0), 0.03)
    waves = _Waves(
        np.concatenate((waves_lo.freq, waves_mid.freq)),
        np.concatenate((waves_lo.phase, waves_mid.phase)),
        np.concatenate((waves_lo.amp, waves_mid.amp)),
    )
    t_last = max(spec.frames - 1, 0)
    ends = (0.0, t_last * spec.bg_velocity[0]), (0.0, t_last * spec.bg_velocity[1])
    x0, x1 = min(ends[0]) - BLOB_MARGIN_PX, max(ends[0]) + spec.width + BLOB_MARGIN_PX
    y0, y1 = min(ends[1]) - BLOB_MARGIN_PX, max(ends[1]) + spec.height + BLOB_MARGIN_PX
    n = max(4, int((x1 - x0) * (y1 - y0) / BLOB_SPACING_PX**2))
    blobs = np.stack(
        (
            rng.uniform(x0, x1, n),
            rng.uniform(y0, y1, n),
            rng.uniform(14.0, 40.0, n),
            rng.uniform(0.5, 0.9, n),
        ),
        -1,
    )
    blob_rgb = _BG_PALETTE[rng.integers(len(_BG_PALETTE), size=n)] + rng.uniform(-0.06, 0.06, (n, 3))

    srng = np.random.default_rng([spec.seed, SPRITE_STREAM])
    w, h = spec.fg_size
    wavelength = max(MIN_WAVELENGTH_PX, min(w, h) / 3.0)
    angle = srng.uniform(0.2, 1.3)
    stripe_freq = np.array([np.cos(angle), np.sin(angle)]) * (2.0 * np.pi / wavelength)
    k = int(srng.integers(4, 7))
    radius = max(MIN_BUMP_RADIUS_PX, min(w, h) / 4.5)
    spots = np.stack(
        (
            srng.uniform(0.15 * w, 0.85 * w, k),
            srng.uniform(0.2 * h, 0.8 * h, k),
            srng.uniform(0.7, 1.2, k) * radius,
        ),
        -1,
    )
    spot_rgb = _FG_SPOTS[np.arange(k) % len(_FG_SPOTS)]
    sprite = _Sprite((w, h), stripe_freq, float(srng.uniform(0, 2 * np.pi)), spots, spot_rgb)
    return _Background(base, waves, blobs, blob_rgb), sprite


# --- scene -------------------------------------------------------------------------------------------------


@dataclass
class SyntheticScene:
    """A rendered clip and its ground truth (sprite coverage and both layers' exact motion)."""

    frames: np.ndarray  # float32 [T, H, W, 3] in [0, 1]
    masks: np.ndarray  # bool [T, H, W]: the sprite's coverage > contract.MASK_THRESHOLD
    bg_offset: np.ndarray  # float32 [T, 2]: frame pixel (x, y) shows background texture point (x+ox, y+oy)
    fg_offset: np.ndarray  # float32 [T, 2]: sprite top-left; frame (x, y) shows sprite texture (x-ox, y-oy)
    spec: SceneSpec

    def bg_point_in_frame(self, tex_xy: Any, t: int) -> np.ndarray:
        """Frame position of background texture point(s) ``tex_xy`` ([..., 2]) in frame ``t``."""
        return np.asarray(tex_xy, dtype=np.float64) - self.bg_offset[t].astype(np.float64)

    def fg_point_in_frame(self, tex_xy: Any, t: int) -> np.ndarray:
        """Frame position of sprite texture point(s) ``tex_xy`` ([..., 2]) in frame ``t``."""
        return np.asarray(tex_xy, dtype=np.float64) + self.fg_offset[t].astype(np.float64)

    def bg_color(self, tex_xy: Any) -> np.ndarray:
        """Exact background colour at texture point(s) ``tex_xy`` ([..., 2]) -> [..., 3] (the bg atlas)."""
        p = np.asarray(tex_xy, dtype=np.float64)
        return _textures(self.spec)[0](p[..., 0], p[..., 1])

    def fg_color(self, tex_xy: Any) -> np.ndarray:
        """Exact sprite colour at sprite texture point(s) ``tex_xy`` ([..., 2]) -> [..., 3] (the fg atlas)."""
        p = np.asarray(tex_xy, dtype=np.float64)
        return _textures(self.spec)[1].color(p[..., 0], p[..., 1])

    def true_flow(self, t: int) -> np.ndarray:
        """Ground-truth forward flow t -> t+1, float32 [H, W, 2]: sprite pixels move with the sprite, the
        rest with the background (also where the background is about to be covered)."""
        flow = np.empty((self.spec.height, self.spec.width, 2), dtype=np.float32)
        flow[...] = self.bg_offset[t] - self.bg_offset[t + 1]
        flow[self.masks[t]] = self.fg_offset[t + 1] - self.fg_offset[t]
        return flow


def paint_sprite(img: np.ndarray, sprite: _Sprite, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Composite ``sprite`` over ``img`` [H, W, 3] in place, pixel (y, x) showing its texture point
    (u[y, x], v[y, x]) with its anti-aliased coverage; returns the coverage [H, W]."""
    cov = sprite.coverage(u, v)
    inside = cov > 0.0
    if inside.any():
        c = cov[inside][:, None]
        img[inside] = c * sprite.color(u[inside], v[inside]) + (1.0 - c) * img[inside]
    return cov


def make_scene(spec: SceneSpec | None = None) -> SyntheticScene:
    """Render ``spec`` (default ``SceneSpec()``). Colours are computed in float64 then stored as float32."""
    spec = SceneSpec() if spec is None else spec
    if spec.width < 1 or spec.height < 1 or spec.frames < 1 or min(spec.fg_size) < 1:
        raise ValueError(f"scene sizes must be positive: {spec}")
    background, sprite = _textures(spec)
    t_idx = np.arange(spec.frames, dtype=np.float64)[:, None]
    bg_offset = t_idx * np.asarray(spec.bg_velocity, dtype=np.float64)
    fg_offset = np.asarray(spec.fg_start, dtype=np.float64) + t_idx * np.asarray(spec.fg_velocity, np.float64)
    ys, xs = np.mgrid[0 : spec.height, 0 : spec.width].astype(np.float64)
    xv, yv = np.arange(spec.width, dtype=np.float64), np.arange(spec.height, dtype=np.float64)
    frames = np.empty((spec.frames, spec.height, spec.width, 3), dtype=np.float32)
    masks = np.empty((spec.frames, spec.height, spec.width), dtype=bool)
    for t in range(spec.frames):
        img = background.grid(xv + bg_offset[t, 0], yv + bg_offset[t, 1])
        masks[t] = paint_sprite(img, sprite, xs - fg_offset[t, 0], ys - fg_offset[t, 1]) > C.MASK_THRESHOLD
        frames[t] = img
    return SyntheticScene(
        frames=frames,
        masks=masks,
        bg_offset=bg_offset.astype(np.float32),
        fg_offset=fg_offset.astype(np.float32),
        spec=spec,
    )


# --- files -------------------------------------------------------------------------------------------------


def _scene_meta(scene: SyntheticScene) -> dict[str, Any]:
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(scene.frames).tobytes())
    digest.update(np.ascontiguousarray(scene.masks).tobytes())
    meta = {
        "synthetic_version": SYNTHETIC_VERSION,
        "spec": asdict(scene.spec),
        "frames": int(scene.frames.shape[0]),
        "sha256": digest.hexdigest(),
    }
    return json.loads(json.dumps(meta))  # tuples -> lists, as they read back


def _already_written(folder: Path, meta: dict[str, Any], frames_dir: Path, masks_dir: Path) -> bool:
    try:
        old = json.loads((folder / SCENE_JSON).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    if old != meta:
        return False
    names = [f"{t:05d}.png" for t in range(meta["frames"])]
    return all((frames_dir / n).is_file() and (masks_dir / n).is_file() for n in names)


def write_pngs(frames: np.ndarray, frames_dir: Path, masks: dict[Path, np.ndarray], first: int = 0) -> None:
    """``frames`` [T, H, W, 3] as 8-bit sRGB ``frames_dir/00000.png ...``, and each folder's bool masks [T, H, W]
    as 0/255 PNGs with the same names (the folders must exist); numbered from ``first`` (a clip written a frame at
    a time)."""
    rgb8 = np.clip(np.rint(frames * 255.0), 0, 255).astype(np.uint8)
    for t in range(frames.shape[0]):
        cv2_write(frames_dir / f"{first + t:05d}.png", cv2.cvtColor(rgb8[t], cv2.COLOR_RGB2BGR))
        for folder, m in masks.items():
            cv2_write(folder / f"{first + t:05d}.png", np.where(m[t], 255, 0).astype(np.uint8))


def write_scene(scene: SyntheticScene, folder: Path) -> tuple[Path, Path]:
    """Write ``folder/frames/00000.png ...`` (8-bit sRGB) and ``folder/masks/00000.png ...`` (0/255).

    Idempotent: ``scene.json`` (written last) records the spec and a hash of the pixels; when it matches,
    nothing is rewritten, so the demo can be set up any number of times. Returns (frames_dir, masks_dir).
    """
    folder = Path(folder)
    frames_dir, masks_dir = folder / "frames", folder / "masks"
    meta = _scene_meta(scene)
    if _already_written(folder, meta, frames_dir, masks_dir):
        return frames_dir, masks_dir
    for d in (frames_dir, masks_dir):
        d.mkdir(parents=True, exist_ok=True)
        for old in d.iterdir():  # a previous, longer scene's frames would otherwise be read as part of this one
            if _FRAME_NAME.match(old.name):
                old.unlink()
    (folder / SCENE_JSON).unlink(missing_ok=True)
    write_pngs(scene.frames, frames_dir, {masks_dir: scene.masks})
    tmp = folder / f".{SCENE_JSON}.tmp"
    tmp.write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    os.replace(tmp, folder / SCENE_JSON)
    return frames_dir, masks_dir
