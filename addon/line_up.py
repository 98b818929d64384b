"""Line Up My Clip: move the artist's own clip so it shows plate frame F at scene frame F, and move the animation of
the masks drawn on it, and its annotation strokes (the scribbles), by the same number of frames, so each stays on
the object it was drawn on.

A Blender Mask is animated two ways: layer shape keys (what the Clip Editor's mask tools key) and F-curves (a script's
``keyframe_insert``). F-curves are moved key by key. Shape keys have no Python API: each layer's keyed frames are found
with Blender's own keyframe jump in a Clip Editor showing the mask, its state read at each of them, the keys cleared
and inserted again the same number of frames later (the frames and states read first, so nothing is lost between).
Mask shapes interpolate linearly, so a frame found that held no key (the scene's own keys are jumped to as well)
is keyed with the value it already had: the animation is the same.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import bpy

from . import compat

#: How many keyframes of one mask layer are read at most (a guard against a jump that never ends).
MAX_KEYS = 100000


def shift_fcurves(mask: Any, offset: int) -> int:
    """Move every F-curve key of ``mask`` (and its handles) ``offset`` frames; returns how many keys moved."""
    moved = 0
    for fc in compat.action_fcurves(mask):
        for kp in fc.keyframe_points:
            kp.co.x += offset
            kp.handle_left.x += offset
            kp.handle_right.x += offset
            moved += 1
        fc.update()
    return moved


@contextmanager
def _clip_editor(context: Any, clip: Any) -> Iterator[tuple[Any, Any, Any]]:
    """A Clip Editor in Mask mode on ``clip`` (an open one, else the window's first area turned into one for the
    while): (area, its main region, its space); the area and space are put back as they were."""
    window = context.window
    areas = list(window.screen.areas)
    area = next((a for a in areas if a.type == "CLIP_EDITOR"), areas[0])
    old_type = area.type
    area.type = "CLIP_EDITOR"
    space = area.spaces.active
    saved = (space.mode, space.clip, space.mask)
    try:
        space.mode, space.clip = "MASK", clip
        region = next(r for r in area.regions if r.type == "WINDOW")
        yield area, region, space
    finally:
        space.mode, space.clip, space.mask = saved
        area.type = old_type


_POINT_ATTRS = ("co", "handle_left", "handle_right")


def _layer_state(layer: Any) -> list[list[tuple[Any, ...]]]:
    return [
        [(*(tuple(getattr(p, a)) for a in _POINT_ATTRS), p.weight) for p in spline.points] for spline in layer.splines
    ]


def _set_layer_state(layer: Any, state: list[list[tuple[Any, ...]]]) -> None:
    for spline, points in zip(layer.splines, state, strict=True):
        for p, (co, left, right, weight) in zip(spline.points, points, strict=True):
            p.co, p.handle_left, p.handle_right, p.weight = co, left, right, weight


def _jump_frames(scene: Any, run: Any) -> Iterator[int]:
    """The frames Blender's keyframe jump stops at, from the earliest on (the Clip Editor's mask layer's keys)."""
    scene.frame_set(-MAX_KEYS)
    for _ in range(MAX_KEYS):
        if run(bpy.ops.screen.keyframe_jump, next=True) != {"FINISHED"}:
            return
        yield scene.frame_current


@contextmanager
def _mask_operators(context: Any, clip: Any, mask: Any) -> Iterator[Any]:
    """A Clip Editor showing ``mask`` over ``clip``; yields ``run(op, **kwargs)``, which calls a mask or screen
    operator there. The mask's active layer and the scene's frame are put back afterwards."""
    scene, frame_before, active_before = context.scene, context.scene.frame_current, mask.layers.active
    with _clip_editor(context, clip) as (area, region, space):
        space.mask = mask

        def run(op: Any, **kwargs: Any) -> set[str]:
            with context.temp_override(window=context.window, area=area, region=region, space_data=space):
                return op(**kwargs)

        try:
            yield run
        finally:
            mask.layers.active = active_before
            scene.frame_set(frame_before)


def shape_key_frames(context: Any, clip: Any, mask: Any) -> list[list[int]]:
    """The frames of each layer's shape keys of ``mask`` (with any frame the scene itself keys), layer by layer."""
    frames = []
    with _mask_operators(context, clip, mask) as run:
        for layer in mask.layers:
            mask.layers.active = layer
            frames.append(list(_jump_frames(context.scene, run)))
    return frames


def shift_shape_keys(context: Any, clip: Any, mask: Any, offset: int) -> int:
    """Move the layer shape keys of ``mask`` ``offset`` frames (the module's docstring); returns how many moved."""
    scene = context.scene
    moved = 0
    with _mask_operators(context, clip, mask) as run:
        for layer in mask.layers:
            mask.layers.active = layer
            selected = [[p.select for p in spline.points] for spline in layer.splines]
            for spline in layer.splines:  # Insert Shape Key keys the selected points' layer: select them
                for p in spline.points:
                    p.select = True
            keys: list[tuple[int, Any]] = []
            for frame in list(_jump_frames(scene, run)):
                scene.frame_set(frame)  # applies the layer's shape at this frame to its points
                keys.append((frame, _layer_state(layer)))
            for frame, _ in keys:
                scene.frame_set(frame)
                run(bpy.ops.mask.shape_key_clear)
            for frame, state in keys:
                scene.frame_set(frame + offset)
                _set_layer_state(layer, state)
                if run(bpy.ops.mask.shape_key_insert) != {"FINISHED"}:
                    raise RuntimeError(f"mask {mask.name!r}: its shape key at frame {frame} could not be moved")
                moved += 1
            for spline, flags in zip(layer.splines, selected, strict=True):
                for p, flag in zip(spline.points, flags, strict=True):
                    p.select = flag
    return moved


def shift_annotation(clip: Any, offset: int) -> int:
    """Move the keyframes of the clip's annotation (the scribbles, keyed to scene frames) ``offset`` frames;
    returns how many moved. The last first when moving later (and the first first when earlier): no frame lands
    on one not moved yet."""
    annotation = compat.clip_annotation(clip)
    moved = 0
    for layer in annotation.layers if annotation is not None else ():
        frames = sorted(layer.frames, key=lambda f: f.frame_number, reverse=offset > 0)
        for frame in frames:
            frame.frame_number += offset
            moved += 1
    return moved


def line_up(context: Any, clip: Any, masks: list[Any], offset: int) -> tuple[int, int]:
    """Start ``clip`` ``offset`` frames later and move the animation of ``masks`` and the clip's annotation
    (scribbles) with it; (keys moved, masks). Each mask's own frame range moves too."""
    moved = shift_annotation(clip, offset)
    for mask in masks:
        moved += shift_fcurves(mask, offset)
        moved += shift_shape_keys(context, clip, mask, offset)
        # the end first when moving later (a start past the old end would push the end along), else the start first
        if offset > 0:
            mask.frame_end += offset
            mask.frame_start += offset
        else:
            mask.frame_start += offset
            mask.frame_end += offset
    clip.frame_start += offset
    return moved, len(masks)
