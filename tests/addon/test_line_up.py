"""Line Up My Clip (bpy 4.5 and 5.0): a shot numbered plate.1011.png .. is loaded by Blender at scene frame 1, and the
artist's masks are keyed to scene frames 1..3. Import Atlas with Line Up My Clip starts the clip at 1011 (plate frame F
at scene frame F) and moves the masks' keys by the same 1010 frames: layer shape keys (the Clip Editor's mask tools)
and F-curves alike, and the clip's annotation (scribble) frames. Each mask rasterized at scene frame 1011..1013 after
equals the one at 1..3 before (pixel for pixel), so the masks stay on the object; without the option the clip and
masks are left alone and the import warns."""

from __future__ import annotations

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from helpers import polygon_mask, shape_key_mask  # noqa: E402
from neural_atlas.addon import compat, line_up, masks  # noqa: E402
from neural_atlas.addon.ops.import_run import clip_note  # noqa: E402

TAG = f"[bpy {bpy.app.version_string}]"
SHOT = tuple(range(1011, 1023))
W, H = X.W, X.H
CORNERS = [
    (1, [(2, 2), (10, 2), (10, 8), (2, 8)]),
    (2, [(6, 3), (14, 4), (14, 10), (5, 10)]),
    (3, [(1, 1), (8, 1), (8, 11), (1, 11)]),
]


def _shape_key_mask(clip):
    """A mask keyed with layer shape keys as the Clip Editor's mask tools key it (Insert Shape Key on each frame)."""
    return shape_key_mask(bpy, clip, CORNERS, W, H)


def _raster(mask, frames, folder) -> np.ndarray:
    names = [f"{f:05d}.png" for f in frames]
    paths = masks.rasterize(mask, W, H, list(frames), str(folder), names)
    out = []
    for path in paths:  # grey PNGs, read through Blender (its pixels: the stored values, rows bottom-up)
        img = bpy.data.images.load(path, check_existing=False)
        px = np.zeros(W * H * img.channels, np.float32)
        img.pixels.foreach_get(px)
        out.append(np.round(px.reshape(H, W, img.channels)[..., 0] * 255).astype(np.uint8))
        bpy.data.images.remove(img)
    return np.stack(out)


def _scene(blender, tmp_path):
    manifest = X.make_export(tmp_path, frames=SHOT, plate_name="plate.{frame}.png")
    clip = blender.data.movieclips.load(str(tmp_path / "plate" / "plate.1011.png"))
    assert clip.frame_start == 1
    props = blender.context.scene.neural_atlas
    props.clip = clip
    keyed = _shape_key_mask(clip)
    curved = polygon_mask(bpy.data, CORNERS, W, H)
    for mask in (keyed, curved):
        props.layers.add().mask = mask
    layer = compat.new_clip_annotation(clip, "Scribbles").layers.new("red")  # scribbles on scene frames 1 and 3
    for frame in (1, 3):
        layer.frames.new(frame)
    return manifest, clip, keyed, curved


def test_line_up_my_clip_moves_the_clip_and_its_masks_together(blender, tmp_path):
    manifest, clip, keyed, curved = _scene(blender, tmp_path)
    before = {m.name: _raster(m, (1, 2, 3), tmp_path / f"before_{m.name}") for m in (keyed, curved)}
    assert all(r.max() == 255 and r.min() == 0 for r in before.values())  # a mask, not an empty or full frame
    props = blender.context.scene.neural_atlas
    props.use_clip_range, props.frame_start, props.frame_end = False, 2, 3  # the fit's own range, in scene frames
    assert line_up.shape_key_frames(blender.context, clip, keyed) == [[1, 2, 3]]

    for spline in keyed.layers[0].splines:  # nothing selected, as after the artist clicked away
        for p in spline.points:
            p.select = False
    ret = bpy.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest), line_up_clip=True)
    assert ret == {"FINISHED"}
    assert clip.frame_start == 1011 and clip_note(blender.context) is None  # plate frame F at scene frame F
    assert line_up.shape_key_frames(blender.context, clip, keyed) == [[1011, 1012, 1013]]
    assert sorted({kp.co.x for fc in compat.action_fcurves(curved) for kp in fc.keyframe_points}) == [1011, 1012, 1013]
    assert (props.frame_start, props.frame_end) == (1012, 1013)  # the same plate frames
    assert [f.frame_number for f in compat.clip_annotation(clip).layers[0].frames] == [1011, 1013]
    assert not any(p.select for spline in keyed.layers[0].splines for p in spline.points)  # selection put back
    diffs = {}
    for mask in (keyed, curved):
        after = _raster(mask, (1011, 1012, 1013), tmp_path / f"after_{mask.name}")
        diffs[mask.name] = int(np.abs(after.astype(int) - before[mask.name].astype(int)).max())
    print(f"{TAG} masks at scene 1011-1013 after line-up vs 1-3 before: max abs pixel diff {diffs}")
    assert diffs == {keyed.name: 0, curved.name: 0}


def test_without_the_option_the_clip_and_masks_stay_and_the_import_says_so(blender, tmp_path):
    manifest, clip, keyed, curved = _scene(blender, tmp_path)
    assert bpy.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    assert clip.frame_start == 1 and clip_note(blender.context) is not None
    assert line_up.shape_key_frames(blender.context, clip, keyed) == [[1, 2, 3]]
    assert sorted({kp.co.x for fc in compat.action_fcurves(curved) for kp in fc.keyframe_points}) == [1, 2, 3]
    assert [f.frame_number for f in compat.clip_annotation(clip).layers[0].frames] == [1, 3]
