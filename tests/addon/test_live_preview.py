"""The live preview (bpy 4.5 and 5.0): Import Atlas builds a plate-shaped plane whose material is the render equation;
rendered headless with Cycles on the CPU (1 sample, 0.01-pixel box filter, Standard view) at two frames, it equals
``engine render`` of the same edit, for an 8-bit PNG edit layer and a float EXR one, with both filters.

Painting operators cannot run headless: each test writes its stroke's pixels into the edit image (``img.pixels``), as
a brush would, without saving; the preview render shows them at once (the engine is given the same pixels as files).
The engine runs in its own interpreter: NEURAL_ATLAS_TEST_ENGINE_PYTHON, else the checkout's .venv."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from helpers import engine_python  # noqa: E402
from neural_atlas.addon import compat, preview_plane  # noqa: E402
from neural_atlas.addon.core import preview_plan as V  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402

from engine import contract as C  # noqa: E402
from engine.terms.export_names import EDITS_DIR, PASSES_DIR, pass_file_name  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
TAG = f"[bpy {bpy.app.version_string}]"
#: Two frames of the export (scrubbing: the same paint seen at another frame).
FRAME_A, FRAME_B = X.FRAMES[0], X.FRAMES[-1]
#: Preview vs engine render: the plate is an 8-bit sRGB PNG that the engine decodes by OCIO's float32 curve, within
#: 2.4e-5 of the exact formula (docs/colour.md); the rest is float rounding (measured 4e-7 against the exact formula).
TOLERANCE = 1e-4


def _float_edit(manifest: Path, layer: str) -> Path:
    """Make ``layer``'s edit a float EXR edit layer (linear, premultiplied) beside its PNG, from the PNG's pixels."""
    m = C.load_manifest(str(manifest))
    png = Path(C.resolve_manifest_path(str(manifest), next(x for x in m["layers"] if x["name"] == layer)["edit_layer"]))
    rgba8 = X.read_png_rgba8(png)
    a = rgba8[..., 3:4] / 255.0
    pre = np.concatenate([X.srgb_to_linear(rgba8[..., :3] / 255.0) * a, a], -1).astype(np.float32)
    exr = Path(C.float_edit_layer(str(png)))
    X.write_exr(exr, {c: pre[..., i] for i, c in enumerate("RGBA")})
    return exr


def _import(blender, tmp_path, filt=P.FILTER_DEFAULT):
    manifest = X.make_export(tmp_path)
    _float_edit(manifest, "Foreground")  # Foreground: float EXR edit layer; Background: 8-bit PNG
    scene = blender.context.scene
    scene.neural_atlas.filter_type = filt
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    return manifest, scene


def _pixels(img) -> np.ndarray:
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    return px.reshape(h, w, 4)  # rows bottom-up


def _paint(img, rgba: tuple[float, float, float, float], box: tuple[float, float, float, float]) -> None:
    """A stroke: ``rgba`` over the texels in ``box`` (u0, v0, u1, v1). An 8-bit image gets straight sRGB values on
    byte steps (as a brush leaves them); a float one linear premultiplied values."""
    px = _pixels(img)
    h, w, _ = px.shape
    u0, v0, u1, v1 = box
    block = px[int(v0 * h) : int(v1 * h), int(u0 * w) : int(u1 * w)]
    if img.is_float:
        block[...] = (rgba[0] * rgba[3], rgba[1] * rgba[3], rgba[2] * rgba[3], rgba[3])
    else:
        block[...] = np.round(np.array(rgba) * 255) / 255
    img.pixels.foreach_set(px.ravel())
    img.update()


def _edit_files(folder: Path) -> dict[str, Path]:
    """The edit images' pixels as the engine reads them (8-bit PNG, or float EXR), written outside Blender."""
    files = {}
    for layer in ("Background", "Foreground"):
        img = bpy.data.images[P.edit_image_name(layer)]
        px = _pixels(img)[::-1]
        if img.is_float:
            files[layer] = folder / f"{layer}.exr"
            X.write_exr(files[layer], {c: px[..., i] for i, c in enumerate("RGBA")})
        else:
            files[layer] = folder / f"{layer}.png"
            X.write_png(files[layer], np.round(px * 255).astype(np.uint8))
    return files


def _engine_render(manifest: Path, edits: dict[str, Path], out: Path, filt: str) -> None:
    py = engine_python("render", "torch")
    args = [py, "-m", "engine", "render", str(manifest), "--out", str(out), "--format", "exr", "--filter", filt]
    for layer, path in edits.items():
        args += ["--edit", f"{layer}={path}"]
    done = subprocess.run([*args, "--no-bar"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]


@pytest.mark.slow
@pytest.mark.parametrize("filt", P.FILTERS)
def test_preview_render_equals_engine_render(blender, tmp_path, filt):
    """Painted (not saved) PNG and EXR layers; the preview at frames A and B against ``engine render`` of that paint
    (the panel's filter by the engine's name: Bilinear samples Linear, Nearest Closest)."""
    manifest, scene = _import(blender, tmp_path, filt)
    assert not bpy.data.images[P.edit_image_name("Background")].is_float
    assert bpy.data.images[P.edit_image_name("Foreground")].is_float
    _paint(bpy.data.images[P.edit_image_name("Background")], (1.0, 0.2, 0.05, 0.6), (0.3, 0.2, 0.8, 0.7))
    _paint(bpy.data.images[P.edit_image_name("Foreground")], (0.1, 0.9, 0.3, 0.8), (0.1, 0.1, 0.9, 0.6))
    engine_filter = filt  # the panel's Filter is named as engine render's --filter
    _engine_render(manifest, _edit_files(tmp_path / "edits"), tmp_path / "engine", engine_filter)
    errors = {}
    for frame in (FRAME_A, FRAME_B):
        got = X.read_exr_rgba(Path(preview_plane.render_frame(scene, frame, str(tmp_path / f"preview.{frame}.exr"))))
        want = X.read_exr_rgba(tmp_path / "engine" / f"edit.{frame:05d}.exr")
        assert got.shape == want.shape == (X.H, X.W, 4)
        errors[frame] = float(np.abs(got[..., :3] - want[..., :3]).max())
    scrub = float(np.abs(got[..., :3] - X.read_exr_rgba(tmp_path / f"preview.{FRAME_A}.exr")[..., :3]).max())
    print(
        f"{TAG} live preview ({filt}: {V.INTERPOLATION[filt]}) vs engine render --filter {engine_filter}: max abs err "
        f"frame {FRAME_A} {errors[FRAME_A]:.2e}, frame {FRAME_B} {errors[FRAME_B]:.2e} (frames differ by {scrub:.2f})"
    )
    assert max(errors.values()) <= TOLERANCE
    assert scrub > 0.1  # the second frame is another plate frame, not the first one again
    assert all(bpy.data.images[P.edit_image_name(n)].is_dirty for n in ("Background", "Foreground"))


def test_a_stroke_shows_in_the_preview_at_once(blender, tmp_path):
    """A stroke on each layer (unsaved) changes the next preview render where the layer shows, by what the render
    equation says, and the files on disk are untouched."""
    manifest, scene = _import(blender, tmp_path)
    before = X.read_exr_rgba(Path(preview_plane.render_frame(scene, FRAME_A, str(tmp_path / "before.exr"))))
    disk = {p: p.read_bytes() for p in (tmp_path / "run" / EDITS_DIR).iterdir()}
    for layer, colour in (("Background", (0.0, 0.0, 1.0, 1.0)), ("Foreground", (1.0, 1.0, 0.0, 1.0))):
        _paint(bpy.data.images[P.edit_image_name(layer)], colour, (0.0, 0.0, 1.0, 1.0))  # the whole atlas
    # what the viewport shows: the timer's tick (no event loop runs headless: called as the timer would) copies the
    # paint into the float twins the material samples, and asks again within a second
    assert bpy.app.timers.is_registered(preview_plane._tick)
    assert preview_plane.SYNC_INTERVAL <= preview_plane._tick() <= 1.0
    for layer, want_px in (("Background", (0.0, 0.0, 1.0, 1.0)), ("Foreground", (1.0, 1.0, 0.0, 1.0))):
        twin = _pixels(bpy.data.images[V.mirror_image_name(layer)])
        assert np.abs(twin - np.array(want_px, np.float32)).max() <= 1e-7, layer
    assert preview_plane.sync() == 0  # nothing changed since: nothing copied
    after = X.read_exr_rgba(Path(preview_plane.render_frame(scene, FRAME_A, str(tmp_path / "after.exr"))))
    assert {p: p.read_bytes() for p in disk} == disk
    # the whole atlas painted opaque: out = plate * (1 - Zb - Zf) + blue * Zb + yellow * Zf (Z: the passes' alphas)
    with OpenEXR.File(str(manifest.parent / PASSES_DIR / pass_file_name(FRAME_A))) as f:
        ch = {k: np.asarray(v.pixels, np.float64) for k, v in f.channels().items()}
    zb, zf = ch["Atlas.UVBackground.Z"], ch["Atlas.UVForeground.Z"]
    plate = X.srgb_to_linear(X.read_png_rgba8(tmp_path / "plate" / f"{FRAME_A:05d}.png")[..., :3] / 255.0)
    want = plate * (1 - zb - zf)[..., None] + np.array([0.0, 0.0, 1.0]) * zb[..., None]
    want = want + np.array([1.0, 1.0, 0.0]) * zf[..., None]
    err = float(np.abs(after[..., :3] - want).max())
    changed = float(np.abs(after - before).max())
    print(f"{TAG} a stroke shows in the next preview render: changed by up to {changed:.2f}, max abs err {err:.2e}")
    assert changed > 0.3 and err <= TOLERANCE


def test_the_preview_frames_the_plate_and_rebuilds_in_place(blender, tmp_path):
    """Plane, camera, material and images are named NA_..., the camera frames the plane exactly, the frame-paint
    image shows in node FramePaint once it exists, and a second build replaces rather than adds."""
    assert blender.context.scene.neural_atlas.filter_type == P.FILTER_BILINEAR  # the panel's default
    _, scene = _import(blender, tmp_path)
    # Bilinear: the compositor samples as engine render does (5.0 Map UV Bilinear, 4.x the bilinear group's taps)
    tree = compat.scene_tree(scene)
    if compat.V5:
        assert tree.nodes["NA_MapUV_Foreground"].inputs["Interpolation"].default_value == "Bilinear"
    else:
        assert tree.nodes[P.filter_switch_name("Foreground")].inputs["Switch"].default_value
    plane, cam = bpy.data.objects[V.PREVIEW_OBJECT], bpy.data.objects[V.PREVIEW_CAMERA]
    assert plane.users_collection[0].name == V.PREVIEW_COLLECTION
    xs = [plane.matrix_world @ v.co for v in plane.data.vertices]
    width, height = max(v.x for v in xs) - min(v.x for v in xs), max(v.y for v in xs) - min(v.y for v in xs)
    assert abs(width / height - X.W / X.H) < 1e-6 and max(v.x for v in xs) < 0.0  # left of the canvases
    assert cam.data.type == "ORTHO" and abs(cam.data.ortho_scale - max(width, height)) < 1e-6
    assert abs(cam.location.x - (min(v.x for v in xs) + width / 2)) < 1e-6
    nodes = bpy.data.materials[V.PREVIEW_MATERIAL].node_tree.nodes
    assert nodes["Edit_Foreground"].image.name == V.mirror_image_name("Foreground")  # the float twins
    assert nodes["Edit_Background"].image.name == V.mirror_image_name("Background")
    assert V.FRAME_PAINT_NODE not in nodes
    assert {nodes[f"Edit_{n}"].interpolation for n in ("Background", "Foreground")} == {"Linear"}
    scene.neural_atlas.filter_type = P.FILTER_NEAREST  # the panel's Filter: the preview follows
    assert {nodes[f"Edit_{n}"].interpolation for n in ("Background", "Foreground")} == {"Closest"}
    scene.neural_atlas.filter_type = P.FILTER_BILINEAR
    bpy.data.images.new(P.FRAME_PAINT_IMAGE, X.W, X.H, alpha=True, float_buffer=True)
    counts = (len(bpy.data.objects), len(bpy.data.materials), len(bpy.data.images), len(bpy.data.cameras))
    assert bpy.ops.neural_atlas.live_preview("EXEC_DEFAULT") == {"FINISHED"}  # shown: hides it
    assert not preview_plane.is_shown(scene)
    assert bpy.ops.neural_atlas.live_preview("EXEC_DEFAULT") == {"FINISHED"}  # builds again, shows it
    assert preview_plane.is_shown(scene)
    assert (len(bpy.data.objects), len(bpy.data.materials), len(bpy.data.images), len(bpy.data.cameras)) == counts
    nodes = bpy.data.materials[V.PREVIEW_MATERIAL].node_tree.nodes
    assert nodes[V.FRAME_PAINT_NODE].image.name == P.FRAME_PAINT_IMAGE
    assert bpy.data.materials[V.PREVIEW_MATERIAL].node_tree.nodes.active.name == V.FRAME_PAINT_NODE
    # the frame paint lies over the composite by its alpha: an opaque red frame paint shows red
    fp = bpy.data.images[P.FRAME_PAINT_IMAGE]
    fp.pixels.foreach_set(np.tile(np.array([1.0, 0.0, 0.0, 1.0], np.float32), X.W * X.H))
    got = X.read_exr_rgba(Path(preview_plane.render_frame(scene, FRAME_A, str(tmp_path / "fp.exr"))))
    assert np.abs(got[..., :3] - np.array([1.0, 0.0, 0.0])).max() <= 1e-6


def test_outside_the_export_the_preview_shows_the_plate_and_says_so(blender, tmp_path):
    """A plate of frames 3-7 exported for 3-5 only: at frame 7 the preview is plate frame 7 (not frame 5 held, not
    the paint over it), and the panel says the frame is outside the export; inside, the paint shows again. Live
    Preview is drawn as a toggle that is pressed while the preview is on screen."""
    from helpers import RecordingLayout
    from neural_atlas.addon import ui
    from test_relink import _panel

    manifest = X.make_export(tmp_path, frames=(3, 4, 5, 6, 7))
    data = C.load_manifest(str(manifest))
    data["passes"]["frames"] = [3, 4, 5]
    manifest.write_text(__import__("json").dumps(data))
    scene = blender.context.scene
    scene.neural_atlas.filter_type = P.FILTER_NEAREST
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    plate7 = X.srgb_to_linear(X.read_png_rgba8(tmp_path / "plate" / "00007.png")[..., :3] / 255.0)
    got7 = X.read_exr_rgba(Path(preview_plane.render_frame(scene, 7, str(tmp_path / "preview.7.exr"))))[..., :3]
    got5 = X.read_exr_rgba(Path(preview_plane.render_frame(scene, 5, str(tmp_path / "preview.5.exr"))))[..., :3]
    want5 = X.reference_frame(manifest, 5, P.FILTER_NEAREST)
    err7, err5 = float(np.abs(got7 - plate7).max()), float(np.abs(got5 - want5).max())
    print(f"{TAG} preview outside the export: frame 7 vs plate {err7:.1e}; frame 5 vs the edit {err5:.1e}")
    assert err7 <= TOLERANCE and err5 <= TOLERANCE
    plate5 = X.srgb_to_linear(X.read_png_rgba8(tmp_path / "plate" / "00005.png")[..., :3] / 255.0)
    assert float(np.abs(want5 - plate5).max()) > 0.1  # inside the export the edit shows over the plate

    line = "Frame 7 is outside the export (3-5): the preview shows the plate without paint"
    scene.frame_set(7)
    assert line in _panel()[0]
    scene.frame_set(4)
    assert not any(text.startswith("Frame ") for text in _panel()[0])
    calls = RecordingLayout().draw(ui.NEURALATLAS_PT_edit, bpy.context)
    (toggle,) = [kw for name, a, kw in calls if name == "operator" and a[0] == "neural_atlas.live_preview"]
    assert toggle.get("depress") is True
    assert blender.ops.neural_atlas.live_preview("EXEC_DEFAULT") == {"FINISHED"}  # hidden
    calls = RecordingLayout().draw(ui.NEURALATLAS_PT_edit, bpy.context)
    (toggle,) = [kw for name, a, kw in calls if name == "operator" and a[0] == "neural_atlas.live_preview"]
    assert toggle.get("depress") is False


def _first_file_size(img) -> tuple[int, int]:
    """The size of a sequence image's files: its first file's, loaded on its own (a sequence image's own size
    depends on the frame it last loaded)."""
    first = bpy.data.images.load(bpy.path.abspath(img.filepath), check_existing=False)
    try:
        return int(first.size[0]), int(first.size[1])
    finally:
        bpy.data.images.remove(first)


def test_a_proxy_preview_is_smaller_and_the_render_stays_full_size(blender, tmp_path):
    """Preview Size 50% on the preview on screen: it is built again at once, its UV passes and plate written at
    20x12 (the 40x24 plate's half) in their own folder and its images showing them, the panel saying so; nothing
    the artist made changes (unsaved paint, the edit files, the full-size preview's files). Rendered at the proxy's
    size it is the full-size preview at the sampled pixels (paint lands where it lands at full size), and Render
    Edited Clip still writes 40x24 frames. Back at 100% the full-size files show again, not written again."""
    from helpers import RecordingLayout
    from neural_atlas.addon import ui
    from neural_atlas.addon.core import preview_proxy as PX

    manifest, scene = _import(blender, tmp_path)
    assert scene.neural_atlas.preview_proxy == PX.AUTO  # Auto: a 40x24 plate is previewed at full size
    assert preview_plane.shown_size() == (100, (X.W, X.H), (X.W, X.H))
    _paint(bpy.data.images[P.edit_image_name("Background")], (1.0, 0.2, 0.05, 0.6), (0.3, 0.2, 0.8, 0.7))
    _paint(bpy.data.images[P.edit_image_name("Foreground")], (0.1, 0.9, 0.3, 0.8), (0.1, 0.1, 0.9, 0.6))
    full = X.read_exr_rgba(Path(preview_plane.render_frame(scene, FRAME_A, str(tmp_path / "full.exr"))))
    made = [manifest.parent / V.PREVIEW_UV_DIR, tmp_path / "run" / EDITS_DIR]
    disk = {p: (p.read_bytes(), p.stat().st_mtime_ns) for d in made for p in d.rglob("*") if p.is_file()}
    painted = {n: _pixels(bpy.data.images[P.edit_image_name(n)]) for n in ("Background", "Foreground")}

    scene.neural_atlas.preview_proxy = PX.choice_id(50)
    assert preview_plane.is_shown(scene) and preview_plane.shown_size() == (50, (20, 12), (X.W, X.H))
    folder = manifest.parent / PX.PROXY_DIR / "proxy_50"
    for name in (V.PREVIEW_PLATE_IMAGE, V.uv_image_name("Background"), V.uv_image_name("Foreground")):
        img = bpy.data.images[name]
        assert Path(bpy.path.abspath(img.filepath)).parent in (folder, folder / name.split("_")[-1]), img.filepath
        assert _first_file_size(img) == (20, 12), name
    for name, px in painted.items():
        img = bpy.data.images[P.edit_image_name(name)]
        assert img.is_dirty and np.array_equal(_pixels(img), px), name
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in disk} == disk
    labels = [kw.get("text", "") for n, _, kw in RecordingLayout().draw(ui.NEURALATLAS_PT_edit, bpy.context)]
    assert "Preview at 50%: 20x12 of 40x24 (the render is full size)" in [lab for lab in labels if lab]

    scene.render.resolution_percentage = 50  # the render at the proxy's size: each pixel a proxy pixel
    try:
        small = X.read_exr_rgba(Path(preview_plane.render_frame(scene, FRAME_A, str(tmp_path / "small.exr"))))
    finally:
        scene.render.resolution_percentage = 100
    rows, cols = PX.sampled((X.W, X.H), (20, 12), top_first=True)
    err = float(np.abs(small[..., :3] - full[rows][:, cols][..., :3]).max())
    print(f"{TAG} the 50% preview vs the full-size preview at the sampled pixels: max abs err {err:.1e}")
    assert small.shape == (12, 20, 4) and err <= 1e-6

    scene.neural_atlas.preview_proxy = PX.choice_id(100)
    assert bpy.data.images[V.uv_image_name("Foreground")].filepath.endswith(f"uv.{X.FRAMES[0]:05d}.exr")
    assert Path(bpy.path.abspath(bpy.data.images[V.uv_image_name("Foreground")].filepath)).parent == (
        manifest.parent / V.PREVIEW_UV_DIR / "Foreground"
    )
    assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in disk} == disk  # shown again, not written again
    scene.neural_atlas.preview_proxy = PX.choice_id(50)
    out = tmp_path / "render"
    assert bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="exr") == {"FINISHED"}
    rendered = sorted(out.glob("edit.*.exr"))
    assert len(rendered) == len(X.FRAMES)
    assert all(X.read_exr_rgba(p).shape == (X.H, X.W, 4) for p in rendered)
