"""Refine a fit and keep the paint (bpy 4.5 and 5.0), with the real engine on a tiny synthetic clip: Fit Atlas fits,
exports and imports; the panel then offers Refine; a stroke is painted and left unsaved; Refine saves it, runs
``fit --refine``, ``export`` and ``realign`` and imports the new export: the paint is in the re-aligned edit layer on
disk and in Blender, the layer as painted is kept in ``edits/history``, and the first export is kept.

Painting operators cannot run headless (docs/blender-compat.md#painting): the stroke is its pixels, written into the
edit image as a brush would, and left unsaved. The engine runs in its own interpreter (NEURAL_ATLAS_TEST_ENGINE_PYTHON,
else the checkout's .venv); skipped when that Python has no torch or no realign verb.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from helpers import RecordingLayout, as_operator, engine_python, fit_panel, write_tiny_clip  # noqa: E402
from neural_atlas.addon import ui  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402
from neural_atlas.addon.ops import refine as refine_ops  # noqa: E402

from engine import contract as C  # noqa: E402
from engine.terms.export_names import EDITS_ALIGNED, EDITS_DIR  # noqa: E402

FAST = "steps=6 batch=256 eval_every=3 eval_pixels=256 bootstrap_steps=3 global_rigidity_steps=2"
#: The stroke: a block in the middle of the background's atlas (opaque red, 8-bit sRGB straight); the background owns
#: most pixels after a few steps, so the refine has pixels to pair there.
STROKE = (1.0, 0.0, 0.0, 1.0)


def _stroke(img) -> np.ndarray:
    """Paint the stroke's pixels into ``img`` (rows bottom-up), unsaved; returns the painted mask."""
    w, h = img.size
    px = np.zeros(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    px = px.reshape(h, w, 4)
    mask = np.zeros((h, w), bool)
    mask[h // 3 : 2 * h // 3, w // 3 : 2 * w // 3] = True
    px[mask] = STROKE
    img.pixels.foreach_set(px.ravel())
    img.update()
    assert img.is_dirty
    return mask


def _alpha(img) -> np.ndarray:
    w, h = img.size
    px = np.zeros(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    return px.reshape(h, w, 4)[..., 3]


@pytest.mark.slow
def test_refine_keeps_and_realigns_the_paint(blender, tmp_path, monkeypatch):
    py = engine_python(C.VERB_REALIGN, "torch")
    clip_dir = tmp_path / "clip"
    write_tiny_clip(py, clip_dir)
    monkeypatch.setenv("NEURAL_ATLAS_ENGINE_PYTHON", py)
    props = fit_panel(bpy, clip_dir / "frames" / "00000.png", clip_dir / "masks", tmp_path / "run", overrides=FAST)
    run = tmp_path / "run"

    calls = RecordingLayout().draw(ui.NEURALATLAS_PT_fit, blender.context)
    assert not any(c[0] == "operator" and c[1][0] == "neural_atlas.refine" for c in calls)  # no fit yet
    assert not refine_ops.NEURALATLAS_OT_refine.poll(blender.context)
    assert bpy.ops.neural_atlas.fit("EXEC_DEFAULT") == {"FINISHED"}, props.status
    assert props.manifest.endswith(str(Path("v001") / C.MANIFEST_NAME))
    calls = RecordingLayout().draw(ui.NEURALATLAS_PT_fit, blender.context)
    assert any(c[0] == "operator" and c[1][0] == "neural_atlas.refine" for c in calls)  # the finished fit: Refine
    assert refine_ops.NEURALATLAS_OT_refine.poll(blender.context)

    edit = bpy.data.images[P.edit_image_name("Background")]
    png = Path(bpy.path.abspath(edit.filepath))
    painted = _stroke(edit)
    props.refine_steps = 4
    props.refine_preset = "balanced"
    job = as_operator(refine_ops.NEURALATLAS_OT_refine).make_job(blender.context)  # saves the paint first
    assert job.commands[0].argv[3:] == [C.VERB_FIT, "--out", str(run), C.FIT_REFINE_FLAG, "4", "--preset",
                                        "balanced", "--no-bar"]  # fmt: skip
    assert [c.argv[3:] for c in job.commands[1:]] == [[C.VERB_EXPORT, str(run)], [C.VERB_REALIGN, str(run)]]
    assert not edit.is_dirty and (X.read_png_rgba8(png)[::-1][painted] == (255, 0, 0, 255)).all()
    on_disk_before = png.read_bytes()
    _stroke(edit)  # painted again, unsaved: the operator itself saves it

    assert bpy.ops.neural_atlas.refine("EXEC_DEFAULT") == {"FINISHED"}, props.status
    assert props.manifest.endswith(str(Path("v002") / C.MANIFEST_NAME)), props.manifest
    assert (run / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME).is_file()  # the export the paint was made on stays
    assert json.loads((run / C.RUN_METRICS).read_text())["steps"] == 10  # 6 + 4
    assert json.loads((run / EDITS_DIR / EDITS_ALIGNED).read_text())["export"] == "v002"
    (kept,) = (run / EDITS_DIR / "history").iterdir()  # the layer as painted, byte for byte
    assert kept.read_bytes() == on_disk_before
    # the re-aligned paint: on disk and in Blender (reloaded), most of it where it was on this tiny refine
    edit = bpy.data.images[P.edit_image_name("Background")]
    assert Path(bpy.path.abspath(edit.filepath)) == png and not edit.is_dirty
    alpha = _alpha(edit)
    on_disk = X.read_png_rgba8(png)[::-1][..., 3] / 255.0
    assert np.allclose(alpha, on_disk, atol=1 / 255)
    mass = float(alpha.sum()) / float(painted.sum())
    overlap = float((alpha >= 0.5)[painted].mean())
    print(f"[bpy {bpy.app.version_string}] paint mass kept {mass:.3f}, still on its texels {overlap:.3f}")
    assert 0.8 < mass < 1.2 and overlap > 0.8
    assert "Background: paint carried from v001 to v002" in (tmp_path / "run.blender.log").read_text()
