"""A shot folder moved or copied keeps working (bpy 4.5 and 5.0): Import Atlas into a saved .blend stores every path
relative to it, so the folder (the .blend, the run folder and the plate) copied elsewhere and opened there, the
original deleted, renders the same pixels; the run folder moved on its own greys Render out with the line naming
the missing manifest, and Relink Run Folder points everything at the new place: the render is the same again.
A missing plate (which would render black) or atlas greys Render out too."""

from __future__ import annotations

import os
import re
import shutil

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from neural_atlas.addon.core import needs  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402

TAG = f"[bpy {bpy.app.version_string}]"


def _render(out) -> dict[str, np.ndarray]:
    assert bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="exr") == {"FINISHED"}
    return {p.name: X.read_exr_rgba(p) for p in sorted(out.glob("edit.*"))}


def _diff(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> float:
    assert sorted(a) == sorted(b) and a
    return max(float(np.abs(a[k] - b[k]).max()) for k in a)


def _refused(name: str, line: str) -> None:
    """Greyed out (poll False), and a script that calls it anyway gets the poll's line."""
    op = getattr(bpy.ops.neural_atlas, name)
    assert not op.poll(), name
    with pytest.raises(RuntimeError, match=re.escape(line[:200])):
        op("EXEC_DEFAULT")


def _panel() -> tuple[list[str], list[str]]:
    """The Paint & Render panel's labels and operators (a recording layout: no region is drawn headless)."""
    from helpers import RecordingLayout
    from neural_atlas.addon import ui

    calls = RecordingLayout().draw(ui.NEURALATLAS_PT_edit, bpy.context)
    labels = [kw.get("text", "") for name, _, kw in calls if name == "label"]
    return labels, [a[0] for name, a, _ in calls if name == "operator"]


def _our_paths() -> dict[str, str]:
    blocks = [*bpy.data.images, *bpy.data.movieclips]
    return {b.name: b.filepath for b in blocks if b.name.startswith(P.PREFIX) and b.filepath}


def test_a_copied_shot_renders_the_same_and_a_moved_run_folder_is_relinked(blender, tmp_path):
    shot = tmp_path / "shot"
    manifest = X.make_export(shot)
    blend = shot / "scene.blend"
    assert bpy.ops.wm.save_as_mainfile(filepath=str(blend)) == {"FINISHED"}
    bpy.context.scene.neural_atlas.filter_type = P.FILTER_NEAREST
    assert bpy.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    paths = _our_paths()
    # the plate clip, the passes, the atlases and the edit layers, and the manifest: all relative to the .blend
    assert {P.PLATE_CLIP, P.PASSES_IMAGE, P.edit_image_name("Foreground"), P.atlas_image_name("Foreground")} <= set(
        paths
    )
    assert all(p.startswith("//") for p in paths.values()), paths
    assert bpy.context.scene.neural_atlas.manifest == "//run/exports/v001/manifest.json"
    assert bpy.ops.wm.save_mainfile() == {"FINISHED"}
    original = _render(tmp_path / "out_original")
    assert X.render_error(tmp_path / "out_original", manifest, "nearest") <= 5e-5  # the edit, not the bare plate

    # the whole shot folder copied elsewhere, opened there, the original deleted
    copy = tmp_path / "elsewhere" / "shot_copy"
    shutil.copytree(shot, copy)
    shutil.rmtree(shot)
    assert bpy.ops.wm.open_mainfile(filepath=str(copy / "scene.blend")) == {"FINISHED"}
    assert bpy.ops.neural_atlas.render.poll()
    copied = _render(tmp_path / "out_copy")
    err_copy = _diff(copied, original)
    assert err_copy == 0.0

    # only the run folder moved: Render is greyed out with the line naming the missing manifest
    moved = tmp_path / "moved" / "run_moved"
    moved.parent.mkdir()
    shutil.move(str(copy / "run"), str(moved))
    gone = os.path.normpath(str(copy / "run" / "exports" / "v001" / "manifest.json"))
    _refused("render", needs.MANIFEST_GONE + gone)
    labels, ops_drawn = _panel()
    assert needs.MANIFEST_GONE + gone in labels and "neural_atlas.relink" in ops_drawn  # the panel says so
    assert needs.moved_need(gone, str(copy / "run" / "exports" / "v001" / "passes" / "x")) == needs.MANIFEST_GONE + gone
    # Relink with the run folder (its newest export's manifest is found)
    assert bpy.ops.neural_atlas.relink("EXEC_DEFAULT", filepath=str(moved)) == {"FINISHED"}
    props = bpy.context.scene.neural_atlas
    assert props.manifest == "//../../moved/run_moved/exports/v001/manifest.json"
    relinked = _our_paths()
    assert relinked[P.PLATE_CLIP] == paths[P.PLATE_CLIP]  # the plate did not move: its path is kept
    assert relinked[P.PASSES_IMAGE].startswith("//../../moved/run_moved/")
    assert not any(line.startswith(needs.MANIFEST_GONE) for line in _panel()[0])
    err_relinked = _diff(_render(tmp_path / "out_relinked"), original)
    print(f"{TAG} copied shot vs original render: max abs diff {err_copy:.2e}; relinked run folder: {err_relinked:.2e}")
    assert err_relinked == 0.0

    # the plate gone: it would render black, so Render refuses naming it; an atlas gone, the same
    plate = bpy.path.abspath(bpy.data.movieclips[P.PLATE_CLIP].filepath)
    shutil.move(os.path.dirname(plate), str(tmp_path / "plate_away"))
    _refused("render", needs.PLATE_GONE + os.path.normpath(plate))
    shutil.move(str(tmp_path / "plate_away"), os.path.dirname(plate))
    atlas = os.path.normpath(bpy.path.abspath(bpy.data.images[P.atlas_image_name("Foreground")].filepath))
    os.rename(atlas, atlas + ".away")
    _refused("render", needs.ATLAS_GONE + atlas)
    os.rename(atlas + ".away", atlas)
    assert bpy.ops.neural_atlas.render.poll()


def test_relink_keeps_unsaved_paint(blender, tmp_path):
    """An edit image with paint not yet saved is not reloaded from the new place: the stroke (its pixels written, as
    painting cannot run headless) stays in the image, and Save Edits writes it to the relinked file."""
    shot = tmp_path / "shot"
    manifest = X.make_export(shot)
    assert bpy.ops.wm.save_as_mainfile(filepath=str(shot / "scene.blend")) == {"FINISHED"}
    assert bpy.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    img = bpy.data.images[P.edit_image_name("Foreground")]
    px = np.zeros(img.size[0] * img.size[1] * 4, np.float32)
    img.pixels.foreach_get(px)
    px[:4] = (1.0, 0.0, 0.0, 1.0)
    img.pixels.foreach_set(px)
    img.update()
    assert img.is_dirty
    moved = tmp_path / "run_moved"
    shutil.move(str(shot / "run"), str(moved))
    assert bpy.ops.neural_atlas.relink("EXEC_DEFAULT", filepath=str(moved / "exports" / "v001" / "manifest.json")) == {
        "FINISHED"
    }
    assert img.is_dirty and img.pixels[0] == 1.0 and img.pixels[1] == 0.0
    assert bpy.path.abspath(img.filepath) == str(moved / "edits" / "Foreground.png").replace(os.sep, "/") or (
        os.path.normpath(bpy.path.abspath(img.filepath)) == os.path.normpath(str(moved / "edits" / "Foreground.png"))
    )
    assert bpy.ops.neural_atlas.save_edits("EXEC_DEFAULT") == {"FINISHED"}
    saved = X.read_png_rgba8(moved / "edits" / "Foreground.png")
    assert tuple(saved[-1, 0]) == (255, 0, 0, 255)  # bottom-left texel (Blender's rows are bottom-up)
    assert not (shot / "run").exists()  # nothing written at the old place


def test_an_import_before_the_first_save_becomes_relative_when_saved(blender, tmp_path):
    """Imported into a .blend never saved (absolute paths: nothing to be relative to), then saved into the shot
    folder: the file holds the manifest and every NA_ image and clip relative to it, a Save Copy elsewhere leaves
    the open file's own paths, and the copied folder renders the same."""
    shot = tmp_path / "shot"
    manifest = X.make_export(shot)
    bpy.context.scene.neural_atlas.filter_type = P.FILTER_NEAREST
    assert bpy.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    assert bpy.context.scene.neural_atlas.manifest == str(manifest)
    assert not any(p.startswith("//") for p in _our_paths().values())
    assert bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "elsewhere.blend"), copy=True) == {"FINISHED"}
    assert bpy.context.scene.neural_atlas.manifest == str(manifest)  # a copy: the open file is unchanged
    assert not any(p.startswith("//") for p in _our_paths().values())
    assert bpy.ops.wm.save_as_mainfile(filepath=str(shot / "scene.blend")) == {"FINISHED"}
    assert bpy.context.scene.neural_atlas.manifest == "//run/exports/v001/manifest.json"
    assert all(p.startswith("//") for p in _our_paths().values()), _our_paths()
    original = _render(tmp_path / "out_original")
    copy = tmp_path / "copy"
    shutil.copytree(shot, copy)
    shutil.rmtree(shot)
    assert bpy.ops.wm.open_mainfile(filepath=str(copy / "scene.blend")) == {"FINISHED"}
    assert bpy.context.scene.neural_atlas.manifest == "//run/exports/v001/manifest.json"
    assert _diff(_render(tmp_path / "out_copy"), original) == 0.0
