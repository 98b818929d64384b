"""Import Atlas numbers the scene as the plate (bpy 4.5 and 5.0): an export of plate frames 1001..1003 at
24000/1001 with 2:1 pixels sets the scene range to 1001-1003, its rate to the exact fraction and its pixel aspect,
and the compositor shows plate frame F at scene frame F (the render of scene frame 1002 is plate frame 1002 edited)."""

from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from neural_atlas.addon import compat  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402

FRAMES = (1001, 1002, 1003)
TIMING = {"rate": [24000, 1001], "fps": 24000 / 1001, "pixel_aspect": 2.0, "timecode": "01:00:00:00"}
TAG = f"[bpy {bpy.app.version_string}]"


def test_import_sets_the_scene_range_rate_and_aspect_of_the_plate(blender, tmp_path):
    manifest = X.make_export(tmp_path, frames=FRAMES, clip_fields=TIMING)
    scene = blender.context.scene
    scene.neural_atlas.filter_type = P.FILTER_NEAREST
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    assert (scene.frame_start, scene.frame_end) == (1001, 1003)
    r = scene.render
    assert (r.fps, r.fps_base) == (24000, 1001.0) and r.fps / r.fps_base == 24000 / 1001
    assert (r.pixel_aspect_x, r.pixel_aspect_y) == (2.0, 1.0)
    clip = blender.data.movieclips[P.PLATE_CLIP]
    assert clip.frame_start == 1001 and clip.frame_duration == 3
    passes = compat.scene_tree(scene).nodes["NA_Passes"]
    assert (passes.frame_start, passes.frame_duration, passes.frame_offset) == (1001, 3, 1000)

    out = tmp_path / "out"
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="exr") == {"FINISHED"}
    assert sorted(p.name for p in out.iterdir()) == [f"edit.{f:05d}.exr" for f in FRAMES]
    err = X.render_error(out, manifest, "nearest", frames=FRAMES)
    # each frame against the plate and passes of the NEIGHBOURING number: a shifted mapping would match these
    shifted = max(
        float(
            np.abs(
                X.read_exr_rgba(out / f"edit.{f:05d}.exr")[..., :3] - X.reference_frame(manifest, g, "nearest")
            ).max()
        )
        for f, g in ((1001, 1002), (1002, 1003), (1003, 1001))
    )
    print(
        f"{TAG} scene frames 1001-1003 vs plate frames 1001-1003: max abs err {err:.2e} (shifted by one: {shifted:.2f})"
    )
    assert err <= 5e-5 and shifted > 0.1


def test_a_plate_without_a_rate_keeps_the_scenes(blender, tmp_path):
    manifest = X.make_export(tmp_path, frames=FRAMES, clip_fields={"fps": None})
    scene = blender.context.scene
    scene.render.fps, scene.render.fps_base = 30, 1.0
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    assert (scene.render.fps, scene.render.fps_base) == (30, 1.0)
    assert (scene.render.pixel_aspect_x, scene.render.pixel_aspect_y) == (1.0, 1.0)
    assert (scene.frame_start, scene.frame_end) == (1001, 1003)
