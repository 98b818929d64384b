"""Float Edit Layers: the PNG paint (unsaved strokes included) becomes <Layer>.exr, linear and premultiplied;
the tree switches to it; the PNG gets the unsaved strokes first (saved, as before any reload); an existing EXR is
never replaced; the render uses it."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from neural_atlas.addon import edit_layers  # noqa: E402
from neural_atlas.addon.core import needs  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402
from neural_atlas.addon.ops.import_run import import_manifest  # noqa: E402

TAG = f"[bpy {bpy.app.version_string}]"


def test_float_edit_layers_convert_switch_and_never_overwrite(blender, tmp_path):
    manifest = X.make_export(tmp_path)
    blender.context.scene.neural_atlas.filter_type = P.FILTER_NEAREST
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    edits = tmp_path / "run" / "edits"

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
    png = X.read_png_rgba8(edits / "Foreground.png")[::-1]  # saved first: the PNG holds the stroke as painted
    assert np.array_equal(png, np.round(straight * 255).astype(np.uint8))
    for layer in ("Background", "Foreground"):
        img = bpy.data.images[P.edit_image_name(layer)]
        assert img.filepath.endswith(f"{layer}.exr") and img.colorspace_settings.name == "Non-Color"
        assert img.alpha_mode == "PREMUL"
    exr = X.read_exr_rgba(edits / "Foreground.exr")[::-1]  # rows bottom-up, like image.pixels
    a = straight[..., 3:4]
    want = np.concatenate((X.srgb_to_linear(straight[..., :3]) * a, a), -1)
    err = np.abs(exr - want).max()
    print(f"{TAG} Float Edit Layers: EXR vs exact decode x alpha of the painted pixels: {err:.2e}")
    assert err <= 1e-6 and np.abs(exr[0, 0] - want[0, 0]).max() <= 1e-6 and exr[0, 0, 3] == np.float32(128 / 255)

    stamp = os.stat(edits / "Foreground.exr").st_mtime_ns
    assert not blender.ops.neural_atlas.float_edits.poll()  # already float: greyed out, saying so
    with pytest.raises(RuntimeError, match=needs.ALL_FLOAT):
        blender.ops.neural_atlas.float_edits("EXEC_DEFAULT")
    assert os.stat(edits / "Foreground.exr").st_mtime_ns == stamp
    with pytest.raises(ValueError, match="already a float edit layer"):
        edit_layers.make_float_edit("Foreground")

    out = tmp_path / "out"
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="exr") == {"FINISHED"}
    decode = X.lut_decoder(X.blender_srgb_lut(bpy, tmp_path / "lut"))  # the plate is still an 8-bit sRGB PNG
    err = X.render_error(out, manifest, "nearest", decode)
    print(f"{TAG} render with float edit layers vs the equation (nearest): {err:.2e}")
    assert err <= 1e-5


def test_float_edit_layers_leave_an_edit_override_alone(blender, tmp_path):
    """A layer showing another image than the run's edit layer (headless --edit) is not converted, and stays."""
    manifest = X.make_export(tmp_path)
    edits = tmp_path / "run" / "edits"
    other = tmp_path / "elsewhere" / "edit_layers.png"
    other.parent.mkdir()
    shutil.copy(edits / "Foreground.png", other)
    import_manifest(blender.context, str(manifest), True, {"Foreground": str(other)})
    assert blender.ops.neural_atlas.float_edits("EXEC_DEFAULT") == {"FINISHED"}
    assert (edits / "Background.exr").exists()
    assert not (edits / "Foreground.exr").exists() and not (other.parent / "edit_layers.exr").exists()
    fg = bpy.data.images[P.edit_image_name("Foreground")]
    assert os.path.samefile(bpy.path.abspath(fg.filepath), other)
    assert bpy.data.images[P.edit_image_name("Background")].filepath.endswith("Background.exr")
