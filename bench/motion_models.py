"""The forward models of the first four motion scenes (turning, deforming, small_fast, thin; the last two are
``bench.motion_bodies``'): each maps a frame point to the surface coordinate and coverage it shows
(``surface``) and a surface point to where it is in a frame and whether the camera sees it (``position``), exactly,
so the scenes' ground truth is solved rather than estimated."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bench.motion_bodies import LimbsJump, TurningDepth
from bench.motion_bodies import rotate as _rotate
from bench.motion_bodies import smooth_coverage as _smooth_coverage
from engine.data.synthetic import _FG_STRIPES, _bump, _Sprite

#: turning: query points lie within this angle of facing the camera (the limb is foreshortened to nothing).
QUERY_MAX_ANGLE_DEG = 60.0


@dataclass(frozen=True)
class _WrappedTexture:
    """A cylinder's texture in (arc length, height) px, periodic in arc length with period ``period``: stripes
    with a whole number of turns round the cylinder and spots whose distance wraps round, so there is no seam."""

    period: float
    turns: int
    stripe_rise: float  # radians per px of height
    phase: float
    spots: np.ndarray  # [N, 3]: arc length, height, radius
    spot_rgb: np.ndarray  # [N, 3]

    def color(self, s: np.ndarray, h: np.ndarray) -> np.ndarray:
        w = 0.5 + 0.5 * np.sin(2.0 * np.pi * self.turns * s / self.period + self.stripe_rise * h + self.phase)
        c = _FG_STRIPES[0] * (1.0 - w[..., None]) + _FG_STRIPES[1] * w[..., None]
        for (cs, ch, r), rgb in zip(self.spots, self.spot_rgb, strict=True):
            ds = (s - cs + self.period / 2.0) % self.period - self.period / 2.0
            g = _bump(ds, h, 0.0, ch, r)[..., None]
            c = c * (1.0 - g) + rgb * g
        return c


@dataclass(frozen=True)
class _Turning:
    """A vertical cylinder seen side-on (orthographic), turning by ``spin`` rad/frame while its axis drifts.
    Surface coordinate: (arc length R * theta in [0, 2 pi R), height from the top), theta the angle on the
    cylinder; the camera sees the half facing it, theta - spin * t within 90 degrees of the view direction."""

    radius: float
    height: float
    centre0: tuple[float, float]  # axis x and mid-height y at frame 0
    drift: tuple[float, float]
    spin: float
    texture: _WrappedTexture
    n_parts: int = 1

    @property
    def u_period(self) -> float:
        return 2.0 * np.pi * self.radius

    @property
    def texture_size(self) -> tuple[int, int]:
        return int(np.ceil(self.u_period)), int(np.ceil(self.height)) + 1

    def _centre(self, t: float) -> tuple[float, float]:
        return self.centre0[0] + self.drift[0] * t, self.centre0[1] + self.drift[1] * t

    def surface(self, t: float, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cx, cy = self._centre(t)
        dx, dy = x - cx, y - cy
        cov = _smooth_coverage(np.minimum(self.radius - np.abs(dx), self.height / 2.0 - np.abs(dy)))
        alpha = np.arcsin(np.clip(dx / self.radius, -1.0, 1.0))  # angle from the view direction
        period = 2.0 * np.pi * self.radius
        s = (self.radius * (alpha + self.spin * t)) % period
        return np.stack((s, dy + self.height / 2.0), -1), cov

    def position(self, t: float, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cx, cy = self._centre(t)
        alpha = (uv[..., 0] / self.radius - self.spin * t + np.pi) % (2.0 * np.pi) - np.pi
        xy = np.stack((cx + self.radius * np.sin(alpha), cy + uv[..., 1] - self.height / 2.0), -1)
        return xy, np.abs(alpha) < np.pi / 2.0

    def color(self, uv: np.ndarray) -> np.ndarray:
        return self.texture.color(uv[..., 0], uv[..., 1])

    def query_ok(self, t: float, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Query points face the camera within QUERY_MAX_ANGLE_DEG (not on the foreshortened limb)."""
        cx, _ = self._centre(t)
        return np.abs(x - cx) < self.radius * np.sin(np.radians(QUERY_MAX_ANGLE_DEG))


@dataclass(frozen=True)
class _Deforming:
    """The sprite's ellipse warped without any similarity in it: row v of the body (height from its centre)
    shifts sideways by a travelling wave ``bend * sin(2 pi v / wavelength - 2 pi t / period)`` and a lean
    ``lean(t) * v``, and the body squashes and stretches (area kept) while it drifts. Rows stay rows, so the
    inverse is exact: v from y, then u from x. Surface coordinate: the sprite texture's (u, v)."""

    sprite: _Sprite
    centre0: tuple[float, float]
    drift: tuple[float, float]
    bend: float
    wavelength: float
    bend_period: float
    lean: float
    squash: float
    squash_period: float
    n_parts: int = 1
    u_period: float | None = None

    @property
    def texture_size(self) -> tuple[int, int]:
        return self.sprite.size

    def _pose(self, t: float) -> tuple[float, float, float, float, float]:
        cx, cy = self.centre0[0] + self.drift[0] * t, self.centre0[1] + self.drift[1] * t
        sy = 1.0 + self.squash * np.sin(2.0 * np.pi * t / self.squash_period)
        lean = self.lean * np.sin(2.0 * np.pi * t / (1.7 * self.squash_period) + 0.6)
        return cx, cy, 1.0 / sy, sy, lean

    def _shift(self, t: float, vc: np.ndarray, lean: float) -> np.ndarray:
        k = 2.0 * np.pi / self.wavelength
        return self.bend * np.sin(k * vc - 2.0 * np.pi * t / self.bend_period) + lean * vc

    def surface(self, t: float, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cx, cy, sx, sy, lean = self._pose(t)
        vc = (y - cy) / sy
        uc = (x - cx - self._shift(t, vc, lean)) / sx
        w, h = self.sprite.size
        u, v = uc + w / 2.0, vc + h / 2.0
        return np.stack((u, v), -1), self.sprite.coverage(u, v)

    def position(self, t: float, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cx, cy, sx, sy, lean = self._pose(t)
        w, h = self.sprite.size
        uc, vc = uv[..., 0] - w / 2.0, uv[..., 1] - h / 2.0
        xy = np.stack((cx + sx * uc + self._shift(t, vc, lean), cy + sy * vc), -1)
        return xy, np.ones(uv.shape[:-1], bool)

    def color(self, uv: np.ndarray) -> np.ndarray:
        return self.sprite.color(uv[..., 0], uv[..., 1])

    def query_ok(self, t: float, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.ones(np.shape(x), bool)


@dataclass(frozen=True)
class _Rigid:
    """A rigid sprite: its centre on ``path(t)``, turned by ``spin * t``; ``shape`` gives the signed distance in
    px (> 0 inside) of a centred texture point, ``None`` for the sprite's own ellipse. Surface coordinate: the
    sprite texture's (u, v). Serves small_fast (the sprite's ellipse) and thin (a cross of bars)."""

    sprite: _Sprite
    path: Callable[[float], tuple[float, float]]
    spin: float
    shape: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    n_parts: int = 1
    u_period: float | None = None

    @property
    def texture_size(self) -> tuple[int, int]:
        return self.sprite.size

    def surface(self, t: float, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cx, cy = self.path(t)
        uc, vc = _rotate(x - cx, y - cy, -self.spin * t)
        w, h = self.sprite.size
        u, v = uc + w / 2.0, vc + h / 2.0
        cov = self.sprite.coverage(u, v) if self.shape is None else _smooth_coverage(self.shape(uc, vc))
        return np.stack((u, v), -1), cov

    def position(self, t: float, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cx, cy = self.path(t)
        w, h = self.sprite.size
        x, y = _rotate(uv[..., 0] - w / 2.0, uv[..., 1] - h / 2.0, self.spin * t)
        return np.stack((x + cx, y + cy), -1), np.ones(uv.shape[:-1], bool)

    def color(self, uv: np.ndarray) -> np.ndarray:
        return self.sprite.color(uv[..., 0], uv[..., 1])

    def query_ok(self, t: float, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.ones(np.shape(x), bool)


_Model = _Turning | _Deforming | _Rigid | TurningDepth | LimbsJump
