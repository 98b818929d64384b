"""An artist's day in Blender, part 1 (bpy 4.5 and 5.0): what a file reopened, reverted, moved and relinked keeps.

- File > Open, File > Revert and opening another shot in a running Blender: the live preview shows that file's paint
  at once (its float twins are refilled on load), not a black plane;
- Relink Run Folder after the run folder moved without its plate: Live Preview, Import Atlas, Float Edit Layers and
  Paint on Frame work as before the move (the plate is where the scene's plate clip points); Paint on Frame that
  cannot show its paint refuses before it makes anything;
- a scene range wider than the export renders only the exported frames and says so;
- Blender's conventions: a Viewer node on the composite, Import Atlas sets the Run Folder and the current frame,
  Ctrl+S saves the edit layers' paint, Land Paint on Atlases takes a stroke at once, no colour-space warning on a
  preview render, the panel's render status after a render.

Painting operators cannot run headless (docs/blender-compat.md#painting): a stroke is its pixels, written into the
image as a brush would, and left unsaved. No timer fires headless: what the preview's timer would do is checked by
reading the float twins the preview material samples."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from neural_atlas.addon import preview_plane  # noqa: E402
from neural_atlas.addon.core import preview_plan as V  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402

from engine import contract as C  # noqa: E402

TAG = f"[bpy {bpy.app.version_string}]"
FRAME = X.FRAMES[1]


def _pixels(img) -> np.ndarray:
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    return px.reshape(h, w, 4)  # rows bottom-up


def _stroke(img, rgba: tuple[float, float, float, float], rows: slice = slice(0, 6)) -> None:
    """A stroke's pixels over the bottom rows of ``img``, left unsaved."""
    px = _pixels(img)
    px[rows] = rgba
    img.pixels.foreach_set(px.ravel())
    img.update()
    assert img.is_dirty


def _relative_manifest(manifest: Path) -> Path:
    """The manifest's paths relative to its folder, and the plate's also as they are now, as ``engine export``
    writes them (the tests' export writes the plate and edit layers absolute)."""
    data = json.loads(manifest.read_text())
    folder = manifest.parent

    def rel(path: str) -> str:
        return os.path.relpath(path, folder) if os.path.isabs(path) else path

    clip = data["clip"]
    clip["source_absolute"] = os.path.abspath(clip["source"])
    clip["frame_files_absolute"] = [os.path.abspath(p) for p in clip["frame_files"]]
    clip["source"] = rel(clip["source"])
    clip["frame_files"] = [rel(p) for p in clip["frame_files"]]
    data["run_dir"] = rel(data["run_dir"])
    for layer in data["layers"]:
        layer["edit_layer"] = rel(layer["edit_layer"])
    manifest.write_text(json.dumps(data, indent=2))
    return manifest


def _shot(blender, root: Path, seed: int, paint: tuple[float, float, float, float]) -> np.ndarray:
    """A shot saved as ``root/scene.blend``: imported with the live preview, painted, saved (Ctrl+S: the paint is
    saved with it); returns its preview render at ``FRAME``."""
    manifest = _relative_manifest(X.make_export(root, seed=seed))
    assert blender.ops.wm.save_as_mainfile(filepath=str(root / "scene.blend")) == {"FINISHED"}
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    _stroke(bpy.data.images[P.edit_image_name("Background")], paint)
    assert bpy.ops.neural_atlas.save_edits("EXEC_DEFAULT") == {"FINISHED"}
    assert blender.ops.wm.save_mainfile() == {"FINISHED"}
    return _preview(root / "before.exr")


def _preview(path: Path) -> np.ndarray:
    return X.read_exr_rgba(Path(preview_plane.render_frame(bpy.context.scene, FRAME, str(path))))


def _twins_show_the_paint() -> float:
    """The largest difference between each float twin and its edit image's pixels as the engine reads them."""
    worst = 0.0
    for layer in ("Background", "Foreground"):
        edit = _pixels(bpy.data.images[P.edit_image_name(layer)]).ravel()
        want = edit if bpy.data.images[P.edit_image_name(layer)].is_float else V.straight_srgb_to_premultiplied(edit)
        twin = _pixels(bpy.data.images[V.mirror_image_name(layer)]).ravel()
        worst = max(worst, float(np.abs(twin - want).max()))
    return worst


def test_the_preview_survives_open_revert_and_another_shot(blender, tmp_path):
    """Two shots saved; in the same Blender, open the first, revert it, open the second: each time the float twins
    hold the file's paint as soon as it is loaded (no stroke or timer needed), and the preview renders as it did
    before the file was closed."""
    want_b = _shot(blender, tmp_path / "b", 1, (0.0, 0.2, 1.0, 1.0))
    bpy.ops.wm.read_factory_settings(use_empty=True)
    want_a = _shot(blender, tmp_path / "a", 0, (1.0, 0.5, 0.0, 1.0))
    assert np.abs(want_a - want_b).max() > 0.3  # two different shots
    steps = (
        ("open", lambda: bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "a" / "scene.blend")), want_a),
        ("revert", lambda: bpy.ops.wm.revert_mainfile(), want_a),
        ("open another", lambda: bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "b" / "scene.blend")), want_b),
    )
    for step, load, want in steps:
        assert load() == {"FINISHED"}, step
        assert _twins_show_the_paint() <= 1e-7, step  # what the viewport shows, before any timer tick
        got = _preview(tmp_path / f"{step}.exr")
        err = float(np.abs(got - want).max())
        print(
            f"{TAG} preview after {step}: mean {got[..., :3].mean():.3f} (before {want[..., :3].mean():.3f}), "
            f"max abs diff {err:.1e}"
        )
        assert err <= 1e-6, step


def _render(out: Path) -> dict[str, np.ndarray]:
    assert bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="exr") == {"FINISHED"}
    return {p.name: X.read_exr_rgba(p) for p in sorted(out.glob("edit.*.exr"))}


def _moved_run(blender, tmp_path) -> tuple[Path, Path, np.ndarray, dict[str, np.ndarray]]:
    """A shot (``shot/scene.blend``, ``shot/run``, ``shot/plate``; the manifest's paths relative, as an export writes
    them) imported with the live preview and saved, then its run folder moved on its own to ``moved/run``: the
    manifest's relative plate paths now name a plate that is not there. Returns (shot, the moved run, the preview
    render and the render before the move)."""
    shot = tmp_path / "shot"
    manifest = _relative_manifest(X.make_export(shot))
    assert blender.ops.wm.save_as_mainfile(filepath=str(shot / "scene.blend")) == {"FINISHED"}
    blender.context.scene.neural_atlas.filter_type = P.FILTER_NEAREST
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    assert blender.ops.wm.save_mainfile() == {"FINISHED"}
    before = _preview(tmp_path / "before.exr")
    rendered = _render(tmp_path / "out_before")
    assert X.render_error(tmp_path / "out_before", Path(X.make_export(tmp_path / "ref")), "nearest") <= 5e-5
    moved = tmp_path / "moved" / "run"
    moved.parent.mkdir()
    shutil.move(str(shot / "run"), str(moved))
    return shot, moved, before, rendered


def test_after_a_relink_every_operator_works_as_before_the_move(blender, tmp_path):
    """Relink Run Folder, then Live Preview (hidden and built again), Paint on Frame (the preview gains its frame
    paint node), Float Edit Layers, Import Atlas of the relinked manifest and Render: each finishes, the preview
    renders as before the move and the render is the edit, not the bare plate."""
    shot, moved, before, rendered = _moved_run(blender, tmp_path)
    new_manifest = moved / "exports" / "v001" / "manifest.json"
    # the manifest's relative plate paths name nothing now: its plate's paths as at export still do
    plan = P.plan_tree(C.load_manifest(str(new_manifest)), str(new_manifest))
    assert os.path.normpath(plan.plate.filepath) == os.path.normpath(shot / "plate" / f"{X.FRAMES[0]:05d}.png")
    data = C.load_manifest(str(new_manifest))
    del data["clip"]["source_absolute"], data["clip"]["frame_files_absolute"]  # as an older export has it
    with pytest.raises(P.PlanError, match="plate frame does not exist"):
        P.plan_tree(data, str(new_manifest))
    assert bpy.ops.neural_atlas.relink("EXEC_DEFAULT", filepath=str(moved)) == {"FINISHED"}
    ops = bpy.ops.neural_atlas
    assert ops.live_preview("EXEC_DEFAULT") == {"FINISHED"} and not preview_plane.is_shown(bpy.context.scene)
    assert ops.live_preview("EXEC_DEFAULT") == {"FINISHED"} and preview_plane.is_shown(bpy.context.scene)  # built again
    err = float(np.abs(_preview(tmp_path / "relinked.exr") - before).max())
    bpy.context.scene.frame_set(FRAME)
    assert ops.frame_paint_start("EXEC_DEFAULT") == {"FINISHED"}
    frame_paint = moved / "edits" / "frames" / f"frame.{FRAME:05d}.png"
    assert frame_paint.is_file() and not (shot / "run").exists()
    nodes = bpy.data.materials[V.PREVIEW_MATERIAL].node_tree.nodes
    assert nodes[V.FRAME_PAINT_NODE].image == bpy.data.images[P.FRAME_PAINT_IMAGE]
    assert ops.float_edits("EXEC_DEFAULT") == {"FINISHED"}
    assert {p.name for p in (moved / "edits").glob("*.exr")} == {"Background.exr", "Foreground.exr"}
    assert ops.import_run("EXEC_DEFAULT", filepath=str(new_manifest)) == {"FINISHED"}
    plate = bpy.path.abspath(bpy.data.movieclips[P.PLATE_CLIP].filepath)
    assert os.path.normpath(plate) == os.path.normpath(shot / "plate" / f"{X.FRAMES[0]:05d}.png")
    after = _render(tmp_path / "out_after")  # the float edit layers hold the same paint: the same render
    assert sorted(after) == sorted(rendered) == [f"edit.{f:05d}.exr" for f in X.FRAMES]
    render_err = max(float(np.abs(after[k] - rendered[k]).max()) for k in after)
    print(f"{TAG} after a relink: preview vs before the move {err:.1e}, render vs before {render_err:.1e}")
    assert err <= 1e-6 and render_err <= 1e-4


def test_paint_on_frame_refuses_before_it_makes_anything(blender, tmp_path):
    """The plate gone (the run folder moved, the plate too, no relink): Paint on Frame, which must rebuild the live
    preview to show its paint, refuses with the plate's line and makes no image and no file."""
    shot, moved, _, _ = _moved_run(blender, tmp_path)
    shutil.move(str(shot / "plate"), str(tmp_path / "plate_away"))
    assert bpy.ops.neural_atlas.relink("EXEC_DEFAULT", filepath=str(moved)) == {"FINISHED"}
    bpy.context.scene.frame_set(FRAME)
    with pytest.raises(RuntimeError, match="plate frame does not exist"):
        bpy.ops.neural_atlas.frame_paint_start("EXEC_DEFAULT")
    assert bpy.data.images.get(P.FRAME_PAINT_IMAGE) is None
    assert not (moved / "edits" / "frames").exists()


def _import(blender, manifest: Path) -> None:
    blender.context.scene.neural_atlas.filter_type = P.FILTER_NEAREST
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}


def test_a_scene_range_wider_than_the_export_renders_the_exported_frames_and_says_so(blender, tmp_path):
    """Scene range 1-8 over an export of frames 3-5: frames 3-5 are rendered (the edit), the others are not, and the
    report and the panel's render status say which were left out; a range with none of them is refused."""
    manifest = X.make_export(tmp_path)
    _import(blender, manifest)
    scene = blender.context.scene
    scene.frame_start, scene.frame_end = 1, 8
    out = tmp_path / "out"
    assert bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="exr") == {"FINISHED"}
    assert sorted(p.name for p in out.glob("edit.*")) == [f"edit.{f:05d}.exr" for f in X.FRAMES]
    assert X.render_error(out, manifest, "nearest") <= 5e-5
    assert scene.neural_atlas.render_status == (
        f"rendered 3 frame(s) to {out}; scene frame(s) 1-2, 6-8 not rendered: the export has passes for frames 3-5 "
        "only (export more frames to render them)"
    )
    assert (scene.frame_start, scene.frame_end) == (1, 8)  # the artist's range stays
    scene.frame_start, scene.frame_end = 10, 12
    line = "The scene's range 10-12 holds none of the exported frames 3-5: set the range inside them"
    with pytest.raises(RuntimeError, match=line):
        bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(tmp_path / "none"), file_format="exr")
    assert not (tmp_path / "none").exists()


def test_import_sets_the_viewer_the_run_folder_and_the_current_frame(blender, tmp_path):
    """Import Atlas of frames 1001-1004 into a saved .blend: a Viewer node shows the composite (the Compositor's
    backdrop), the Run Folder is the export's run (Refine is ready once the run holds a finished fit) and the current
    frame is the first imported one; the panel's render status says what the last render did."""
    manifest = X.make_export(tmp_path, frames=(1001, 1002, 1003, 1004))
    assert bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend")) == {"FINISHED"}
    scene = blender.context.scene
    assert scene.frame_current == 1
    _import(blender, manifest)
    assert scene.frame_current == 1001
    from neural_atlas.addon import compat

    tree = compat.scene_tree(scene)
    viewer = tree.nodes[P.VIEWER_NODE]
    assert viewer.bl_idname == "CompositorNodeViewer"
    (link,) = viewer.inputs[0].links
    assert link.from_node.name == f"{P.PREFIX}Over"
    out_links = [lk for lk in tree.links if lk.from_node.name == f"{P.PREFIX}Over"]
    assert len(out_links) == 2  # the render's output and the viewer: the same composite
    assert scene.neural_atlas.run_dir == "//run/"
    assert not bpy.ops.neural_atlas.refine.poll()  # no finished fit in the run yet
    for name in (C.RUN_CHECKPOINT, C.RUN_METRICS):
        (tmp_path / "run" / name).write_bytes(b"")
    assert bpy.ops.neural_atlas.refine.poll()
    scene.frame_set(1003)
    _import(blender, manifest)  # a re-import keeps the artist's place
    assert scene.frame_current == 1003
    out = tmp_path / "out"
    assert bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="png") == {"FINISHED"}
    assert scene.neural_atlas.render_status == f"rendered 4 frame(s) to {out}"


def test_save_writes_the_paint_with_the_blend(blender, tmp_path):
    """Ctrl+S and Save As write the edit layers' and the frame paint's unsaved strokes to their files (a .blend saved
    for the first time, its paths made relative, included), nothing anywhere else."""
    manifest = X.make_export(tmp_path / "shot")
    _import(blender, manifest)
    edits = tmp_path / "shot" / "run" / "edits"
    img = bpy.data.images[P.edit_image_name("Foreground")]
    _stroke(img, (1.0, 0.0, 0.0, 1.0), slice(0, 2))
    assert bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "shot" / "scene.blend")) == {"FINISHED"}
    assert not img.is_dirty and img.filepath == "//run/edits/Foreground.png"
    png = X.read_png_rgba8(edits / "Foreground.png")
    assert (png[-2:] == (255, 0, 0, 255)).all()  # the bottom two rows (Blender's rows are bottom-up)
    _stroke(img, (0.0, 0.0, 1.0, 1.0), slice(0, 1))
    bpy.context.scene.frame_set(FRAME)
    assert bpy.ops.neural_atlas.frame_paint_start("EXEC_DEFAULT") == {"FINISHED"}
    fp = bpy.data.images[P.FRAME_PAINT_IMAGE]
    _stroke(fp, (0.0, 1.0, 0.0, 1.0), slice(0, 3))
    assert bpy.ops.wm.save_mainfile() == {"FINISHED"}  # Ctrl+S
    assert not img.is_dirty and not fp.is_dirty
    assert (X.read_png_rgba8(edits / "Foreground.png")[-1] == (0, 0, 255, 255)).all()
    assert (X.read_png_rgba8(edits / "frames" / f"frame.{FRAME:05d}.png")[-3:] == (0, 255, 0, 255)).all()
    made = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*") if p.is_file())
    assert [p for p in made if "edits" in p and "shot/run/edits" not in p] == []


def test_land_takes_a_stroke_at_once(blender, tmp_path):
    """Land Paint on Atlases is greyed out over an empty frame paint and ready right after the first stroke (no
    half-second wait)."""
    _import(blender, X.make_export(tmp_path))
    bpy.context.scene.frame_set(FRAME)
    assert bpy.ops.neural_atlas.frame_paint_start("EXEC_DEFAULT") == {"FINISHED"}
    assert not bpy.ops.neural_atlas.frame_paint_land.poll()
    _stroke(bpy.data.images[P.FRAME_PAINT_IMAGE], (1.0, 0.0, 0.0, 1.0), slice(0, 2))
    assert bpy.ops.neural_atlas.frame_paint_land.poll()


def test_the_first_preview_render_prints_no_colour_space_warning(blender, tmp_path, capfd):
    """A shot painted, its edits saved: the preview's first render reads and puts back the output settings without
    Blender's "matches no enum" warning."""
    manifest = X.make_export(tmp_path)
    _import(blender, manifest)
    _stroke(bpy.data.images[P.edit_image_name("Background")], (1.0, 0.0, 0.0, 1.0))
    assert bpy.ops.neural_atlas.save_edits("EXEC_DEFAULT") == {"FINISHED"}
    capfd.readouterr()
    _preview(tmp_path / "first.exr")
    printed = "".join(capfd.readouterr())  # bpy 4.5 prints its warnings on stdout, 5.0 on stderr
    assert "matches no enum" not in printed and "ColorManagedInputColorspaceSettings" not in printed


def test_the_file_handlers_are_persistent_and_leave_with_the_add_on(registered):
    """Load and save handlers outlive a loaded file (persistent), the paint is saved before the paths are rebased for
    the file being written, and unregistering removes every one of them (registering again puts them back)."""
    from neural_atlas.addon import blend_paths, save_paint

    def ours() -> list[tuple[str, str]]:
        return [
            (kind, h.__name__)
            for kind in ("load_pre", "load_post", "save_pre", "save_post")
            for h in getattr(bpy.app.handlers, kind)
            if getattr(h, "__module__", "").startswith("neural_atlas.")
        ]

    before = ours()
    assert {("load_pre", "_cancel_jobs"), ("load_post", "_fresh_file"), ("save_pre", "save_paint_with_file")} <= set(
        before
    )
    save_pre = bpy.app.handlers.save_pre
    assert save_pre.index(save_paint.save_paint_with_file) < save_pre.index(blend_paths.relative_before_save)
    kinds = ("load_pre", "load_post", "save_pre", "save_post")
    handlers = [h for kind in kinds for h in getattr(bpy.app.handlers, kind)]
    assert all(hasattr(h, "_bpy_persistent") for h in handlers if h.__module__.startswith("neural_atlas."))
    registered.unregister()
    try:
        assert ours() == []
    finally:
        registered.register()
    assert sorted(ours()) == sorted(before)
