"""Render Edited Clip frame by frame (bpy 4.5 and 5.0): the steps the button's modal render takes write the same
files as one animation render, a Cancel keeps the finished frames and puts the artist's settings back, and an
error does too.

The modal path needs an event loop that a headless Blender lacks: the tests call the operator's ``start_modal``
and ``modal`` with timer events themselves (``helpers.as_operator``), as Blender's window manager would."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from helpers import RecordingLayout, as_operator  # noqa: E402
from neural_atlas.addon import compositor, ui  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402
from neural_atlas.addon.ops import render as render_ops  # noqa: E402

from engine import contract as C  # noqa: E402

FRAMES = X.FRAMES
TIMER = SimpleNamespace(type="TIMER")


def _import(blender, tmp_path):
    manifest = X.make_export(tmp_path)
    scene = blender.context.scene
    scene.neural_atlas.filter_type = P.FILTER_NEAREST
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    return scene


def _artist_settings(scene) -> dict:
    """Output settings an artist may have set, all different from what a render uses."""
    r = scene.render
    r.filepath = "//artist_out/shot_"
    r.image_settings.file_format = "JPEG"
    r.dither_intensity = 0.5
    r.use_file_extension = False
    scene.view_settings.view_transform = "Filmic" if bpy.app.version < (4, 0, 0) else "AgX"
    scene.frame_set(FRAMES[1])
    return _settings(scene)


def _settings(scene) -> dict:
    r = scene.render
    return {
        "filepath": r.filepath,
        "format": r.image_settings.file_format,
        "dither": r.dither_intensity,
        "extension": r.use_file_extension,
        "view": scene.view_settings.view_transform,
        "frame": scene.frame_current,
    }


def _animation_render(scene, out, fmt, space):
    """One animation render with the output settings ``RenderSession.begin`` sets: the render as one call to Blender."""
    session = compositor.RenderSession(scene, str(out), fmt, space)
    try:
        session.begin()
        assert "FINISHED" in bpy.ops.render.render(animation=True, scene=scene.name)
    finally:
        session.end()
    return session.written()


def _pixels(path) -> np.ndarray:
    img = bpy.data.images.load(str(path), check_existing=False)
    try:
        return np.array(img.pixels[:], dtype=np.float32)
    finally:
        bpy.data.images.remove(img)


#: PNG chunks of text and time: Blender writes the render's date and duration there (two renders of a frame differ).
PNG_METADATA = (b"tEXt", b"zTXt", b"iTXt", b"tIME")


def _png_chunks(path: Path) -> list[tuple[bytes, bytes]]:
    """A PNG's chunks (type, data) in order, without its text and time metadata."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", path
    chunks, at = [], 8
    while at < len(data):
        size = int.from_bytes(data[at : at + 4], "big")
        kind = data[at + 4 : at + 8]
        if kind not in PNG_METADATA:
            chunks.append((kind, data[at + 8 : at + 8 + size]))
        at += 12 + size
    return chunks


@pytest.mark.parametrize("fmt", ["exr", "png"])
def test_frame_steps_write_what_one_animation_render_writes(blender, tmp_path, fmt):
    scene = _import(blender, tmp_path)
    space = P.output_colorspace(C.load_manifest(scene.neural_atlas.manifest)["clip"])
    whole = _animation_render(scene, tmp_path / "whole", fmt, space)
    artist = _artist_settings(scene)
    assert bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(tmp_path / "steps"), file_format=fmt) == {
        "FINISHED"
    }
    steps = sorted((tmp_path / "steps").glob("edit.*"))
    assert [p.name for p in steps] == [f"edit.{f:05d}.{fmt}" for f in FRAMES]
    assert [p.rsplit("/", 1)[-1] for p in whole] == [p.name for p in steps]
    worst = 0.0
    for a, b in zip(whole, steps, strict=True):
        pa, pb = _pixels(a), _pixels(b)
        assert pa.shape == pb.shape == (X.H * X.W * 4,)
        worst = max(worst, float(np.abs(pa - pb).max()))
        if fmt == "png":
            assert _png_chunks(Path(a)) == _png_chunks(b)  # 8-bit PNG: the same bytes, but for the metadata
    print(f"[bpy {bpy.app.version_string}] {fmt}: frame steps vs one animation render, max abs diff {worst:.1e}")
    assert worst == 0.0
    assert _settings(scene) == artist  # the artist's output settings are back


def test_modal_render_shows_progress_and_cancel_keeps_finished_frames(blender, tmp_path):
    scene = _import(blender, tmp_path)
    artist = _artist_settings(scene)
    out = tmp_path / "modal"
    op = as_operator(render_ops.NEURALATLAS_OT_render, directory=str(out), file_format="exr")
    assert op.start_modal(blender.context) == {"RUNNING_MODAL"}
    assert not bpy.ops.neural_atlas.render.poll()  # one render per scene at a time
    layout = RecordingLayout()
    drawn = layout.draw(ui.NEURALATLAS_PT_edit, blender.context)
    assert ("operator", ("neural_atlas.render_cancel",), {"icon": "CANCEL"}) in drawn
    assert op.modal(blender.context, SimpleNamespace(type="ESC")) == {"PASS_THROUGH"}  # ESC is not a cancel
    assert op.modal(blender.context, TIMER) == {"PASS_THROUGH"}
    props = scene.neural_atlas
    assert props.render_status.startswith(f"frame 1/{len(FRAMES)} · ETA ")
    assert props.render_progress == pytest.approx(1 / len(FRAMES))
    assert bpy.ops.neural_atlas.render_cancel() == {"FINISHED"}
    assert op.modal(blender.context, TIMER) == {"CANCELLED"}
    assert sorted(p.name for p in out.glob("edit.*")) == [f"edit.{FRAMES[0]:05d}.exr"]  # the finished frame stays
    assert _settings(scene) == artist
    assert "cancelled after 1/3 frames" in props.render_status and "stay" in props.render_status
    assert render_ops.active_render(scene) is None and bpy.ops.neural_atlas.render.poll()
    assert not bpy.ops.neural_atlas.render_cancel.poll()
    drawn = layout.draw(ui.NEURALATLAS_PT_edit, blender.context)
    assert ("operator", ("neural_atlas.render",), {"icon": "RENDER_ANIMATION"}) in drawn


def test_modal_render_to_the_end_equals_the_blocking_render(blender, tmp_path):
    scene = _import(blender, tmp_path)
    assert bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(tmp_path / "block"), file_format="exr") == {
        "FINISHED"
    }
    before = scene.frame_current
    op = as_operator(render_ops.NEURALATLAS_OT_render, directory=str(tmp_path / "modal"), file_format="exr")
    assert op.start_modal(blender.context) == {"RUNNING_MODAL"}
    rets = [op.modal(blender.context, TIMER) for _ in FRAMES]
    assert rets == [{"PASS_THROUGH"}] * (len(FRAMES) - 1) + [{"FINISHED"}]
    for f in FRAMES:
        name = f"edit.{f:05d}.exr"
        np.testing.assert_array_equal(_pixels(tmp_path / "block" / name), _pixels(tmp_path / "modal" / name))
    assert scene.neural_atlas.render_status == f"rendered {len(FRAMES)} frame(s) to {tmp_path / 'modal'}"
    assert scene.frame_current == before  # the artist's frame, as after an animation render


def test_an_error_mid_render_restores_the_settings(blender, tmp_path, monkeypatch):
    scene = _import(blender, tmp_path)
    artist = _artist_settings(scene)
    real = compositor.RenderSession.render_step

    def failing(self, frame):
        if frame == FRAMES[1]:
            raise RuntimeError("render returned {'CANCELLED'}")
        real(self, frame)

    monkeypatch.setattr(compositor.RenderSession, "render_step", failing)
    out = tmp_path / "err"
    with pytest.raises(RuntimeError, match="CANCELLED"):
        bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="png")
    assert sorted(p.name for p in out.glob("edit.*")) == [f"edit.{FRAMES[0]:05d}.png"]
    assert _settings(scene) == artist
