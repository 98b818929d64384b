"""Named synthetic scenes, each simulating exactly one effect a real clip can have.

A test about parallax should not also have to survive a moving object, a shadow and a pan; so each scene
here changes one thing from a still textured plate (the analytic textures of ``engine.data.synthetic``, exact at
sub-pixel positions) and says in its docstring what it tests. ``SCENES`` maps each name to its builder;
``make_named_scene(name)`` renders one. Sizes are small (default 96x64, 6 frames) so a test stays fast.

Conventions as in ``engine.data.synthetic``: pixel ``[y, x]`` is the point ``(x, y)``; frames float32 in [0, 1].
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from engine.data.synthetic import SceneSpec, _textures

#: Camera pan of the ``pan`` scene, px per frame (x, y): clearly above the scene
#: analysis's static threshold.
PAN_VELOCITY = (2.0, 0.5)
#: ``parallax``: the ground plane's horizontal speed grows from this at the top row to PARALLAX_BOTTOM at the
#: bottom (px/frame), like a camera trucking over a floor; no single similarity explains it.
PARALLAX_TOP = 0.5
PARALLAX_BOTTOM = 4.0
#: ``transparency``: the object's opacity (a pane of tinted glass).
TRANSPARENT_OPACITY = 0.5
#: ``shadow``: how much the shadow darkens the ground under it, and its offset from the object (px).
SHADOW_DARKENING = 0.45
SHADOW_OFFSET = (6.0, 8.0)
#: ``lighting``: the exposure multiplies by this over the clip (a cloud passing), linearly per frame.
LIGHTING_GAIN = (0.75, 1.15)


@dataclass
class NamedScene:
    """A rendered scene: frames, the object's mask (all False when there is no object), and its story."""

    name: str
    frames: np.ndarray  # float32 [T, H, W, 3]
    masks: np.ndarray  # bool [T, H, W]
    description: str
    has_object: bool


def _spec(width: int, height: int, frames: int, seed: int) -> SceneSpec:
    return SceneSpec(
        width=width,
        height=height,
        frames=frames,
        bg_velocity=(0.0, 0.0),
        fg_start=(width * 0.15, height * 0.3),
        fg_velocity=(3.0, 0.5),
        fg_size=(max(8, width // 4), max(6, height // 3)),
        seed=seed,
    )


def _plate(spec: SceneSpec, offset_x: np.ndarray, offset_y: np.ndarray) -> np.ndarray:
    """Background texture seen through per-pixel offsets ([H, W] each): frame pixel (x, y) shows (x+ox, y+oy)."""
    bg, _ = _textures(spec)
    ys, xs = np.mgrid[0 : spec.height, 0 : spec.width].astype(np.float64)
    return bg(xs + offset_x, ys + offset_y)


def _object(spec: SceneSpec, t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sprite in frame ``t``: colour [H, W, 3], coverage [H, W], top-left offset."""
    _, sprite = _textures(spec)
    off = np.asarray(spec.fg_start) + t * np.asarray(spec.fg_velocity)
    ys, xs = np.mgrid[0 : spec.height, 0 : spec.width].astype(np.float64)
    u, v = xs - off[0], ys - off[1]
    cov = sprite.coverage(u, v)
    return sprite.color(u, v), cov, off


def _render(
    spec: SceneSpec,
    name: str,
    description: str,
    plate: Callable[[int], np.ndarray],
    with_object: bool,
    opacity: float = 1.0,
    shadow: bool = False,
    occluder: tuple[int, int] | None = None,
) -> NamedScene:
    frames = np.empty((spec.frames, spec.height, spec.width, 3), np.float32)
    masks = np.zeros((spec.frames, spec.height, spec.width), bool)
    for t in range(spec.frames):
        img = plate(t)
        if with_object:
            col, cov, _ = _object(spec, t)
            if shadow:
                _, shadow_cov, _ = _object(
                    SceneSpec(**{**spec.__dict__, "fg_start": tuple(np.add(spec.fg_start, SHADOW_OFFSET))}), t
                )
                img = img * (1.0 - SHADOW_DARKENING * shadow_cov[..., None])
            a = opacity * cov[..., None]
            img = a * col + (1.0 - a) * img
            visible = cov > 0.5
            if occluder is not None:  # a still post in front of everything: part of the background
                x0, x1 = occluder
                img[:, x0:x1] = plate(0)[:, x0:x1] * 0.6
                visible[:, x0:x1] = False
            masks[t] = visible
        frames[t] = np.clip(img, 0.0, 1.0)
    return NamedScene(name, frames, masks, description, with_object)


def static_camera(width: int = 96, height: int = 64, frames: int = 6, seed: int = 0) -> NamedScene:
    """Tripod: the background never moves; one object slides across. Tests that the analysis calls the
    camera static (and that a near-identity background mapping reconstructs it)."""
    spec = _spec(width, height, frames, seed)
    zero = np.zeros((height, width))
    still = _plate(spec, zero, zero)
    return _render(spec, "static_camera", static_camera.__doc__ or "", lambda t: still, True)


def pan(width: int = 96, height: int = 64, frames: int = 6, seed: int = 0) -> NamedScene:
    """A pure camera pan (every background point moves by the same vector), one object. Tests that the
    analysis finds a similarity explains the background (pan/zoom), not a deformable motion."""
    spec = _spec(width, height, frames, seed)
    one = np.ones((height, width))
    vx, vy = PAN_VELOCITY
    return _render(spec, "pan", pan.__doc__ or "", lambda t: _plate(spec, one * vx * t, one * vy * t), True)


def parallax(width: int = 96, height: int = 64, frames: int = 6, seed: int = 0) -> NamedScene:
    """A camera trucking over a ground plane: near rows (bottom) move faster than far rows (top), no
    object. Tests that the analysis calls this deformable (no per-frame similarity explains it)."""
    spec = _spec(width, height, frames, seed)
    ys = np.mgrid[0:height, 0:width][0].astype(np.float64)
    speed = PARALLAX_TOP + (PARALLAX_BOTTOM - PARALLAX_TOP) * ys / max(height - 1, 1)
    zero = np.zeros((height, width))
    return _render(spec, "parallax", parallax.__doc__ or "", lambda t: _plate(spec, speed * t, zero), False)


def occlusion(width: int = 96, height: int = 64, frames: int = 6, seed: int = 0) -> NamedScene:
    """Static camera; the object passes behind a still post (a vertical bar of the background). Tests
    that the object's layer survives frames where part of it is hidden (its mask excludes the post)."""
    spec = _spec(width, height, frames, seed)
    zero = np.zeros((height, width))
    still = _plate(spec, zero, zero)
    post = (width // 2 - max(2, width // 16), width // 2 + max(2, width // 16))
    return _render(spec, "occlusion", occlusion.__doc__ or "", lambda t: still, True, occluder=post)


def shadow(width: int = 96, height: int = 64, frames: int = 6, seed: int = 0) -> NamedScene:
    """Static camera; the object casts a soft shadow that moves with it (the mask covers the object only).
    Tests where a moving darkening of the background ends up (the paper puts it in the object's layer)."""
    spec = _spec(width, height, frames, seed)
    zero = np.zeros((height, width))
    still = _plate(spec, zero, zero)
    return _render(spec, "shadow", shadow.__doc__ or "", lambda t: still, True, shadow=True)


def transparency(width: int = 96, height: int = 64, frames: int = 6, seed: int = 0) -> NamedScene:
    """Static camera; the object is half transparent (the background shows through it). Tests that alpha
    can settle between 0 and 1 instead of being forced binary."""
    spec = _spec(width, height, frames, seed)
    zero = np.zeros((height, width))
    still = _plate(spec, zero, zero)
    return _render(spec, "transparency", transparency.__doc__ or "", lambda t: still, True, opacity=TRANSPARENT_OPACITY)


def lighting_change(width: int = 96, height: int = 64, frames: int = 6, seed: int = 0) -> NamedScene:
    """Static camera, no object; the exposure ramps over the clip (a cloud passing). Tests that a global
    brightness change is not taken for motion (static camera, no foreground)."""
    spec = _spec(width, height, frames, seed)
    zero = np.zeros((height, width))
    still = _plate(spec, zero, zero)
    lo, hi = LIGHTING_GAIN
    gain = np.linspace(lo, hi, frames) if frames > 1 else np.array([1.0])
    return _render(spec, "lighting_change", lighting_change.__doc__ or "", lambda t: still * gain[t], False)


#: Every named scene, by name.
SCENES: dict[str, Callable[..., NamedScene]] = {
    "static_camera": static_camera,
    "pan": pan,
    "parallax": parallax,
    "occlusion": occlusion,
    "shadow": shadow,
    "transparency": transparency,
    "lighting_change": lighting_change,
}


def make_named_scene(name: str, **kw: int) -> NamedScene:
    """Render the scene called ``name`` (see ``SCENES``); an unknown name lists the known ones."""
    if name not in SCENES:
        raise ValueError(f"unknown scene {name!r}; known: {', '.join(SCENES)}")
    return SCENES[name](**kw)


__all__ = ["SCENES", "NamedScene", "make_named_scene"]
