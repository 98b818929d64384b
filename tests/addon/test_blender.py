"""The add-on inside Blender (bpy 4.5 and 5.0): registration, compositor tree against the render equation,
masks, the Fit Atlas operator with a fake engine (ok, crash, cancel, bad input), paint and render."""

from __future__ import annotations

import json
import os
import re
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from cancel_at import cancel_at_step  # noqa: E402
from helpers import RecordingLayout, drive_modal, fake_python, polygon_mask, shape_key_mask, stand_in_pip  # noqa: E402
from mask_reference import rasterize_polygon  # noqa: E402
from neural_atlas.addon import compat, preferences  # noqa: E402
from neural_atlas.addon.core import engine_setup as ES  # noqa: E402
from neural_atlas.addon.core import needs, running  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402
from neural_atlas.addon.ops import fit as fit_ops  # noqa: E402
from neural_atlas.addon.ops import setup as setup_ops  # noqa: E402

from engine import contract as C  # noqa: E402

FRAMES, H, W, make_export = X.FRAMES, X.H, X.W, X.make_export
#: the numbers the tests print carry this tag (pytest -s, or the runner's log)
TAG = f"[bpy {bpy.app.version_string}]"


def _tree(scene):
    return compat.scene_tree(scene, create=False)


def _layer_filter(tree, layer: str) -> str:
    """The filter a layer is sampled with, read back from the version's own settings: 5.0's Map UV interpolation;
    on 4.x a Nearest Map UV and the Switch to the bilinear group."""
    if compat.V5:
        value = tree.nodes[f"NA_MapUV_{layer}"].inputs["Interpolation"].default_value
        return P.FILTER_NEAREST if value == "Nearest" else P.FILTER_BILINEAR
    assert tree.nodes[f"NA_MapUV_{layer}"].filter_type == "NEAREST"
    on = tree.nodes[P.filter_switch_name(layer)].inputs["Switch"].default_value
    return P.FILTER_BILINEAR if on else P.FILTER_NEAREST


def _import(blender, manifest, filt=P.FILTER_NEAREST):
    scene = blender.context.scene
    scene.neural_atlas.filter_type = filt
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    return scene


# --- registration -------------------------------------------------------------------------------------------
def test_register_unregister_repeatable(registered):
    from neural_atlas.addon import registration

    for _ in range(3):
        registered.unregister()
        assert not hasattr(bpy.types.Scene, "neural_atlas")
        assert not hasattr(bpy.types, "NEURALATLAS_PT_fit")
        registered.register()
        assert hasattr(bpy.types, "NEURALATLAS_PT_fit")
        assert bpy.ops.neural_atlas.import_run.poll()  # registered (Fit Atlas is greyed: no clip)
    assert len(registration.classes) == len(set(registration.classes)) >= 13
    assert [h.__name__ for h in bpy.app.handlers.load_pre].count("_cancel_jobs") == 1
    assert bpy.context.scene.neural_atlas.preset == "draft"


def test_panel_draws_with_a_fake_layout(blender):
    """draw() never runs headless (no region): call it with a recording layout."""
    from neural_atlas.addon import ui

    scene = blender.context.scene
    scene.neural_atlas.layers.add()
    layout = RecordingLayout()
    calls = layout.draw(ui.NEURALATLAS_PT_fit, blender.context) + layout.draw(ui.NEURALATLAS_PT_edit, blender.context)
    ops = [a[0] for name, a, _ in calls if name == "operator"]
    assert {"neural_atlas.fit", "neural_atlas.import_run", "neural_atlas.render", "neural_atlas.save_edits"} <= set(ops)


# --- compositor ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def lut(tmp_path_factory, registered):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return X.blender_srgb_lut(bpy, tmp_path_factory.mktemp("lut"))


def test_blender_srgb_decode_is_close_to_the_formula(lut):
    err = np.abs(lut - X.srgb_to_linear(np.arange(256) / 255)).max()
    print(f"{TAG} Blender 8-bit sRGB decode vs exact formula: max abs err {err:.2e}")
    assert err < 5e-5


@pytest.mark.parametrize("filt", [P.FILTER_NEAREST, P.FILTER_BILINEAR])
def test_compositor_matches_render_equation(blender, tmp_path, lut, filt):
    manifest = make_export(tmp_path)
    scene = _import(blender, manifest, filt)
    tree = _tree(scene)
    ours = [n for n in tree.nodes if n.name.startswith(P.PREFIX)]
    # + 6 frames, and a Reroute and a File Output per matte (2 layers + paint); 4.x: a bilinear group and a Switch
    # per layer
    assert len(ours) == 14 + 12 + (0 if compat.V5 else 4)
    assert tree.nodes[P.VIEWER_NODE].inputs[0].links[0].from_node.name == "NA_Over"  # the backdrop: the composite
    assert _layer_filter(tree, "Foreground") == _layer_filter(tree, "Background") == filt
    assert (scene.frame_start, scene.frame_end) == (FRAMES[0], FRAMES[-1])
    assert (scene.render.resolution_x, scene.render.resolution_y) == (W, H)
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(tmp_path / "out"), file_format="exr") == {
        "FINISHED"
    }
    ref_filter = filt  # the engine's name for it
    for f in FRAMES:
        out = X.read_exr_rgba(tmp_path / "out" / f"edit.{f:05d}.exr")
        assert out.shape == (H, W, 4)
        np.testing.assert_allclose(out[..., 3], 1.0, atol=1e-6)
    err = X.render_error(tmp_path / "out", manifest, ref_filter, X.lut_decoder(lut))
    err_exact = X.render_error(tmp_path / "out", manifest, ref_filter)
    print(f"{TAG} filter {filt}: max abs err {err:.2e} (Blender's sRGB decode), {err_exact:.2e} (exact sRGB)")
    assert err <= 1e-5  # both filters on both versions (4.x bilinear: the group's four nearest taps)
    assert err_exact <= 5e-5


def test_compositor_three_layers_matches_render_equation(blender, tmp_path, lut):
    """Two foreground layers (paper Sec. 4.3): the tree sums every layer, checked against the equation."""
    manifest = make_export(tmp_path, foregrounds=2)
    scene = _import(blender, manifest, P.FILTER_NEAREST)
    tree = _tree(scene)
    ours = {n.name for n in tree.nodes if n.name.startswith(P.PREFIX)}
    # + 7 frames, and a Reroute and a File Output per matte (3 layers, paint, the foregrounds with their Add node);
    # 4.x: a bilinear group and a Switch per layer
    assert len(ours) == 19 + 15 + 3 + (0 if compat.V5 else 6)
    assert {"NA_MapUV_Background", "NA_MapUV_Foreground1", "NA_MapUV_Foreground2"} <= ours
    out_dir = tmp_path / "out"
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out_dir), file_format="exr") == {"FINISHED"}
    err = X.render_error(out_dir, manifest, "nearest", X.lut_decoder(lut))
    print(f"{TAG} three layers, nearest: max abs err {err:.2e}")
    assert err <= 1e-5


def test_float_exr_edit_layer_is_used_premultiplied(blender, tmp_path):
    """An edit layer may be a linear float EXR with premultiplied alpha (no decode, no premultiply)."""
    manifest = make_export(tmp_path)
    data = json.loads(manifest.read_text())
    layer = data["layers"][1]
    edit8 = X.read_png_rgba8(Path(layer["edit_layer"]))
    a = edit8[..., 3] / 255.0
    rgb = (edit8[..., :3] / 255.0) ** 2.2 * a[..., None]  # any linear premultiplied values
    exr = tmp_path / "run" / "edits" / "Foreground.exr"
    X.write_exr(exr, {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2], "A": a})
    layer["edit_layer"] = str(exr)
    manifest.write_text(json.dumps(data))
    _import(blender, manifest)
    img = bpy.data.images["NA_Edit_Foreground"]
    assert img.colorspace_settings.name == "Non-Color" and img.alpha_mode == "PREMUL"
    out = tmp_path / "out"
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="exr") == {"FINISHED"}
    err = X.render_error(out, manifest, "nearest", X.lut_decoder(X.blender_srgb_lut(bpy, tmp_path / "lut")))
    print(f"{TAG} float EXR edit layer, nearest: max abs err {err:.2e}")
    assert err <= 1e-5


def test_rebuild_is_idempotent_and_keeps_the_artists_nodes(blender, tmp_path):
    manifest = make_export(tmp_path)
    scene = blender.context.scene
    tree = compat.scene_tree(scene)
    artist = tree.nodes.new("CompositorNodeBlur")
    artist.name = "Artist Blur"
    artist_img = bpy.data.images.new("artist_plate", 4, 4)
    for _ in range(3):
        _import(blender, manifest)
    names = sorted(n.name for n in tree.nodes)
    assert names.count("Artist Blur") == 1
    ours = 26 + (0 if compat.V5 else 4)  # the composite's Viewer included; 4.x: a bilinear group and a Switch a layer
    assert len([n for n in names if n.startswith(P.PREFIX)]) == ours
    assert len(names) == ours + 1
    assert len([g for g in bpy.data.node_groups if g.name.startswith(P.BILINEAR_GROUP)]) == (0 if compat.V5 else 1)
    assert bpy.data.images.get("artist_plate") == artist_img
    assert len([i for i in bpy.data.images if i.name.startswith("NA_Edit_")]) == 2
    assert len([c for c in bpy.data.movieclips if c.name.startswith(P.PREFIX)]) == 1
    over = tree.nodes["NA_Over"]
    fg = compat.input_socket(over, P.ALPHA_OVER, "fg")
    assert fg.is_linked and fg.links[0].from_node.name == "NA_SetAlpha"


def test_paint_then_save_and_render_png(blender, tmp_path):
    manifest = make_export(tmp_path)
    scene = _import(blender, manifest)
    canvas = bpy.data.objects["NA_Canvas_Foreground"]
    assert tuple(canvas.scale)[:2] == (1.0, 1.0)  # the test atlas is square (16x16)
    assert bpy.data.objects["NA_Canvas_Background"].location.x == 0.0 and canvas.location.x == pytest.approx(1.2)
    mat = canvas.data.materials[0]
    assert mat.node_tree.nodes.active.image.name == "NA_Edit_Foreground"
    # headless painting is impossible (docs/blender-compat.md): write pixels as a brush would
    img = bpy.data.images["NA_Edit_Foreground"]
    w, h = img.size
    px = np.zeros(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    px = px.reshape(h, w, 4)
    px[: h // 2, : w // 2] = (1.0, 0.0, 0.0, 1.0)  # bottom-left quarter painted opaque red
    img.pixels.foreach_set(px.ravel())
    img.update()
    assert blender.ops.neural_atlas.save_edits("EXEC_DEFAULT") == {"FINISHED"}
    on_disk = X.read_png_rgba8(Path(bpy.path.abspath(img.filepath)))[::-1]  # rows bottom-up like pixels
    assert (on_disk[: h // 2, : w // 2] == [255, 0, 0, 255]).all()
    np.testing.assert_allclose(on_disk / 255.0, px, atol=0.5 / 255)
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(tmp_path / "png"), file_format="png") == {
        "FINISHED"
    }
    assert sorted(os.listdir(tmp_path / "png")) == [*(f"edit.{f:05d}.png" for f in FRAMES), P.MATTES_DIR]
    assert scene.render.image_settings.file_format == "PNG" or scene.render.filepath != ""


# --- masks --------------------------------------------------------------------------------------------------
def test_mask_datablock_rasterizes_exactly(blender, tmp_path):
    from neural_atlas.addon import masks

    w, h = 64, 48
    frames = [
        (1, [(10, 8), (30, 8), (30, 20), (10, 20)]),
        (2, [(22, 8), (42, 10), (42, 30), (20, 30)]),  # moved and skewed: an animated roto
    ]
    mask = polygon_mask(bpy.data, frames, w, h)
    paths = masks.rasterize(mask, w, h, [1, 2], str(tmp_path / "m"), ["00001.png", "00002.png"])
    assert [os.path.basename(p) for p in paths] == ["00001.png", "00002.png"]
    for (_frame, corners), path in zip(frames, paths, strict=True):
        img = bpy.data.images.load(path)
        px = np.zeros(w * h * img.channels, np.float32)
        img.pixels.foreach_get(px)
        got = px.reshape(h, w, img.channels)[..., 0] > 0.5  # rows bottom-up
        ref = np.array(rasterize_polygon(corners, w, h))
        iou = (got & ref).sum() / (got | ref).sum()
        assert iou == 1.0, f"IoU {iou}"
        bpy.data.images.remove(img)
    assert "NA_MaskRaster" not in bpy.data.scenes  # the temporary scene is gone


def test_mask_shape_keys_rasterize_exactly(blender, tmp_path):
    """Layer shape keys, keyed as the clip editor's mask tools do (docs/blender-compat.md)."""
    from neural_atlas.addon import masks

    w, h = 64, 48
    frames = [
        (1, [(10, 8), (30, 8), (30, 20), (10, 20)]),
        (2, [(22, 8), (42, 10), (42, 30), (20, 30)]),
        (3, [(5, 5), (20, 5), (20, 40), (5, 40)]),
    ]
    black = np.zeros((h, w, 4), np.uint8)
    black[..., 3] = 255
    X.write_png(tmp_path / "clip" / "0001.png", black)
    clip = bpy.data.movieclips.load(str(tmp_path / "clip" / "0001.png"))
    mask = shape_key_mask(bpy, clip, frames, w, h)
    names = [f"{f:05d}.png" for f, _ in frames]
    paths = masks.rasterize(mask, w, h, [f for f, _ in frames], str(tmp_path / "m"), names)
    for (_frame, corners), path in zip(frames, paths, strict=True):
        img = bpy.data.images.load(path)
        px = np.zeros(w * h * img.channels, np.float32)
        img.pixels.foreach_get(px)
        got = px.reshape(h, w, img.channels)[..., 0] > 0.5
        ref = np.array(rasterize_polygon(corners, w, h))
        assert (got & ref).sum() / (got | ref).sum() == 1.0
    assert sorted(os.listdir(tmp_path / "m")) == names


def test_render_movie(blender, tmp_path):
    manifest = make_export(tmp_path)
    _import(blender, manifest)
    out = tmp_path / "movie"
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="movie") == {"FINISHED"}
    movies = list(out.glob("*.mp4"))
    assert len(movies) == 1 and movies[0].stat().st_size > 1000
    clip = bpy.data.movieclips.load(str(movies[0]))
    assert clip.source == "MOVIE" and clip.frame_duration == len(FRAMES) and tuple(clip.size) == (W, H)
    assert blender.context.scene.render.image_settings.file_format != "FFMPEG"  # the artist's setting is back


# --- Fit Atlas operator with a fake engine ------------------------------------------------------------------
@pytest.fixture
def fit_scene(blender, tmp_path, monkeypatch):
    """A scene with a clip (the fake export's plate), one Mask layer, and the fake engine as interpreter."""
    src = make_export(tmp_path / "src")
    plate = tmp_path / "src" / "plate" / f"{FRAMES[0]:05d}.png"
    clip = bpy.data.movieclips.load(str(plate))
    monkeypatch.setenv("NEURAL_ATLAS_ENGINE_PYTHON", fake_python(tmp_path))
    props = blender.context.scene.neural_atlas
    props.clip = clip
    layer = props.layers.add()
    layer.mask = polygon_mask(bpy.data, [(clip.frame_start, [(5, 5), (20, 5), (20, 15), (5, 15)])], W, H)
    props.run_dir = str(tmp_path / "run")
    return props, src


def _fit(**kwargs):
    return bpy.ops.neural_atlas.fit("EXEC_DEFAULT", **kwargs)


def _fit_error(match, **kwargs):
    """An ERROR report: called from Python, Blender raises it as RuntimeError (the UI shows it)."""
    with pytest.raises(RuntimeError, match=match):
        _fit(**kwargs)


def test_fit_operator_runs_engine_exports_and_imports(fit_scene, tmp_path):
    props, _ = fit_scene
    assert props.clip.frame_duration == len(FRAMES)
    assert _fit() == {"FINISHED"}
    assert not props.running and props.progress == 1.0
    assert props.manifest.endswith(C.MANIFEST_NAME)
    assert "NA_Over" in _tree(bpy.context.scene).nodes
    log = Path(props.log_path).read_text()
    # argv: plate folder, rasterized masks named like the plate's files, the plate's frame numbers, preset, --no-bar
    first = log.splitlines()[0]
    assert f" fit {tmp_path / 'src' / 'plate' / '#####.png'} --mask {tmp_path / 'run.masks' / 'layer1'} " in first
    assert f"--frames {FRAMES[0]}:{FRAMES[-1]}" in first and "--preset draft" in first and first.endswith("--no-bar")
    assert sorted(os.listdir(tmp_path / "run.masks" / "layer1")) == [f"{f:05d}.png" for f in FRAMES]
    assert " export " in log


def test_a_split_is_announced_and_the_whole_object_has_a_matte(fit_scene, monkeypatch):
    """Find Parts split the object: the panel's status line says so after the import and names the layers that are
    its parts, and the compositor offers their matte together (the whole object)."""
    props, _ = fit_scene
    monkeypatch.setenv("FAKE_ENGINE_MODE", "parts")
    assert _fit() == {"FINISHED"}
    assert props.status == (
        "done: 3 layers in the compositor (Background, Foreground1, Foreground2); Find Parts: the object split into 2 "
        f"parts that move apart: Foreground1 (the largest), Foreground2, together the {P.FOREGROUNDS_MATTE} matte"
    )
    assert P.matte_node_name(P.FOREGROUNDS_MATTE) in _tree(bpy.context.scene).nodes
    from helpers import RecordingLayout
    from neural_atlas.addon import ui

    calls = RecordingLayout().draw(ui.NEURALATLAS_PT_fit, bpy.context)
    assert props.status in [kw.get("text") for name, _, kw in calls if name == "label"]
    done = props.status
    assert bpy.ops.neural_atlas.estimate("EXEC_DEFAULT") == {"FINISHED"}  # the next job has its own line ...
    assert props.status != done and props.fit_result == done
    calls = RecordingLayout().draw(ui.NEURALATLAS_PT_fit, bpy.context)
    assert done in [kw.get("text") for name, _, kw in calls if name == "label"]  # ... and the fit's stays in view


def test_fit_operator_on_a_movie_clip(fit_scene, tmp_path):
    """A movie plate: the engine gets the file; masks are named by position (the engine matches by count)."""
    props, src = fit_scene
    _import(bpy, src)
    assert bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(tmp_path / "mov"), file_format="movie") == {
        "FINISHED"
    }
    movie = next((tmp_path / "mov").glob("*.mp4"))
    props.clip = bpy.data.movieclips.load(str(movie))
    assert props.clip.source == "MOVIE"
    props.run_dir = str(tmp_path / "run_movie")
    assert _fit() == {"FINISHED"}
    first = Path(props.log_path).read_text().splitlines()[0]
    assert f" fit {movie} --mask " in first and "--frames 0:2" in first
    assert sorted(os.listdir(tmp_path / "run_movie.masks" / "layer1")) == ["00000.png", "00001.png", "00002.png"]


def test_fit_operator_engine_crash_reports_and_blender_stays_usable(fit_scene, monkeypatch, tmp_path):
    props, src = fit_scene
    monkeypatch.setenv("FAKE_ENGINE_MODE", "crash")
    _fit_error(r"Fit Atlas failed: the engine was killed by signal 9 \(log: .*run\.blender\.log\)")
    assert not props.running
    assert "killed by signal 9" in props.status
    assert props.log_path == str(tmp_path / "run") + ".blender.log" and os.path.exists(props.log_path)
    # Blender is fine: the same scene imports and renders
    assert bpy.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(src)) == {"FINISHED"}
    assert bpy.ops.neural_atlas.fit.poll()


def test_fit_operator_traceback_and_bad_input(fit_scene, monkeypatch):
    props, _ = fit_scene
    monkeypatch.setenv("FAKE_ENGINE_MODE", "traceback")
    _fit_error("simulated engine bug")
    assert "simulated engine bug" in props.status
    monkeypatch.setenv("FAKE_ENGINE_MODE", "bad_input")
    _fit_error("Fit Atlas bad_input: .*mask folder does not exist")
    assert props.status.startswith(props.run_dir.rstrip("/")) and "mask folder does not exist" in props.status


def test_fit_operator_cancel_then_resume(fit_scene, monkeypatch):
    props, _ = fit_scene
    monkeypatch.setenv("FAKE_ENGINE_MODE", "hang")
    with monkeypatch.context() as m:
        pressed = cancel_at_step(m, 3)  # once the engine said step 3: its SIGTERM handler is in place
        assert _fit() == {"CANCELLED"}
    stopped = re.fullmatch(r"cancelled at step (\d+); Resume continues from the checkpoint", props.status)
    assert pressed and stopped and int(stopped[1]) >= pressed[0] >= 3 and props.can_resume, props.status
    assert 0.0 < props.progress < 1.0  # the bar moved with the engine's progress lines (hang mode: total 1000)
    from helpers import RecordingLayout
    from neural_atlas.addon import ui

    calls = RecordingLayout().draw(ui.NEURALATLAS_PT_fit, bpy.context)  # Fit Atlas greyed, saying why
    at = next(i for i, (name, a, _) in enumerate(calls) if name == "operator" and a[0] == "neural_atlas.fit")
    assert calls[at - 1] == ("set", ("enabled", False), {})
    assert needs.USED_RUN_FOLDER in [kw.get("text") for name, _, kw in calls if name == "label"]
    _fit_error("already holds a fit")  # a second plain fit, called anyway, refuses to overwrite the run
    assert "already holds a fit" in props.status
    monkeypatch.setenv("FAKE_ENGINE_MODE", "ok")
    assert _fit(resume=True) == {"FINISHED"}
    assert "--resume" in Path(props.log_path).read_text()
    assert not props.can_resume


def test_fit_operator_without_engine_python_says_how_to_fix(fit_scene, monkeypatch):
    props, _ = fit_scene
    monkeypatch.delenv("NEURAL_ATLAS_ENGINE_PYTHON")
    _fit_error("Set up engine")
    assert "Set up engine" in props.status


def test_estimate_operator_asks_the_engine(fit_scene):
    props, _ = fit_scene
    assert bpy.ops.neural_atlas.estimate("EXEC_DEFAULT") == {"FINISHED"}
    assert json.loads(props.estimate_json) == {"draft": {"seconds": 61.0, "psnr": 25.7}}
    from neural_atlas.addon import ui

    assert ui._estimate_text(props) == "about 1m01s here (engine estimate), ~25.7 dB"
    argv = Path(props.run_dir + ".estimate.log").read_text().splitlines()[0]
    assert " estimate " in argv and f"--frames {FRAMES[0]}:{FRAMES[-1]}" in argv and argv.endswith("--json")
    props.long_edge = 512
    assert props.estimate_json == ""  # another size: back to the documented estimate


def test_check_engine_operator(blender, tmp_path, monkeypatch):
    monkeypatch.setenv("NEURAL_ATLAS_ENGINE_PYTHON", fake_python(tmp_path))
    assert bpy.ops.neural_atlas.check_engine("EXEC_DEFAULT") == {"FINISHED"}
    monkeypatch.setenv("NEURAL_ATLAS_ENGINE_PYTHON", str(tmp_path / "missing_python"))
    with pytest.raises(RuntimeError, match=r"the engine does not run with .*missing_python: cannot start"):
        bpy.ops.neural_atlas.check_engine("EXEC_DEFAULT")


def test_operators_refuse_without_inputs(blender, monkeypatch, tmp_path):
    props = blender.context.scene.neural_atlas
    monkeypatch.setenv("NEURAL_ATLAS_ENGINE_PYTHON", sys.executable)
    _fit_error(re.escape(needs.NO_FIT_CLIP))  # no clip: greyed out, the poll's line
    X.write_png(tmp_path / "plate.png", np.zeros((4, 4, 4), np.uint8))
    props.clip = bpy.data.movieclips.load(str(tmp_path / "plate.png"))
    _fit_error("save the .blend file first")  # the default Run Folder is relative to the .blend
    props.run_dir = ""
    _fit_error("choose a Run Folder")
    assert not bpy.ops.neural_atlas.render.poll()  # greyed out; a script calling it gets the poll's line
    with pytest.raises(RuntimeError, match=re.escape(needs.NO_IMPORT)):
        bpy.ops.neural_atlas.render("EXEC_DEFAULT")


def test_modal_path_progress_then_import(fit_scene):
    props, _ = fit_scene
    seen = []

    def events(_tick, job):
        seen.append((props.progress, props.status))
        return "TIMER"

    ret, op, _ = drive_modal(fit_ops.NEURALATLAS_OT_fit, bpy.context, events, resume=False)
    assert ret == {"FINISHED"} and op.reports[-1][0] == {"INFO"}
    assert any(status.startswith("step ") and " dB · ETA " in status for _, status in seen)
    assert any(0.0 < p < 1.0 for p, _ in seen)
    assert props.manifest and not running.is_running(bpy.context.scene.name)


def test_modal_path_cancel_button(fit_scene, monkeypatch):
    props, _ = fit_scene
    monkeypatch.setenv("FAKE_ENGINE_MODE", "hang")
    polls = []

    def events(tick, job):
        polls.append(bpy.ops.neural_atlas.cancel.poll())
        if job.state.step >= 3 and tick % 2 == 0:
            assert bpy.ops.neural_atlas.cancel() == {"FINISHED"}
            assert props.status == "cancelling: writing a checkpoint…"
        return "TIMER"

    ret, op, _ = drive_modal(fit_ops.NEURALATLAS_OT_fit, bpy.context, events, resume=False)
    assert ret == {"CANCELLED"} and op.reports[-1][0] == {"WARNING"}
    assert "cancelled at step" in op.reports[-1][1] and props.can_resume
    assert all(polls) and bpy.ops.neural_atlas.fit.poll()
    assert not bpy.ops.neural_atlas.cancel.poll()  # nothing runs: the button is greyed, and says why
    with pytest.raises(RuntimeError, match=re.escape(needs.NOTHING_RUNNING)):
        bpy.ops.neural_atlas.cancel()


def test_modal_path_escape_does_not_cancel(fit_scene, monkeypatch):
    """ESC (pressed in the Clip Editor to stop playback, five times) passes through: the fit keeps running and
    stepping, one line says where Cancel is; only Cancel stops it, with a checkpoint."""
    props, _ = fit_scene
    monkeypatch.setenv("FAKE_ENGINE_MODE", "hang")
    escapes: list[int] = []  # the engine's step at each ESC
    after: list[tuple[int, bool, bool]] = []  # (step, cancelling, engine alive) on the timer ticks after them

    def events(_tick, job):
        if job.state.step >= 3 and len(escapes) < 5:
            escapes.append(job.state.step)
            return "ESC"
        if escapes:
            after.append((job.state.step, job.cancelling, job.process.running))
            if job.state.step >= escapes[-1] + 5 and not job.cancelling:
                assert bpy.ops.neural_atlas.cancel() == {"FINISHED"}
        return "TIMER"

    ret, op, _ = drive_modal(fit_ops.NEURALATLAS_OT_fit, bpy.context, events, resume=False)
    assert len(escapes) == 5
    before_cancel = [a for a in after if not a[1]]
    assert before_cancel and all(alive for _, _, alive in before_cancel)  # ESC stopped nothing
    assert before_cancel[-1][0] >= escapes[-1] + 5  # and the fit kept stepping after them
    said = [m for level, m in op.reports if level == {"INFO"}]
    assert said == [needs.esc_text("Fit Atlas", fit_ops.NEURALATLAS_OT_fit.cancel_where)]  # once, not five times
    assert "press Cancel in the Fit Atlas panel" in said[0]
    assert ret == {"CANCELLED"} and "cancelled at step" in op.reports[-1][1] and props.can_resume


def test_modal_estimate_keeps_the_ui_free_and_fills_the_estimate(fit_scene):
    """Estimate Time runs like Fit Atlas: polled by the timer, the panel shows it, the scene gets the rows."""
    props, _ = fit_scene
    busy = []

    def events(_tick, job):
        busy.append((bpy.ops.neural_atlas.fit.poll(), props.running))
        return "TIMER"

    ret, op, job = drive_modal(fit_ops.NEURALATLAS_OT_estimate, bpy.context, events)
    assert ret == {"FINISHED"} and op.reports[-1] == ({"INFO"}, "about 1m01s here (engine estimate), ~25.7 dB")
    assert busy[0] == (False, True)  # one job per scene: no fit while it runs
    assert json.loads(props.estimate_json) == job.rows and not props.running and running.jobs() == {}


def test_setup_engine_modal_path_reports_progress_and_offline(blender, tmp_path):
    """The GUI path of Set up engine, driven by hand-made TIMER events; pip is a stand-in that fails offline."""
    blender.context.preferences.system.use_online_access = True  # factory settings have it off: no download
    venv = tmp_path / "venv"
    seen = tmp_path / "seen"
    stand_in_pip(venv, release=seen)  # pip's first line stays until the panel has shown it
    statuses = []
    cancel = []  # (Cancel's poll, the preferences draw Cancel) while it runs

    def events(tick, job):
        assert len(job.commands) == 1  # the environment exists: only the install runs
        statuses.append(job.status_text())
        if "Collecting torch" in statuses[-1]:
            seen.touch()
        cancel.append((bpy.ops.neural_atlas.cancel_setup.poll(), "neural_atlas.cancel_setup" in _preference_ops()))
        return "ESC" if tick == 1 else "TIMER"  # ESC does not stop it: pip goes on to its offline error

    ret, op, _ = drive_modal(setup_ops.NEURALATLAS_OT_setup_engine, blender.context, events, venv_dir=str(venv))
    assert ret == {"CANCELLED"}
    assert any("Collecting torch" in s for s in statuses)  # pip's latest line is what the preferences show
    reports = op.reports
    assert reports[-1][0] == {"ERROR"} and "offline" in reports[-1][1] and "setup.log" in reports[-1][1]
    label = preferences.torch_choice(blender.context).label()  # the build for this machine, and its download
    assert reports[0] == ({"INFO"}, f"Set up engine: {label}…") and label.startswith("installing torch (")
    assert ({"INFO"}, needs.esc_text("Set up engine", "the add-on's preferences")) in reports
    assert cancel and all(c == (True, True) for c in cancel)
    assert running.jobs() == {}
    assert not bpy.ops.neural_atlas.cancel_setup.poll() and "neural_atlas.cancel_setup" not in _preference_ops()


def _preference_ops() -> list[str]:
    """The operators the add-on's preferences draw (with a recording layout: no region is drawn headless)."""
    from types import SimpleNamespace

    from neural_atlas.addon import preferences

    layout = RecordingLayout()
    prefs = SimpleNamespace(layout=layout, setup_status="", farm_kind="openjd")
    preferences.NEURALATLAS_AP_preferences.draw(prefs, bpy.context)
    return [a[0] for name, a, _ in layout.calls if name == "operator"]


def test_cancel_setup_stops_set_up_engine(blender, tmp_path):
    """Cancel in the preferences stops Set up engine (ESC does not)."""
    blender.context.preferences.system.use_online_access = True
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    pip = venv / "bin" / "python"
    pip.write_text(f"#!{sys.executable}\nimport time\nprint('Collecting torch', flush=True)\ntime.sleep(60)\n")
    pip.chmod(0o755)

    def events(tick, job):
        if tick == 3:
            assert bpy.ops.neural_atlas.cancel_setup() == {"FINISHED"}
        return "TIMER"

    ret, op, job = drive_modal(setup_ops.NEURALATLAS_OT_setup_engine, blender.context, events, venv_dir=str(venv))
    assert ret == {"CANCELLED"} and job.result.status == "cancelled" and running.jobs() == {}
    assert op.reports[-1] == ({"WARNING"}, f"{ES.CANCELLED_TEXT} (log: {venv / 'setup.log'})")
    assert not bpy.ops.neural_atlas.cancel_setup.poll()
    with pytest.raises(RuntimeError, match=re.escape(needs.SETUP_NOT_RUNNING)):
        bpy.ops.neural_atlas.cancel_setup()


def test_setup_engine_blocking_path_reports_offline(blender, tmp_path):
    """Set up engine in background mode (``execute``: the same job, stepped in a loop)."""
    blender.context.preferences.system.use_online_access = True
    stand_in_pip(tmp_path / "venv")
    with pytest.raises(RuntimeError, match=r"cannot download the engine's packages \(offline.*setup\.log"):
        bpy.ops.neural_atlas.setup_engine("EXEC_DEFAULT", venv_dir=str(tmp_path / "venv"))
    assert running.jobs() == {} and bpy.ops.neural_atlas.setup_engine.poll()
