"""No stroke is ever lost (bpy 4.5 and 5.0): Import Atlas again, the import that ends a Fit, and Float Edit Layers
reload the edit images, so each saves the unsaved paint to its file first; paint with no file to go to makes them
refuse in one line, reloading nothing; Render refuses in one line when an edit layer's file is gone.

Painting operators cannot run headless (docs/blender-compat.md#painting): a stroke is its pixels, written into the
edit image as a brush would, and left unsaved."""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from helpers import as_operator, fake_python, polygon_mask  # noqa: E402
from neural_atlas.addon.core import needs  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402
from neural_atlas.addon.ops import import_run as import_ops  # noqa: E402
from neural_atlas.addon.ops import render as render_ops  # noqa: E402

#: The stroke: a 4x4 block at the atlas's bottom-left, as an 8-bit image stores it (sRGB, straight alpha).
RED = (1.0, 0.0, 0.0, 1.0)
#: A stroke on a float edit layer (linear, premultiplied): values no 8-bit image could hold.
FLOAT_PAINT = (0.125, 0.5, 2.5, 0.75)
N = 4


def _edit(layer: str = "Foreground"):
    return bpy.data.images[P.edit_image_name(layer)]


def _paint(rgba=RED, layer: str = "Foreground") -> None:
    """A stroke's pixels, left unsaved."""
    img = _edit(layer)
    w, h = img.size
    px = np.zeros(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    px = px.reshape(h, w, 4)
    px[:N, :N] = rgba
    img.pixels.foreach_set(px.ravel())
    img.update()
    assert img.is_dirty


def _stroke_in_image(rgba=RED, layer: str = "Foreground") -> np.ndarray:
    """The stroke's block as Blender's image holds it now (rows bottom-up)."""
    img = _edit(layer)
    w, h = img.size
    px = np.zeros(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    return px.reshape(h, w, 4)[:N, :N]


def _edit_file(layer: str = "Foreground") -> Path:
    return Path(bpy.path.abspath(_edit(layer).filepath))


def _assert_png_stroke(path: Path) -> None:
    on_disk = X.read_png_rgba8(path)[::-1][:N, :N]  # rows bottom-up, like image.pixels
    assert (on_disk == np.array([255, 0, 0, 255], np.uint8)).all(), path
    assert not _edit().is_dirty  # reloaded from the file that holds the stroke
    assert np.array_equal(_stroke_in_image(), np.broadcast_to(np.float32(RED), (N, N, 4)))


def _import(manifest) -> None:
    assert bpy.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}


def test_import_atlas_again_saves_the_paint_first(blender, tmp_path):
    manifest = X.make_export(tmp_path)
    _import(manifest)
    png = _edit_file()
    assert not (X.read_png_rgba8(png)[::-1][:N, :N] == (255, 0, 0, 255)).all()  # not there before
    _paint()
    _import(manifest)  # reloads the edit images
    assert _edit_file() == png
    _assert_png_stroke(png)


def test_the_import_after_a_finished_fit_saves_the_paint_first(blender, tmp_path, monkeypatch):
    """The fake engine's export rewrites the run's edit layers blank; the import after it saves the paint over them
    (the real engine never rewrites them) and reloads: the stroke is in the file and in Blender."""
    plate = Path(X.make_export(tmp_path / "src")).parents[3] / "plate" / f"{X.FRAMES[0]:05d}.png"
    clip = bpy.data.movieclips.load(str(plate))
    monkeypatch.setenv("NEURAL_ATLAS_ENGINE_PYTHON", fake_python(tmp_path))
    props = blender.context.scene.neural_atlas
    props.clip = clip
    layer = props.layers.add()
    layer.mask = polygon_mask(bpy.data, [(clip.frame_start, [(5, 5), (20, 5), (20, 15), (5, 15)])], X.W, X.H)
    props.run_dir = str(tmp_path / "run")
    assert bpy.ops.neural_atlas.fit("EXEC_DEFAULT") == {"FINISHED"}
    png = _edit_file()
    _paint()
    assert bpy.ops.neural_atlas.fit("EXEC_DEFAULT") == {"FINISHED"}  # finishes with an import of the new export
    assert _edit_file() == png
    _assert_png_stroke(png)


def test_float_edit_layers_on_then_import_keep_the_paint(blender, tmp_path):
    manifest = X.make_export(tmp_path)
    _import(manifest)
    png = _edit_file()
    _paint()
    assert bpy.ops.neural_atlas.float_edits("EXEC_DEFAULT") == {"FINISHED"}
    on_disk = X.read_png_rgba8(png)[::-1][:N, :N]  # the PNG was saved before the switch
    assert (on_disk == np.array([255, 0, 0, 255], np.uint8)).all()
    exr = _edit_file()
    assert exr.suffix == ".exr" and exr.parent == png.parent
    red = np.array(RED, np.float32)  # sRGB 1 is linear 1; opaque, so premultiplied is the same
    assert np.array_equal(X.read_exr_rgba(exr)[::-1][:N, :N], np.broadcast_to(red, (N, N, 4)))
    assert np.array_equal(_stroke_in_image(), np.broadcast_to(red, (N, N, 4))) and not _edit().is_dirty

    _paint(FLOAT_PAINT)  # a stroke on the float layer, unsaved
    _import(manifest)  # the EXR is reloaded
    want = np.broadcast_to(np.float32(FLOAT_PAINT), (N, N, 4))
    assert np.array_equal(X.read_exr_rgba(exr)[::-1][:N, :N], want)
    assert _edit_file() == exr and not _edit().is_dirty
    assert np.array_equal(_stroke_in_image(FLOAT_PAINT), want)


def test_paint_with_no_file_refuses_and_reloads_nothing(blender, tmp_path):
    """An edit image made in Blender (no file) with paint: Import Atlas refuses in one line and leaves it as it is."""
    manifest = X.make_export(tmp_path)
    _import(manifest)
    name = P.edit_image_name("Foreground")
    bpy.data.images.remove(_edit())
    made = bpy.data.images.new("made in Blender", 16, 16, alpha=True)
    made.name = name
    _paint()
    op = as_operator(import_ops.NEURALATLAS_OT_import, filepath=str(manifest), setup_paint=True, set_range=False)
    assert op.execute(blender.context) == {"CANCELLED"}
    want = f"Import Atlas would drop the unsaved paint of {name} (it has no file): "
    assert len(op.reports) == 1 and op.reports[0][0] == {"ERROR"} and op.reports[0][1].startswith(want)
    assert "\n" not in op.reports[0][1]
    assert _edit() == made and made.is_dirty  # not reloaded, not replaced
    assert np.array_equal(_stroke_in_image(), np.broadcast_to(np.float32(RED), (N, N, 4)))


def test_render_refuses_when_an_edit_layer_is_gone(blender, tmp_path):
    manifest = X.make_export(tmp_path)
    _import(manifest)
    png = _edit_file()
    shutil.move(png, tmp_path / "moved.png")
    line = needs.EDIT_GONE + os.path.normpath(str(png))
    assert not bpy.ops.neural_atlas.render.poll()  # greyed, saying which file
    with pytest.raises(RuntimeError, match=re.escape(line)):
        bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(tmp_path / "out"), file_format="png")
    out = tmp_path / "out2"
    op = as_operator(render_ops.NEURALATLAS_OT_render, directory=str(out), file_format="png")
    assert op.execute(blender.context) == {"CANCELLED"}  # a call that skips the poll
    assert op.reports == [({"ERROR"}, line)]
    assert not out.exists() and not (tmp_path / "out").exists()  # no frames
    shutil.move(tmp_path / "moved.png", png)
    assert bpy.ops.neural_atlas.render.poll()
