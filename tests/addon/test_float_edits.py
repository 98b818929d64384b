"""Float Edit Layers: the PNG paint (unsaved strokes included) becomes <Layer>.exr, linear and premultiplied;
the tree switches to it; the PNG is left alone; an existing EXR is never replaced; the render uses it."""

from __future__ import annotations

import os

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from fake_export import (  # noqa: E402
    FRAMES,
    blender_srgb_lut,
    lut_decoder,
    make_export,
    read_exr_rgba,
    reference_frame,
    srgb_to_linear,
)
from neural_atlas.addon import paint  # noqa: E402
from neural_atlas.addon import tree_plan as P  # noqa: E402

TAG = f"[bpy {bpy.app.version_string}]"


def test_float_edit_layers_convert_switch_and_never_overwrite(blender, tmp_path):
    manifest = make_export(tmp_path)
    blender.context.scene.neural_atlas.filter_type = P.FILTER_NEAREST
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    edits = tmp_path / "run" / "edits"
    png_bytes = (edits / "Foreground.png").read_bytes()

    img = bpy.data.images[P.edit_image_name("Foreground")]
    w, h = img.size
    px = np.zeros(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    px = px.reshape(h, w, 4)
    px[: h // 2, : w // 3] = (0.5, 0.25, 1.0, 0.5)  # an unsaved stroke (sRGB, straight alpha), bottom-left
    img.pixels.foreach_set(px.ravel())
    img.update()
    img.pixels.foreach_get(px.reshape(-1))  # what the byte image holds (8-bit quantised)
    straight = px.astype(np.float64)

    assert blender.ops.neural_atlas.float_edits("EXEC_DEFAULT") == {"FINISHED"}
    assert (edits / "Foreground.png").read_bytes() == png_bytes  # the PNG is never touched
    for layer in ("Background", "Foreground"):
        img = bpy.data.images[P.edit_image_name(layer)]
        assert img.filepath.endswith(f"{layer}.exr") and img.colorspace_settings.name == "Non-Color"
        assert img.alpha_mode == "PREMUL"
    exr = read_exr_rgba(edits / "Foreground.exr")[::-1]  # rows bottom-up, like image.pixels
    a = straight[..., 3:4]
    want = np.concatenate((srgb_to_linear(straight[..., :3]) * a, a), -1)
    err = np.abs(exr - want).max()
    print(f"{TAG} Float Edit Layers: EXR vs exact decode x alpha of the painted pixels: {err:.2e}")
    assert err <= 1e-6 and np.abs(exr[0, 0] - want[0, 0]).max() <= 1e-6 and exr[0, 0, 3] == np.float32(128 / 255)

    stamp = os.stat(edits / "Foreground.exr").st_mtime_ns
    assert blender.ops.neural_atlas.float_edits("EXEC_DEFAULT") == {"FINISHED"}  # already float: nothing to do
    assert os.stat(edits / "Foreground.exr").st_mtime_ns == stamp
    with pytest.raises(ValueError, match="already a float edit layer"):
        paint.make_float_edit("Foreground")

    out = tmp_path / "out"
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="exr") == {"FINISHED"}
    decode = lut_decoder(blender_srgb_lut(bpy, tmp_path / "lut"))  # the plate is still an 8-bit sRGB PNG
    errs = [
        np.abs(
            read_exr_rgba(out / f"edit.{f:05d}.exr")[..., :3] - reference_frame(manifest, f, "nearest", decode)
        ).max()
        for f in FRAMES
    ]
    print(f"{TAG} render with float edit layers vs the equation (nearest): {max(errs):.2e}")
    assert max(errs) <= 1e-5


def test_float_edit_layers_leave_an_edit_override_alone(blender, tmp_path):
    """A layer showing another image than the run's edit layer (headless --edit) is not converted, and stays."""
    import shutil

    from neural_atlas.addon import operators

    manifest = make_export(tmp_path)
    edits = tmp_path / "run" / "edits"
    other = tmp_path / "elsewhere" / "paint.png"
    other.parent.mkdir()
    shutil.copy(edits / "Foreground.png", other)
    operators.import_manifest(blender.context, str(manifest), True, {"Foreground": str(other)})
    assert blender.ops.neural_atlas.float_edits("EXEC_DEFAULT") == {"FINISHED"}
    assert (edits / "Background.exr").exists()
    assert not (edits / "Foreground.exr").exists() and not (other.parent / "paint.exr").exists()
    fg = bpy.data.images[P.edit_image_name("Foreground")]
    assert os.path.samefile(bpy.path.abspath(fg.filepath), other)
    assert bpy.data.images[P.edit_image_name("Background")].filepath.endswith("Background.exr")
