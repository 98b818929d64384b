"""Rasterize a Blender Mask datablock per frame into mask images the engine reads.

The compositor's Mask node (feather off, the scene's size) renders the mask exactly at pixel centres
(docs/blender-compat.md); it runs in a temporary scene so the artist's scene and compositor stay untouched.
Animated masks: layer shape keys (what the clip editor's mask tools key) are evaluated by an animation
render; F-curves are evaluated frame by frame and written into a temporary copy without animation data (the
artist's mask is never written, and no depsgraph update can put a stale frame's values back before the render).
Both are exact on every supported version (tests/addon/test_blender.py); a mask animated both ways at once is not
supported.
"""

from __future__ import annotations

import os
from typing import Any

import bpy

from . import compat, compositor
from .core import tree_plan as P

TEMP_SCENE = f"{P.PREFIX}MaskRaster"


def _apply_fcurves(source: Any, target: Any, frame: int) -> None:
    """Write ``source``'s F-curve values at ``frame`` into ``target`` (a copy of it), the datablock the node reads.

    The Mask node reads the original datablock; outside the window's scene its animation is not (4.x) or
    one frame late (frame_set in a second scene) evaluated into it, so the add-on evaluates it here.
    """
    for fc in compat.action_fcurves(source):
        try:
            prop = target.path_resolve(fc.data_path)
        except ValueError:
            continue
        value = fc.evaluate(frame)
        try:
            prop[fc.array_index] = value  # an array property (a point's co, a handle)
        except TypeError:  # a single value
            owner_path, _, attr = fc.data_path.rpartition(".")
            setattr(target.path_resolve(owner_path) if owner_path else target, attr, value)


def rasterize(mask: Any, width: int, height: int, scene_frames: list[int], out_dir: str, names: list[str]) -> list[str]:
    """Write ``out_dir/<name>`` (8-bit grey PNG, 255 inside) for each scene frame; returns the paths."""
    os.makedirs(out_dir, exist_ok=True)
    old = bpy.data.scenes.get(TEMP_SCENE)
    if old is not None:
        bpy.data.scenes.remove(old)
    scene = bpy.data.scenes.new(TEMP_SCENE)
    paths = []
    copy = None
    try:
        tree = compat.scene_tree(scene)
        node = tree.nodes.new("CompositorNodeMask")
        node.mask = mask
        compat.mask_node_setup(node)
        compositor.add_output(tree, node.outputs["Mask"])
        r = scene.render
        r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
        r.pixel_aspect_x = r.pixel_aspect_y = 1.0
        scene.view_settings.view_transform = "Standard"
        r.dither_intensity = 0.0
        r.compositor_device = "CPU"
        compat.set_render_format(scene, "png")
        r.image_settings.color_mode = "BW"
        r.use_file_extension = False
        if not compat.action_fcurves(mask) and scene_frames == list(range(scene_frames[0], scene_frames[-1] + 1)):
            # layer shape keys (the clip editor's own mask animation) are evaluated by an animation render
            scene.frame_start, scene.frame_end = scene_frames[0], scene_frames[-1]
            r.filepath = os.path.join(os.path.abspath(out_dir), "raw_#####")
            result = bpy.ops.render.render(animation=True, scene=scene.name)
            if "FINISHED" not in result:
                raise RuntimeError(f"rasterizing mask {mask.name!r} failed: {result}")
            for frame, name in zip(scene_frames, names, strict=True):
                paths.append(os.path.join(os.path.abspath(out_dir), name))
                os.replace(os.path.join(out_dir, f"raw_{frame:05d}"), paths[-1])
            return paths
        # F-curves: evaluated frame by frame into a copy that has no animation of its own (see _apply_fcurves)
        copy = mask.copy()
        copy.animation_data_clear()
        node.mask = copy
        for frame, name in zip(scene_frames, names, strict=True):
            scene.frame_set(frame)
            _apply_fcurves(mask, copy, frame)
            r.filepath = os.path.join(os.path.abspath(out_dir), name)
            result = bpy.ops.render.render(write_still=True, scene=scene.name)
            if "FINISHED" not in result:
                raise RuntimeError(f"rasterizing mask {mask.name!r} at frame {frame} failed: {result}")
            paths.append(r.filepath)
    finally:
        bpy.data.scenes.remove(scene)
        if copy is not None:
            bpy.data.masks.remove(copy)
    return paths
