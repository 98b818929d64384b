"""Import Atlas numbers the scene as the plate (bpy 4.5 and 5.0): an export of plate frames 1001..1003 at
24000/1001 with 2:1 pixels sets the scene range to 1001-1003, its rate to the exact fraction and its pixel aspect,
and the compositor shows plate frame F at scene frame F (the render of scene frame 1002 is plate frame 1002 edited).
A shot plate.1011.png .. plate.1022.png keeps its numbers end to end, and an artist's range within it is kept."""

from __future__ import annotations

import os

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from neural_atlas.addon import compat  # noqa: E402
from neural_atlas.addon.core import frames as F  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402
from neural_atlas.addon.ops.import_run import clip_note  # noqa: E402

from engine.terms.export_names import pass_file_name  # noqa: E402

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
    # the plate's files are 01001.png ..: five digits, as engine render pads them
    assert sorted(p.name for p in out.iterdir()) == [*(f"edit.{f:05d}.exr" for f in FRAMES), P.MATTES_DIR]
    assert [X.edit_file(manifest, f) for f in FRAMES] == [f"edit.{f:05d}.exr" for f in FRAMES]
    err = X.render_error(out, manifest, "nearest", frames=FRAMES)
    # each frame against the plate and passes of the NEIGHBOURING number: a shifted mapping would match these
    shifted = max(
        float(
            np.abs(
                X.read_exr_rgba(out / X.edit_file(manifest, f))[..., :3] - X.reference_frame(manifest, g, "nearest")
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


SHOT = tuple(range(1011, 1023))  # plate.1011.png .. plate.1022.png: positions 0..11, numbers 1011..1022


def _shot(blender, tmp_path):
    """A shot numbered plate.1011.png .. plate.1022.png, loaded as the artist loads it (Blender starts such a clip
    at scene frame 1, offset 0: measured on 4.5 and 5.0), and its export."""
    manifest = X.make_export(tmp_path, frames=SHOT, plate_name="plate.{frame}.png")
    artist_clip = blender.data.movieclips.load(str(tmp_path / "plate" / "plate.1011.png"))
    assert (artist_clip.source, artist_clip.frame_start, artist_clip.frame_offset) == ("SEQUENCE", 1, 0)
    assert artist_clip.frame_duration == len(SHOT)
    blender.context.scene.neural_atlas.filter_type = P.FILTER_NEAREST
    return manifest


def _shifted(out, manifest, pairs) -> float:
    """The smallest difference of each rendered frame F against the render equation of plate frame G != F."""
    return min(
        float(
            np.abs(
                X.read_exr_rgba(out / X.edit_file(manifest, f))[..., :3] - X.reference_frame(manifest, g, "nearest")
            ).max()
        )
        for f, g in pairs
    )


def test_a_shot_keeps_its_frame_numbers_end_to_end(blender, tmp_path):
    """Blender's 1-250 becomes the shot's 1011-1022 (not the positions 10-21); the plate clip starts at 1011, the
    passes read file F at scene frame F, and the render writes edit.1011.exr .. edit.1022.exr (padded as the plate's
    files, as engine render names them), each the render equation of its own plate frame (1015 of plate and passes
    1015, not 1014 or 1016)."""
    manifest = _shot(blender, tmp_path)
    scene = blender.context.scene
    assert (scene.frame_start, scene.frame_end) == (1, 250)
    scene.neural_atlas.clip = blender.data.movieclips["plate.1011.png"]  # the panel's clip, as the fit had it
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    assert (scene.frame_start, scene.frame_end) == (1011, 1022)
    # the artist's own clip stays at scene frame 1 (what is drawn on it is keyed to scene frames): the import says so
    assert blender.data.movieclips["plate.1011.png"].frame_start == 1
    assert clip_note(blender.context) == F.clip_offset_note("plate.1011.png", 1, 1011, P.PLATE_CLIP)
    assert "view 'NA_Plate' in the Clip Editor" in clip_note(blender.context)
    clip = blender.data.movieclips[P.PLATE_CLIP]
    # the Clip Editor (as the compositor's Movie Clip node) shows file 1011 + (F - frame_start) at scene frame F
    assert (clip.frame_start, clip.frame_offset, clip.frame_duration) == (1011, 0, 12)
    assert os.path.basename(clip.filepath) == "plate.1011.png"
    passes = compat.scene_tree(scene).nodes["NA_Passes"]
    assert (passes.frame_start, passes.frame_duration, passes.frame_offset) == (1011, 12, 1010)
    assert os.path.basename(passes.image.filepath) == pass_file_name(1011)

    out = tmp_path / "out"
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="exr") == {"FINISHED"}
    assert sorted(p.name for p in out.iterdir()) == [*(f"edit.{f}.exr" for f in SHOT), P.MATTES_DIR]
    err = X.render_error(out, manifest, "nearest", frames=SHOT)
    at_1015 = X.render_error(out, manifest, "nearest", frames=(1015,))
    shifted = _shifted(out, manifest, ((1015, 1014), (1015, 1016), (1011, 1012), (1022, 1021)))
    print(f"{TAG} shot 1011-1022: max abs err {err:.2e}, frame 1015 {at_1015:.2e}, shifted by one {shifted:.2f}")
    assert err <= 5e-5 and at_1015 <= 5e-5 and shifted > 0.1


def test_the_artists_range_within_the_shot_is_left_alone(blender, tmp_path):
    """A range narrowed to 1014-1016 survives Import Atlas (and the render is those frames, each its own plate
    frame); Set Scene Range sets the shot's 1011-1022; a range outside the shot (10-21) becomes the shot's."""
    manifest = _shot(blender, tmp_path)
    scene = blender.context.scene
    scene.frame_start, scene.frame_end = 1014, 1016
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    assert (scene.frame_start, scene.frame_end) == (1014, 1016)
    out = tmp_path / "out"
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="exr") == {"FINISHED"}
    assert sorted(p.name for p in out.iterdir()) == ["edit.1014.exr", "edit.1015.exr", "edit.1016.exr", P.MATTES_DIR]
    assert X.render_error(out, manifest, "nearest", frames=(1014, 1015, 1016)) <= 5e-5

    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest), set_range=True) == {"FINISHED"}
    assert (scene.frame_start, scene.frame_end) == (1011, 1022)
    scene.frame_start, scene.frame_end = 10, 21
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    assert (scene.frame_start, scene.frame_end) == (1011, 1022)
