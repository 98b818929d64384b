"""Each kind of motion scene built from its ``MotionSpec``: the sizes, speeds and textures that make a scene the
motion it is named for, its forward model (``bench.motion_models``, ``bench.motion_bodies``), the
plate it moves over, and a line describing it."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from bench.motion_bodies import Capsule, LimbsJump, TurningDepth, atlas_texture, solid_texture
from bench.motion_models import _Deforming, _Model, _Rigid, _Turning, _WrappedTexture
from bench.motion_spec import DEFORMING, LIMBS_JUMP, SMALL_FAST, THIN, TURNING, TURNING_DEPTH, MotionSpec
from engine.data.synthetic import _FG_SPOTS, MIN_BUMP_RADIUS_PX, MIN_WAVELENGTH_PX, SceneSpec, _textures

#: turning: the cylinder's radius and height as fractions of the frame height, its turn over the whole clip
#: (over 180 degrees: most of what frame 0 shows is hidden by the end) and its drift (px/frame).
CYLINDER_RADIUS = 0.16
CYLINDER_HEIGHT = 0.62
TURN_DEGREES = 200.0
CYLINDER_DRIFT = (1.5, 0.2)
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


BUILDERS: dict[str, Callable[[MotionSpec], tuple[_Model, SceneSpec]]] = {
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
