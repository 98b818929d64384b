"""Paint on a plate frame (bpy 4.5 and 5.0): Paint on Frame at frame N makes a transparent plate-sized image, Land
Paint on Atlases runs ``engine project-frame`` (the real engine, out of process) and the paint lands on the atlases
and shows on every frame.

The export is the tests' own (``fake_export``), 96x64, its foreground a disc moving 6 px per frame whose UVs are
attached to it (the atlas moves with the disc, 1.2 texels per pixel), so "moved with the object" is exact: the
paint laid at frame N must appear 6 px further per frame. Painting operators cannot run headless
(docs/blender-compat.md#painting): the stroke is its pixels, written into ``NA_FramePaint`` as a brush would.

Checked: the edit layer file equals what the engine's ``project-frame`` makes from the same input (byte for byte),
the previous edit layer is in ``edits/history/``, unsaved atlas paint from before Land is on disk after it, the
compositor's render at frame N shows the painted colour on the stroke (error measured on the pixels the object
owns), and at other frames the paint has moved with the object and equals ``engine render`` of the landed edit.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from helpers import RecordingLayout, drive_modal, engine_python  # noqa: E402
from neural_atlas.addon import compositor, preview_plane, ui  # noqa: E402
from neural_atlas.addon.core import frame_paint as FP  # noqa: E402
from neural_atlas.addon.core import running  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402
from neural_atlas.addon.ops import frame_paint as fp_ops  # noqa: E402

from engine import contract as C  # noqa: E402
from engine.terms.cli import VERB_RENDER  # noqa: E402
from engine.terms.export_names import alpha_pass, pass_file_name, uv_pass  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
TAG = f"[bpy {bpy.app.version_string}]"
W, H = 96, 64
FG_ATLAS = (48, 48)
#: The frame painted on, and the disc's centre per frame (x moves 6 px a frame; y fixed), its radius.
N = 4
SPEED = 6
RADIUS = 14.0
#: The stroke, rows top-first and columns of the plate at frame N (inside the disc: the foreground owns it).
ROWS, COLS = slice(26, 38), slice(30, 42)
#: Its colour as an 8-bit image stores it (sRGB, straight alpha, opaque).
STROKE = (1.0, 0.3, 0.1, 1.0)
#: The bytes Blender stores it as (0.3 * 255 = 76.5 rounds up).
STROKE8 = (255, 77, 26, 255)
#: Unsaved atlas paint made before Land (texels the stroke does not reach), as the edit images store it.
UNSAVED = (0.0, 1.0, 0.0, 1.0)


def _centre(t: int) -> tuple[float, float]:
    return 36.0 + SPEED * (t - 3), 32.0


def _attach_foreground(manifest: Path) -> None:
    """Rewrite each frame's passes: the foreground a disc whose UVs move with it (40 px across the atlas), the
    background behind it (0.85 outside, as the fake export has it)."""
    m = C.load_manifest(str(manifest))
    y, x = np.mgrid[0:H, 0:W]
    for t in m["passes"]["frames"]:
        path = manifest.parent / m["passes"]["dir"] / pass_file_name(t)
        with OpenEXR.File(str(path)) as f:
            ch = {k: np.asarray(v.pixels, np.float32).copy() for k, v in f.channels().items()}
        cx, cy = _centre(t)
        d = np.hypot(x + 0.5 - cx, y + 0.5 - cy)
        fg = np.clip((RADIUS - d) / 2.0, 0.0, 1.0).astype(np.float32)
        u = (x + 0.5 - cx) / 40.0 + 0.5
        v = (cy - (y + 0.5)) / 40.0 + 0.5
        for name, val in (("X", u), ("Y", v), ("Z", fg)):
            ch[C.channel_name(uv_pass("Foreground"), name)] = val.astype(np.float32)
        ch[C.channel_name(alpha_pass("Foreground"), "V")] = fg
        bg = (0.85 * (1.0 - fg)).astype(np.float32)
        ch[C.channel_name(uv_pass("Background"), "Z")] = bg
        ch[C.channel_name(alpha_pass("Background"), "V")] = bg
        X.write_exr(path, ch)


@pytest.fixture
def export(tmp_path, monkeypatch):
    """``make_export(root)``: the 96x64 export with the attached foreground (the same files for the same root name)."""
    monkeypatch.setattr(X, "W", W)
    monkeypatch.setattr(X, "H", H)
    monkeypatch.setitem(X.ATLAS_SIZES, "Foreground", FG_ATLAS)

    def make(root: Path) -> Path:
        manifest = X.make_export(root)
        _attach_foreground(manifest)
        return manifest

    return make


def _pixels(img) -> np.ndarray:
    """(h, w, 4) float32, rows top-first."""
    w, h = img.size
    px = np.zeros(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    return px.reshape(h, w, 4)[::-1]


def _set_pixels(img, rgba_top_first: np.ndarray) -> None:
    img.pixels.foreach_set(np.ascontiguousarray(rgba_top_first[::-1], np.float32).ravel())
    img.update()


def _paint_atlas(layer: str) -> None:
    """Unsaved atlas paint: a 3x3 block at the atlas's top-left corner (the disc's UVs never reach it)."""
    img = bpy.data.images[P.edit_image_name(layer)]
    px = _pixels(img)
    px[:3, :3] = UNSAVED
    _set_pixels(img, px)
    assert img.is_dirty


def _import(blender, manifest: Path, setup_paint: bool = False) -> None:
    """Import Atlas; ``setup_paint``: with the canvases and the live preview plane (``NA_Preview``)."""
    scene = blender.context.scene
    scene.neural_atlas.filter_type = P.FILTER_NEAREST
    done = blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest), setup_paint=setup_paint)
    assert done == {"FINISHED"}


def _start(blender, frame: int = N):
    blender.context.scene.frame_set(frame)
    assert blender.ops.neural_atlas.frame_paint_start("EXEC_DEFAULT") == {"FINISHED"}
    return blender.data.images[P.FRAME_PAINT_IMAGE]


def _stroke(img) -> None:
    """The brush's pixels over the plate at frame N, left unsaved."""
    px = _pixels(img)
    px[ROWS, COLS] = STROKE
    _set_pixels(img, px)


def _read_exr(path: Path) -> np.ndarray:
    return X.read_exr_rgba(path)[..., :3].astype(np.float64)


def test_paint_on_frame_starts_a_transparent_plate_sized_image(blender, export, tmp_path):
    """No preview plane: the image alone (the Image Editor paints it); a frame without passes is one line."""
    manifest = export(tmp_path)
    _import(blender, manifest)
    assert bpy.data.objects.get(P.PREVIEW_OBJECT) is None
    img = _start(blender)
    path = tmp_path / "run" / "edits" / "frames" / "frame.00004.png"
    assert tuple(img.size) == (W, H) and img[FP.FRAME_PROP] == N and Path(bpy.path.abspath(img.filepath)) == path
    assert _pixels(img)[..., 3].max() == 0.0 and not img.is_dirty
    assert (X.read_png_rgba8(path)[..., 3] == 0).all()
    assert not bpy.ops.neural_atlas.frame_paint_land.poll()  # greyed: nothing painted yet

    _stroke(img)
    img2 = _start(blender, 5)  # another frame: the strokes of frame 4 are saved to their file first
    assert img2 == img and img[FP.FRAME_PROP] == 5 and _pixels(img)[..., 3].max() == 0.0
    assert (X.read_png_rgba8(path)[ROWS, COLS] == STROKE8).all()
    _start(blender, N)  # back to frame 4: its paint comes back from the file
    assert np.allclose(_pixels(img)[ROWS, COLS], np.float32(STROKE8) / 255, atol=1e-6)

    blender.context.scene.frame_set(9)
    with pytest.raises(RuntimeError, match="Frame 9 has no passes in the imported export \\(frames 3-5\\)"):
        blender.ops.neural_atlas.frame_paint_start("EXEC_DEFAULT")


def test_the_preview_plane_shows_the_frame_paint_and_paints_it(blender, export, tmp_path):
    """The live preview built by the import (before any frame paint) gains its "FramePaint" node on Paint on Frame:
    the node shows the frame paint and is the active paint slot, and a render of the preview at frame N shows the
    stroke over the composite (its sRGB colour decoded), the plate elsewhere. The viewport shows unsaved strokes from
    memory (Cycles treats every image as built in for a viewport render), but a final render reads a file image from
    its file, so the stroke is saved first, as switching frames or Land does."""
    _import(blender, export(tmp_path), setup_paint=True)
    obj = bpy.data.objects[P.PREVIEW_OBJECT]
    mat = obj.material_slots[0].material
    assert fp_ops.PREVIEW_NODE not in mat.node_tree.nodes
    img = _start(blender)
    mat = bpy.data.objects[P.PREVIEW_OBJECT].material_slots[0].material
    node = mat.node_tree.nodes[fp_ops.PREVIEW_NODE]
    assert node.image == img and mat.node_tree.nodes.active == node
    scene = blender.context.scene
    before = X.read_exr_rgba(Path(preview_plane.render_frame(scene, N, str(tmp_path / "before.exr"))))
    _stroke(img)
    img.save()
    after = X.read_exr_rgba(Path(preview_plane.render_frame(scene, N, str(tmp_path / "after.exr"))))
    c = np.float64(STROKE8[:3]) / 255
    want = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)  # IEC 61966-2-1
    stroke_err = float(np.abs(after[ROWS, COLS, :3] - want).max())
    outside = np.ones((H, W), bool)
    outside[ROWS, COLS] = False
    rest = float(np.abs(after[outside][:, :3] - before[outside][:, :3]).max())
    print(f"{TAG} preview with frame paint: stroke vs its colour {stroke_err:.1e}, elsewhere unchanged {rest:.1e}")
    assert stroke_err <= 2e-3  # an 8-bit sRGB image decoded by Blender
    assert rest == 0.0


def test_land_refuses_an_empty_frame_paint_in_one_line(blender, export, tmp_path, monkeypatch):
    monkeypatch.setenv("NEURAL_ATLAS_ENGINE_PYTHON", engine_python(C.VERB_PROJECT_FRAME, "cv2, scipy"))
    _import(blender, export(tmp_path))
    with pytest.raises(RuntimeError, match="Nothing to land: press Paint on Frame"):
        bpy.ops.neural_atlas.frame_paint_land("EXEC_DEFAULT")
    _start(blender)
    line = "Nothing to land: the frame paint of frame 4 is empty (paint over the plate first)"
    with pytest.raises(RuntimeError, match=line.replace("(", "\\(").replace(")", "\\)")):
        bpy.ops.neural_atlas.frame_paint_land("EXEC_DEFAULT")
    assert not (tmp_path / "run" / "edits" / "history").exists()


def _engine(py: str, *args: str) -> None:
    subprocess.run([py, "-m", "engine", *args], cwd=ROOT, check=True, timeout=300, capture_output=True)


@pytest.mark.slow
def test_paint_laid_on_frame_n_lands_on_the_atlas_and_shows_on_every_frame(blender, export, tmp_path, monkeypatch):
    py = engine_python(C.VERB_PROJECT_FRAME, "cv2, scipy")
    monkeypatch.setenv("NEURAL_ATLAS_ENGINE_PYTHON", py)
    manifest = export(tmp_path / "shot")
    edits = tmp_path / "shot" / "run" / "edits"
    _import(blender, manifest)
    _paint_atlas("Foreground")
    _paint_atlas("Background")
    img = _start(blender)
    _stroke(img)
    assert bpy.ops.neural_atlas.frame_paint_land.poll()
    assert bpy.ops.neural_atlas.frame_paint_land("EXEC_DEFAULT") == {"FINISHED"}

    # the previous edit layer (the unsaved paint saved into it first) is in history; both files hold that paint
    (history,) = (edits / "history").glob("Foreground.*.png")
    fg_now = X.read_png_rgba8(edits / "Foreground.png")
    green = np.array([0, 255, 0, 255], np.uint8)
    assert (X.read_png_rgba8(history)[:3, :3] == green).all() and (fg_now[:3, :3] == green).all()
    assert (X.read_png_rgba8(edits / "Background.png")[:3, :3] == green).all()  # saved, not landed on
    assert not list((edits / "history").glob("Background.*"))
    # the frame paint is kept, landed, and the image starts afresh
    (landed,) = (edits / "frames" / "landed").glob("frame.00004.*.png")
    assert (X.read_png_rgba8(landed)[ROWS, COLS] == STROKE8).all()
    assert _pixels(img)[..., 3].max() == 0.0 and not img.is_dirty and not bpy.ops.neural_atlas.frame_paint_land.poll()
    # the edit image shows the landed file
    edit_img = bpy.data.images[P.edit_image_name("Foreground")]
    assert not edit_img.is_dirty
    assert np.array_equal(np.round(_pixels(edit_img) * 255).astype(np.uint8), fg_now)

    # the same input through the engine directly: the same file, byte for byte
    ref_manifest = export(tmp_path / "ref")
    ref_edits = tmp_path / "ref" / "run" / "edits"
    shutil.copyfile(history, ref_edits / "Foreground.png")
    _engine(py, C.VERB_PROJECT_FRAME, str(ref_manifest), "--frame", str(N), "--edit", str(landed))
    assert (ref_edits / "Foreground.png").read_bytes() == (edits / "Foreground.png").read_bytes()
    # what changed (premultiplied, so a texel with alpha 0 whose colour the engine writes as 0 is not a change)
    before = X.read_png_rgba8(history).astype(np.float64) / 255
    after = fg_now.astype(np.float64) / 255
    premult = lambda px: np.concatenate([px[..., :3] * px[..., 3:], px[..., 3:]], -1)  # noqa: E731
    diff = np.abs(premult(after) - premult(before)).max(-1)
    changed = diff > 1.5 / 255
    # where it changed: the texels under the stroke at frame N (u, v of the stroke's pixel centres)
    cx, cy = _centre(N)
    ys, xs = np.mgrid[ROWS, COLS]
    u = (xs + 0.5 - cx) / 40.0 + 0.5
    v = (cy - (ys + 0.5)) / 40.0 + 0.5
    cols = np.floor(u * FG_ATLAS[0]).astype(int)
    rows = FG_ATLAS[1] - 1 - np.floor(v * FG_ATLAS[1]).astype(int)
    under = np.zeros(changed.shape, bool)
    under[rows, cols] = True
    near = np.zeros_like(under)
    r0, r1, c0, c1 = rows.min(), rows.max(), cols.min(), cols.max()
    near[max(0, r0 - 2) : r1 + 3, max(0, c0 - 2) : c1 + 3] = True
    print(f"{TAG} edit layer: changed under the stroke {changed[under].mean():.2f}, elsewhere {diff[~near].max():.4f}")
    assert changed[under].all() and not changed[~near].any()

    # the compositor at frame N shows the painted colour on the stroke, and at 3 and 5 it moved with the object
    out = tmp_path / "blender"
    compositor.render(bpy.context.scene, str(out), "exr")
    want = X.srgb_to_linear(np.array(STROKE8[:3]) / 255.0)
    inner = (slice(ROWS.start + 1, ROWS.stop - 1), slice(COLS.start + 1, COLS.stop - 1))
    errs, where = {}, {}
    for t in (3, 4, 5):
        dx = SPEED * (t - N)
        frame = _read_exr(out / f"edit.{t:05d}.exr")
        stroke = frame[ROWS, COLS.start + dx : COLS.stop + dx]
        core = frame[inner[0], inner[1].start + dx : inner[1].stop + dx]
        errs[t] = (float(np.abs(core - want).max()), float(np.abs(stroke - want).max()))
        ys, xs = np.nonzero(np.abs(frame - want).max(-1) < 1e-3)  # the pixels showing the paint's colour
        where[t] = (len(xs), float(xs.mean()), float(ys.mean()))
    for t in (3, 5):  # the same pixels, moved with the object
        assert where[t][0] == where[N][0] and where[t][2] == where[N][2]
        assert where[t][1] - where[N][1] == pytest.approx(SPEED * (t - N), abs=1e-9)
    engine_out = tmp_path / "engine"
    _engine(py, VERB_RENDER, str(manifest), "--out", str(engine_out), "--format", "exr", "--filter", "nearest")
    vs_engine = max(
        float(np.abs(_read_exr(out / f"edit.{t:05d}.exr") - _read_exr(engine_out / f"edit.{t:05d}.exr")).max())
        for t in (3, 4, 5)
    )
    print(
        f"{TAG} frame paint landed: frame {N} stroke core max err {errs[N][0]:.2e} (whole stroke {errs[N][1]:.2e}); "
        f"{where[N][0]} px of its colour at x {where[N][1]:.1f}, frame 3 at {where[3][1]:.1f}, 5 at {where[5][1]:.1f}; "
        f"frame 3 core {errs[3][0]:.2e}, frame 5 core {errs[5][0]:.2e}; "
        f"Blender vs engine render, frames 3-5: {vs_engine:.2e}"
    )
    assert all(e[0] <= 1e-3 for e in errs.values())
    assert vs_engine <= 1e-5


def test_the_modal_path_shows_the_stages_and_lands(blender, export, tmp_path, monkeypatch):
    """The UI path (hand-made TIMER events, no event loop headless): the bar moves through the engine's stages, a
    second job cannot start and Paint on Frame is greyed meanwhile, and the paint lands."""
    monkeypatch.setenv("NEURAL_ATLAS_ENGINE_PYTHON", engine_python(C.VERB_PROJECT_FRAME, "cv2, scipy"))
    _import(blender, export(tmp_path))
    _stroke(_start(blender))
    seen, drawn = [], []

    def events(tick, job):
        props = bpy.context.scene.neural_atlas
        polls = (bpy.ops.neural_atlas.fit.poll(), bpy.ops.neural_atlas.frame_paint_start.poll())
        seen.append((props.progress, props.status, any(polls)))
        if tick == 0:  # the Paint & Render panel while it runs: the bar and Cancel under the buttons
            drawn.extend(RecordingLayout().draw(ui.NEURALATLAS_PT_edit, bpy.context))
        return "TIMER"

    ret, op, job = drive_modal(fp_ops.NEURALATLAS_OT_frame_paint_land, bpy.context, events)
    assert ret == {"FINISHED"}, op.reports
    ops = [a[0] for name, a, _ in drawn if name == "operator"]
    assert {"neural_atlas.frame_paint_start", "neural_atlas.frame_paint_land", "neural_atlas.cancel"} <= set(ops)
    assert any(name == "progress" for name, _, _ in drawn)
    assert any(s.startswith(f"{FP.LAND_LABEL} 2/3: projecting") for _, s, _ in seen), seen
    assert not any(other for _, _, other in seen)  # one engine job per scene; the frame paint is not re-targeted
    assert running.jobs() == {} and bpy.context.scene.neural_atlas.progress == 1.0
    assert list((tmp_path / "run" / "edits" / "history").glob("Foreground.*.png"))
    assert os.path.isfile(job.log_path)
