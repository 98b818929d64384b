"""Synthetic clips of the motions real clips show and a sliding sprite does not, with ground truth.

Six scenes, each one kind of foreground motion over a textured plate under a mild camera pan (so optical flow has
texture everywhere to lock on to):

    turning     a textured cylinder spinning about its vertical axis while it drifts: texture on one side turns
                away and new texture comes round the other (the object's visible side changes)
    deforming   a textured body under a smooth non-rigid warp (a wave running down it, a lean, squash and
                stretch): no similarity explains its motion
    small_fast  a small object (about 2% of the frame) on a curving path, 12 px or more per frame, spinning
    thin        a propeller-like cross of 3 px wide bars, turning while it drifts
    turning_depth  an elongated textured body turning 180 degrees about its vertical axis under a pinhole camera:
                from side-on through end-on to its other side, near parts larger, its two sides unlike each other
    limbs_jump  a torso with two limbs swinging across it in opposite phase (one in front of it, one behind)
                while the body jumps: parts hide each other and come back (``engine.bench.motion_bodies``)

Every scene is a forward model with an exact inverse: ``surface(t, x, y)`` gives the surface coordinate (the
object's texture coordinate, in texture pixels) and the anti-aliased coverage at any frame point, and
``position(t, uv)`` where a surface point is in frame ``t`` and whether the camera sees it. Frames are rendered
by sampling the analytic textures (``engine.data.synthetic``'s plate and sprite, a periodic one for the cylinder)
at the exact surface coordinate of every pixel, so a surface point has the same colour in every frame that shows
it. The ground truth is the surface-coordinate field (``gt_uv.npz``: NaN where the object is not visible), the
texture itself (``texture.png``, one texel per surface unit: re-sampled through the field it gives the object's
pixels) and TAP-Vid tracks of points spread over the object's parts (``tracks_tapvid.npz``), solved from the forward
model, so ``python -m engine.bench clips`` scores atlas tracking on them against chained optical flow with no other
code. ``masks/`` holds the exact visible object, ``masks_rough/`` the rough roto the ``clips`` bench makes of it by
default (``engine.bench.degrade``), for fitting a clip by hand as the bench does.

Conventions: a scene's own functions use points with pixel ``[y, x]`` at ``(x, y)`` (as ``engine.data.synthetic``);
tracks, ``colour_at`` and ``uv_at`` use the tracks' convention, pixel ``i``'s centre at ``i + 0.5``.
"""

from __future__ import annotations

import io
import os
import re
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from engine.bench.degrade import write_degraded
from engine.bench.motion_bodies import (
    BACK_LIMB,
    FRONT_LIMB,
    TORSO,
    Capsule,
    LimbsJump,
    TurningDepth,
    atlas_texture,
    solid_texture,
)
from engine.bench.motion_bodies import rotate as _rotate
from engine.bench.motion_bodies import smooth_coverage as _smooth_coverage
from engine.bench.tracking import Tracks, save_tracks
from engine.data.synthetic import (
    _FG_SPOTS,
    _FG_STRIPES,
    MIN_BUMP_RADIUS_PX,
    MIN_WAVELENGTH_PX,
    SceneSpec,
    _Background,
    _bump,
    _Sprite,
    _textures,
    write_pngs,
)
from engine.io.images import cv2_write

TURNING = "turning"
DEFORMING = "deforming"
SMALL_FAST = "small_fast"
THIN = "thin"
TURNING_DEPTH = "turning_depth"
LIMBS_JUMP = "limbs_jump"
KINDS: tuple[str, ...] = (TURNING, DEFORMING, SMALL_FAST, THIN, TURNING_DEPTH, LIMBS_JUMP)
#: Real-clip scale: the ``clips`` bench fits one of these in a few minutes with ``draft``.
DEFAULT_SIZE = (480, 272)
DEFAULT_FRAMES = 36
#: Camera pan, px per frame (x, y): frame t shows the plate shifted by t * PAN.
PAN = (1.0, 0.3)
#: Tracks per part of the object (one part but for limbs_jump), their query frames spread evenly over the clip
#: (TRACKS / QUERY_FRAMES points of each part each).
TRACKS = 16
QUERY_FRAMES = 4
#: A query point lies where the object covers its pixel fully (not on the anti-aliased rim).
FULL_COVERAGE = 0.999
#: ...at least this far inside the object's mask (px), or half its thickness for a thinner object: a point on the
#: rim is half background.
QUERY_MARGIN_PX = 4.0
#: Of an object in several parts, half of each query frame's points are ones hidden within this many frames of it
#: (when there are such points): the tracks then ask for a point through its disappearance and return.
NEIGHBOUR_FRAMES = 3
GT_UV_NPZ = "gt_uv.npz"
TRACKS_NPZ = "tracks_tapvid.npz"
TEXTURE_PNG = "texture.png"
#: The rough roto written beside the exact masks: the ``clips`` bench's default recipe, with its default seed.
ROUGH_MASKS = "masks_rough"
ROUGH_RECIPE = "dilated10_dropped10"
#: Per-layer masks of a scene whose object is better fitted as several layers (``masks_parts/NAME/``): the parts a
#: compositor would roto apart. On ``limbs_jump``, the limb that swings across the body, and the rest.
PART_MASKS = "masks_parts"
LIMBS_PARTS: dict[str, tuple[int, ...]] = {"body": (TORSO, BACK_LIMB), "front_limb": (FRONT_LIMB,)}
#: Zip members get this timestamp, so a rewritten clip's .npz files are byte-identical.
ZIP_DATE = (1980, 1, 1, 0, 0, 0)
_FRAME_NAME = re.compile(r"^\d{5}\.png$")

#: turning: the cylinder's radius and height as fractions of the frame height, its turn over the whole clip
#: (over 180 degrees: most of what frame 0 shows is hidden by the end), its drift (px/frame), and query points
#: within this angle of facing the camera (the limb is foreshortened to nothing).
CYLINDER_RADIUS = 0.16
CYLINDER_HEIGHT = 0.62
TURN_DEGREES = 200.0
CYLINDER_DRIFT = (1.5, 0.2)
QUERY_MAX_ANGLE_DEG = 60.0
#: deforming: the body's rest size (fractions of the frame height), the travelling wave's amplitude (px),
#: wavelength (fraction of the body height) and period (frames), the lean (px of horizontal shift per px of
#: height, at most), squash and stretch (relative) and its period (frames), and the drift (px/frame).
BODY_SIZE = (0.32, 0.6)
BEND_PX = 6.0
BEND_WAVELENGTH = 1.0
BEND_PERIOD = 12.0
LEAN = 0.08
SQUASH = 0.12
SQUASH_PERIOD = 16.0
BODY_DRIFT = (2.0, 0.3)
#: small_fast: the object's area as a fraction of the frame, its aspect (w / h), its slowest speed (px/frame,
#: chord between consecutive frames), and its spin (rad/frame).
SMALL_AREA = 0.02
SMALL_ASPECT = 1.25
SMALL_SPEED = 12.0
SMALL_SPIN = 0.05
#: thin: the bars' width (px), arm length (fraction of the frame height), spin (rad/frame) and drift (px/frame).
BAR_WIDTH = 3.0
ARM_LENGTH = 0.3
BAR_SPIN = 0.1
BAR_DRIFT = (2.5, 0.4)
#: turning_depth: the body's cross-section half axes and height (fractions of the frame height; at the axis' depth),
#: the camera's distance from the axis (in half lengths: 3 makes the near end 1.5 times and the far end 0.75 times
#: the scale of the axis when end-on), the turn over the whole clip and the axis' drift (px/frame).
DEPTH_HALF_LENGTH = 0.3
DEPTH_HALF_WIDTH = 0.15
DEPTH_HEIGHT = 0.42
CAMERA_DISTANCE = 3.0
DEPTH_TURN_DEGREES = 180.0
DEPTH_DRIFT = 1.5
#: limbs_jump: the torso's and the limbs' segment lengths and radii (fractions of the frame height), the hinges
#: (x in torso radii either side of its axis, y in torso lengths from its centre, up negative), the swing's
#: amplitude either side of hanging down and its period (frames), the jump's height (fraction of the frame height)
#: and period (frames), the drift (px/frame), and the texels between the parts' texture regions.
TORSO_LENGTH = 0.3
TORSO_RADIUS = 0.12
LIMB_LENGTH = 0.36
LIMB_RADIUS = 0.045
HINGE = (0.35, -0.35)
SWING_DEGREES = 35.0
SWING_PERIOD = 24.0
JUMP_HEIGHT = 0.12
JUMP_PERIOD = 18.0
LIMBS_DRIFT = 1.5
ATLAS_GAP_PX = 8.0


@dataclass(frozen=True)
class MotionSpec:
    """Everything that decides a motion scene (the same spec always gives the same pixels). Object sizes scale
    with the frame; speeds, the bend amplitude and the bar width are in pixels whatever the size."""

    kind: str
    width: int = DEFAULT_SIZE[0]
    height: int = DEFAULT_SIZE[1]
    frames: int = DEFAULT_FRAMES
    seed: int = 0
    pan: tuple[float, float] = PAN

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown motion scene {self.kind!r}; known: {', '.join(KINDS)}")
        if self.width < 16 or self.height < 16 or self.frames < 2:
            raise ValueError(f"a motion scene needs at least 16x16 pixels and 2 frames: {self}")


# --- the first four scenes' forward models (the last two are engine.bench.motion_bodies') ------------------


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


def _plate_spec(spec: MotionSpec, fg_size: tuple[int, int]) -> SceneSpec:
    """The plate (panning with ``spec.pan``) and a sprite texture of ``fg_size`` from the shared synthetic code."""
    return SceneSpec(
        width=spec.width,
        height=spec.height,
        frames=spec.frames,
        bg_velocity=spec.pan,
        fg_size=fg_size,
        seed=spec.seed,
    )


def _turning(spec: MotionSpec) -> tuple[_Model, SceneSpec]:
    w, h, t_last = spec.width, spec.height, spec.frames - 1
    radius, height = CYLINDER_RADIUS * h, CYLINDER_HEIGHT * h
    period = 2.0 * np.pi * radius
    rng = np.random.default_rng([spec.seed, 0x7042])
    turns = max(1, round(period / max(MIN_WAVELENGTH_PX, height / 5.0)))
    n = 9
    spots = np.stack(
        (
            (np.arange(n) + rng.uniform(-0.2, 0.2, n)) * period / n,
            rng.uniform(0.15, 0.85, n) * height,
            np.maximum(MIN_BUMP_RADIUS_PX, rng.uniform(0.45, 0.7, n) * radius),
        ),
        -1,
    )
    rgb = np.concatenate((_FG_SPOTS, [[0.1, 0.2, 0.9], [0.1, 0.75, 0.2]]))[np.arange(n) % 4]
    texture = _WrappedTexture(period, turns, 2.0 * np.pi / (3.0 * height), float(rng.uniform(0, 2 * np.pi)), spots, rgb)
    start = (0.5 * w - CYLINDER_DRIFT[0] * t_last / 2.0, 0.5 * h - CYLINDER_DRIFT[1] * t_last / 2.0)
    model = _Turning(radius, height, start, CYLINDER_DRIFT, np.radians(TURN_DEGREES) / t_last, texture)
    return model, _plate_spec(spec, (round(2 * radius), round(height)))


def _deforming(spec: MotionSpec) -> tuple[_Model, SceneSpec]:
    w, h, t_last = spec.width, spec.height, spec.frames - 1
    size = (round(BODY_SIZE[0] * h), round(BODY_SIZE[1] * h))
    plate = _plate_spec(spec, size)
    start = (0.5 * w - BODY_DRIFT[0] * t_last / 2.0, 0.5 * h - BODY_DRIFT[1] * t_last / 2.0)
    model = _Deforming(
        _textures(plate)[1],
        start,
        BODY_DRIFT,
        BEND_PX,
        BEND_WAVELENGTH * size[1],
        BEND_PERIOD,
        LEAN,
        SQUASH,
        SQUASH_PERIOD,
    )
    return model, plate


def _small_fast(spec: MotionSpec) -> tuple[_Model, SceneSpec]:
    w, h = spec.width, spec.height
    sh = np.sqrt(4.0 * SMALL_AREA * w * h / (np.pi * SMALL_ASPECT))
    size = (round(SMALL_ASPECT * sh), round(sh))
    plate = _plate_spec(spec, size)
    rx, ry = 0.5 * w - 0.6 * size[0], 0.5 * h - 0.6 * size[1]
    # an elliptical orbit stepping a fixed angle per frame: the chord is shortest along the short radius, and there
    # it is SMALL_SPEED px
    step = 2.0 * np.arcsin(min(1.0, SMALL_SPEED / (2.0 * min(rx, ry))))
    phase0 = 0.3

    def path(t: float) -> tuple[float, float]:
        a = phase0 + step * t
        return 0.5 * w + rx * float(np.cos(a)), 0.5 * h + ry * float(np.sin(a))

    return _Rigid(_textures(plate)[1], path, SMALL_SPIN), plate


def _thin(spec: MotionSpec) -> tuple[_Model, SceneSpec]:
    w, h, t_last = spec.width, spec.height, spec.frames - 1
    arm = ARM_LENGTH * h
    side = round(2 * arm)
    plate = _plate_spec(spec, (side, side))
    half = BAR_WIDTH / 2.0

    def cross(uc: np.ndarray, vc: np.ndarray) -> np.ndarray:
        along_u = np.minimum(arm - np.abs(uc), half - np.abs(vc))
        along_v = np.minimum(arm - np.abs(vc), half - np.abs(uc))
        return np.maximum(along_u, along_v)

    x0, y0 = 0.5 * w - BAR_DRIFT[0] * t_last / 2.0, 0.5 * h - BAR_DRIFT[1] * t_last / 2.0

    def path(t: float) -> tuple[float, float]:
        return x0 + BAR_DRIFT[0] * t, y0 + BAR_DRIFT[1] * t

    return _Rigid(_textures(plate)[1], path, BAR_SPIN, cross), plate


def _turning_depth(spec: MotionSpec) -> tuple[_Model, SceneSpec]:
    w, h, t_last = spec.width, spec.height, spec.frames - 1
    a, b, height = DEPTH_HALF_LENGTH * h, DEPTH_HALF_WIDTH * h, DEPTH_HEIGHT * h
    texture = solid_texture(np.random.default_rng([spec.seed, 0xDE97]), a, b, height)
    model = TurningDepth(
        a,
        b,
        height,
        CAMERA_DISTANCE * a,
        -DEPTH_DRIFT * t_last / 2.0,  # world x = px from the optical axis at the axis' depth: centred mid-clip
        DEPTH_DRIFT,
        np.radians(DEPTH_TURN_DEGREES) / t_last,
        ((w - 1) / 2.0, (h - 1) / 2.0),
        texture,
    )
    return model, _plate_spec(spec, model.texture_size)


def _limbs_jump(spec: MotionSpec) -> tuple[_Model, SceneSpec]:
    w, h, t_last = spec.width, spec.height, spec.frames - 1
    lt, rt, ll, rl, gap = TORSO_LENGTH * h, TORSO_RADIUS * h, LIMB_LENGTH * h, LIMB_RADIUS * h, ATLAS_GAP_PX
    parts = (
        Capsule(lt, rt, (gap, gap)),
        Capsule(ll, rl, (2.0 * gap + 2.0 * rt, gap)),
        Capsule(ll, rl, (3.0 * gap + 2.0 * rt + 2.0 * rl, gap)),
    )
    size = (int(np.ceil(4.0 * gap + 2.0 * rt + 4.0 * rl)), int(np.ceil(2.0 * gap + max(lt + 2 * rt, ll + 2 * rl))))
    jump = JUMP_HEIGHT * h
    model = LimbsJump(
        parts,
        (0.5 * w - LIMBS_DRIFT * t_last / 2.0, 0.5 * h + jump / 2.0),  # the arcs centred on the frame
        LIMBS_DRIFT,
        jump,
        JUMP_PERIOD,
        (HINGE[0] * rt, HINGE[1] * lt),
        np.radians(SWING_DEGREES),
        SWING_PERIOD,
        atlas_texture(np.random.default_rng([spec.seed, 0x11B5]), parts, spots_per_part=4),
        size,
    )
    return model, _plate_spec(spec, size)


_BUILDERS: dict[str, Callable[[MotionSpec], tuple[_Model, SceneSpec]]] = {
    TURNING: _turning,
    DEFORMING: _deforming,
    SMALL_FAST: _small_fast,
    THIN: _thin,
    TURNING_DEPTH: _turning_depth,
    LIMBS_JUMP: _limbs_jump,
}
DESCRIPTIONS: dict[str, str] = {
    TURNING: f"a textured cylinder turning {TURN_DEGREES:g} degrees about its vertical axis while it drifts: its "
    "visible side changes (texture turns away, new texture comes round)",
    DEFORMING: f"a textured body bending under a travelling wave ({BEND_PX:g} px), leaning, squashing and "
    "stretching while it drifts: a non-rigid motion no similarity explains",
    SMALL_FAST: f"a small object ({SMALL_AREA:.0%} of the frame) on a curving path at {SMALL_SPEED:g} px/frame or "
    "more, spinning",
    THIN: f"a propeller-like cross of {BAR_WIDTH:g} px wide bars, turning {BAR_SPIN:g} rad/frame while it drifts",
    TURNING_DEPTH: f"an elongated textured body turning {DEPTH_TURN_DEGREES:g} degrees about its vertical axis under "
    "a pinhole camera, from side-on through end-on to its other side: near parts larger, its front half leaves the "
    "view and its back half enters",
    LIMBS_JUMP: f"a torso with two limbs swinging {SWING_DEGREES:g} degrees either way in opposite phase, one in "
    "front of it and one behind, while the body jumps: the limbs hide the torso and each other, and it comes back",
}


# --- the rendered scene ------------------------------------------------------------------------------------


@dataclass
class MotionScene:
    """A rendered motion scene and its ground truth."""

    spec: MotionSpec
    frames: np.ndarray  # float32 [T, H, W, 3] in [0, 1]
    masks: np.ndarray  # bool [T, H, W]: the object's coverage > 0.5 (the visible object)
    uv: np.ndarray  # float32 [T, H, W, 2]: the surface coordinate at each pixel centre, NaN off the object
    tracks: Tracks  # TAP-Vid tracks of points on the object, native pixels, centres at i + 0.5
    model: _Model
    background: _Background
    texture: np.ndarray  # float32 [Ht, Wt, 3]: texel [j, i] is the surface's colour at uv (i, j)

    @property
    def name(self) -> str:
        return self.spec.kind

    @property
    def description(self) -> str:
        return DESCRIPTIONS[self.spec.kind]

    def colour_at(self, t: int, xy: np.ndarray) -> np.ndarray:
        """The rendered colour of frame ``t`` at points ``xy`` [..., 2] (centres at i + 0.5), computed exactly as
        the frames are (the frames hold it at the pixel centres)."""
        p = np.asarray(xy, np.float64) - 0.5
        pan = np.asarray(self.spec.pan) * t
        plate = self.background(p[..., 0] + pan[0], p[..., 1] + pan[1])
        return _composite(self.model, t, p[..., 0], p[..., 1], plate)[0]

    def uv_at(self, t: int, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The exact surface coordinate [..., 2] and coverage [...] at points ``xy`` [..., 2] of frame ``t``."""
        p = np.asarray(xy, np.float64) - 0.5
        return self.model.surface(t, p[..., 0], p[..., 1])


def _composite(
    model: _Model, t: int, x: np.ndarray, y: np.ndarray, plate: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The object over ``plate`` [..., 3] at frame points ``x``, ``y``: colour, surface coordinate, coverage."""
    if isinstance(model, LimbsJump):  # parts over parts: each blends with its own coverage
        return model.composite(t, x, y, plate)
    uv, cov = model.surface(t, x, y)
    img = plate.copy()
    inside = cov > 0.0
    if inside.any():
        c = cov[inside][:, None]
        img[inside] = c * model.color(uv[inside]) + (1.0 - c) * plate[inside]
    return img, uv, cov


def _render(spec: MotionSpec, model: _Model, background: _Background) -> tuple[np.ndarray, ...]:
    """Frames, masks, the surface-coordinate field (NaN off the mask), the coverage and the part each pixel shows
    (-1 off the mask) of every frame."""
    t_n, h, w = spec.frames, spec.height, spec.width
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    xv, yv = np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)
    frames = np.empty((t_n, h, w, 3), np.float32)
    masks = np.empty((t_n, h, w), bool)
    uv_field = np.full((t_n, h, w, 2), np.nan, np.float32)
    cov_field = np.empty((t_n, h, w), np.float32)
    part_field = np.empty((t_n, h, w), np.int8)
    for t in range(t_n):
        plate = background.grid(xv + spec.pan[0] * t, yv + spec.pan[1] * t)  # = background(xs + ..., ys + ...)
        frames[t], uv, cov = _composite(model, t, xs, ys, plate)
        masks[t] = cov > 0.5
        uv_field[t][masks[t]] = uv[masks[t]]
        cov_field[t] = cov
        part_field[t] = model.visible_part(t, xs, ys) if isinstance(model, LimbsJump) else np.where(masks[t], 0, -1)
    return frames, masks, uv_field, cov_field, part_field


def _spread(points: np.ndarray, k: int) -> np.ndarray:
    """Indices of ``k`` of ``points`` [N, 2] spread over them: farthest-point sampling from the one nearest
    their centroid (deterministic)."""
    if len(points) <= k:
        return np.arange(len(points))
    chosen = [int(np.argmin(((points - points.mean(0)) ** 2).sum(-1)))]
    d2 = ((points - points[chosen[0]]) ** 2).sum(-1)
    for _ in range(k - 1):
        nxt = int(np.argmax(d2))
        chosen.append(nxt)
        d2 = np.minimum(d2, ((points - points[nxt]) ** 2).sum(-1))
    return np.asarray(chosen)


def _query_points(
    spec: MotionSpec, model: _Model, tq: int, cov: np.ndarray, part: np.ndarray, p: int, count: int
) -> list[np.ndarray]:
    """``count`` query pixels [2] (x, y) of part ``p`` in frame ``tq``, spread over it: fully covered pixel centres
    inside the part's visible region by QUERY_MARGIN_PX (or half its thickness). Of an object in several parts,
    half of them among those hidden within NEIGHBOUR_FRAMES of ``tq``, where there are such."""
    inside = (part == p).astype(np.uint8)
    depth = cv2.distanceTransform(np.pad(inside, 1), cv2.DIST_L2, 5)[1:-1, 1:-1]
    margin = min(QUERY_MARGIN_PX, 0.5 * float(depth.max()))
    ys, xs = np.nonzero((cov >= FULL_COVERAGE) & (depth >= margin) & (inside > 0))
    ok = model.query_ok(float(tq), xs.astype(np.float64), ys.astype(np.float64))
    if isinstance(model, LimbsJump):  # a part seen in a sliver has no margin: no rim of a part in front either
        ok &= model.unblended(float(tq), xs.astype(np.float64), ys.astype(np.float64))
    pts = np.stack((xs[ok], ys[ok]), -1).astype(np.float64)
    if model.n_parts == 1 or not len(pts):
        return [pts[i] for i in _spread(pts, count)]
    uv = model.surface(float(tq), pts[:, 0], pts[:, 1])[0]
    hidden = np.zeros(len(pts), bool)
    for t in range(max(0, tq - NEIGHBOUR_FRAMES), min(spec.frames, tq + NEIGHBOUR_FRAMES + 1)):
        hidden |= ~model.position(float(t), uv)[1]
    first = [pts[hidden][i] for i in _spread(pts[hidden], count // 2)]
    return first + [pts[~hidden][i] for i in _spread(pts[~hidden], count - len(first))]


def _ground_truth_tracks(spec: MotionSpec, model: _Model, cov: np.ndarray, part: np.ndarray) -> Tracks:
    """TRACKS points on each part of the object, QUERY_FRAMES query frames spread over the clip (``_query_points``);
    in every frame the point's exact position from the forward model, occluded where the camera does not see it
    (it faces away, or a part in front hides it), it leaves the frame or falls off the object's coverage."""
    t_n, h, w = spec.frames, spec.height, spec.width
    query_frames = np.unique(np.rint(np.linspace(0, t_n - 1, QUERY_FRAMES)).astype(int))
    per = -(-TRACKS // len(query_frames))
    queries, uvs = [], []
    for tq in query_frames:
        for k in range(model.n_parts):
            for x, y in _query_points(spec, model, int(tq), cov[tq], part[tq], k, per):
                queries.append((tq, x + 0.5, y + 0.5))
                uvs.append(model.surface(float(tq), x, y)[0])
    query = np.asarray(queries, np.float64)[: TRACKS * model.n_parts]
    uv = np.asarray(uvs, np.float64)[: TRACKS * model.n_parts]
    xy = np.empty((len(query), t_n, 2), np.float64)
    occluded = np.empty((len(query), t_n), bool)
    for t in range(t_n):
        p, facing = model.position(float(t), uv)
        _, c = model.surface(float(t), p[:, 0], p[:, 1])
        inside = (p[:, 0] >= -0.5) & (p[:, 0] < w - 0.5) & (p[:, 1] >= -0.5) & (p[:, 1] < h - 0.5)
        xy[:, t] = p + 0.5
        occluded[:, t] = ~(facing & inside & (c > 0.5))
    return Tracks(xy.astype(np.float32), occluded, query.astype(np.float32), (w, h), np.ones(len(query), dtype=bool))


def texture_image(model: _Model) -> np.ndarray:
    """The object's texture, float32 [Ht, Wt, 3]: texel [j, i] is the colour of surface coordinate (i, j)."""
    tw, th = model.texture_size
    u, v = np.meshgrid(np.arange(tw, dtype=np.float64), np.arange(th, dtype=np.float64))
    return np.clip(model.color(np.stack((u, v), -1)), 0.0, 1.0).astype(np.float32)


def make_motion_scene(spec: MotionSpec | str, **kw: Any) -> MotionScene:
    """Render one motion scene: a ``MotionSpec``, or a kind name and ``MotionSpec`` fields (width=..., ...)."""
    spec = MotionSpec(spec, **kw) if isinstance(spec, str) else spec
    model, plate = _BUILDERS[spec.kind](spec)
    background = _textures(plate)[0]
    frames, masks, uv, cov, part = _render(spec, model, background)
    tracks = _ground_truth_tracks(spec, model, cov, part)
    return MotionScene(spec, frames, masks, uv, tracks, model, background, texture_image(model))


# --- files -------------------------------------------------------------------------------------------------


def _repack_fixed_date(path: Path) -> None:
    """Rewrite the zip (.npz) at ``path`` with every member dated ZIP_DATE: numpy stamps the time of writing,
    which would make two writes of the same clip differ."""
    with zipfile.ZipFile(path) as z:
        members = [(i.filename, i.compress_type, z.read(i)) for i in z.infolist()]
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for name, compress_type, data in members:
            info = zipfile.ZipInfo(name, date_time=ZIP_DATE)
            info.compress_type = compress_type
            info.external_attr = 0o644 << 16
            z.writestr(info, data)
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(buf.getvalue())
    os.replace(tmp, path)


def part_masks(scene: MotionScene) -> dict[str, np.ndarray]:
    """The object's masks split into the parts ``PART_MASKS`` holds (bool [T, H, W] per part name: the pixels of the
    object whose true surface coordinate is on the part); empty for a scene of one part."""
    if not isinstance(scene.model, LimbsJump):
        return {}
    part = np.full(scene.masks.shape, -1, np.int64)
    known = np.isfinite(scene.uv).all(-1)
    part[known] = scene.model.part_of(scene.uv[known])
    return {name: np.isin(part, ids) & scene.masks for name, ids in LIMBS_PARTS.items()}


def write_motion_clip(scene: MotionScene, folder: str | Path) -> Path:
    """Write ``scene`` as a clip folder the ``clips`` bench reads: ``frames/00000.png ...`` (8-bit sRGB),
    ``masks/00000.png ...`` (0/255), ``masks_rough/`` (the same masks degraded by ROUGH_RECIPE), a scene of several
    parts ``masks_parts/PART/`` (``part_masks``), ``texture.png``
    (8-bit, the object's texture), ``tracks_tapvid.npz`` and ``gt_uv.npz`` (``uv`` float32 [T, H, W, 2], NaN off
    the object; ``kind``). Frame files of an earlier, longer clip there are removed; the same scene gives the
    same bytes. Returns the folder."""
    out = Path(folder)
    frames_dir, masks_dir, rough_dir = out / "frames", out / "masks", out / ROUGH_MASKS
    parts = {out / PART_MASKS / name: m for name, m in part_masks(scene).items()}
    for d in (frames_dir, masks_dir, rough_dir, *parts):
        d.mkdir(parents=True, exist_ok=True)
        for old in d.iterdir():
            if _FRAME_NAME.match(old.name):
                old.unlink()
    write_pngs(scene.frames, frames_dir, {masks_dir: scene.masks, **parts})
    write_degraded(masks_dir, rough_dir, ROUGH_RECIPE)
    texture8 = np.clip(np.rint(scene.texture * 255.0), 0, 255).astype(np.uint8)
    cv2_write(out / TEXTURE_PNG, cv2.cvtColor(texture8, cv2.COLOR_RGB2BGR))
    save_tracks(out / TRACKS_NPZ, scene.tracks)
    np.savez_compressed(out / GT_UV_NPZ, uv=scene.uv, kind=np.asarray(scene.spec.kind))
    for name in (TRACKS_NPZ, GT_UV_NPZ):
        _repack_fixed_date(out / name)
    return out


def write_motion_clips(
    root: str | Path,
    width: int = DEFAULT_SIZE[0],
    height: int = DEFAULT_SIZE[1],
    frames: int = DEFAULT_FRAMES,
    seed: int = 0,
    kinds: tuple[str, ...] = KINDS,
) -> list[Path]:
    """Every motion scene of ``kinds`` as a clip folder ``root/KIND``; returns the folders."""
    return [
        write_motion_clip(make_motion_scene(MotionSpec(kind, width, height, frames, seed)), Path(root) / kind)
        for kind in kinds
    ]


__all__ = [
    "DESCRIPTIONS",
    "GT_UV_NPZ",
    "KINDS",
    "PART_MASKS",
    "ROUGH_MASKS",
    "TEXTURE_PNG",
    "MotionScene",
    "MotionSpec",
    "make_motion_scene",
    "part_masks",
    "texture_image",
    "write_motion_clip",
    "write_motion_clips",
]
