"""``realign`` carries paint painted against one export onto a later export whose mapping moved, and ``fit --refine``
continues a finished fit while keeping the edit layers and exports.

The re-alignment is measured on two hand-made exports of one run with a known drift: the foreground's new UV is its
old UV shifted by a smooth, frame-independent offset (a few texels), as a refined fit moves its atlas. The paint
(a square of colour in the foreground's atlas) is rendered through the old passes and, re-aligned, through the new
ones: the same pixels, to the bilinear resampling's blur; not re-aligned, it drifts by the offset. The refine is
checked through the real CLI on a tiny fit.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from engine import contract as C
from engine.config import PRESETS
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.edit.equations import load_edit
from engine.edit.project_frame import save_edit_like
from engine.edit.realign import load_edits, placement_error, realign, realign_measured
from engine.export.manifest import Manifest
from engine.fit.run_folder import RunFolder
from engine.terms.export_names import EDITS_ALIGNED, EDITS_DIR
from tests.engine.fake_export import make_fake_export
from tests.engine_cli import run_cli
from tests.folders import tree_digest
from tests.stability.bad_inputs import TINY_FIT

W, H, T = 64, 48, 4
SIDE = 28  # the object's side in pixels
ATLAS = 32  # the foreground atlas' side in texels


def _object(t: int) -> tuple[float, float]:
    return 6.0 + 6.0 * t, 8.0 + 1.5 * t


def _layers(drift: float) -> list:
    """Background and one square object moving right; the object's UV shifted by ``drift`` (atlas units) plus a
    gentle ramp, the same at every frame (a refined fit moves its atlas, not the object)."""

    def background(t: int, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ox, oy = _object(t)
        inside = (xs >= ox) & (xs < ox + SIDE) & (ys >= oy) & (ys < oy + SIDE)
        return xs / W, 1.0 - ys / H, (~inside).astype(np.float64)

    def foreground(t: int, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ox, oy = _object(t)
        a, b = (xs - ox) / SIDE, (ys - oy) / SIDE
        inside = (a >= 0) & (a < 1) & (b >= 0) & (b < 1)
        u = 0.1 + 0.8 * a + drift * (1.0 + 0.5 * b)
        v = 1.0 - (0.1 + 0.8 * b) - drift * 0.5
        return u, v, inside.astype(np.float64)

    return [(background, (W, H)), (foreground, (ATLAS, ATLAS))]


def _paint() -> np.ndarray:
    """A square of two colours in the foreground atlas, premultiplied linear."""
    edit = np.zeros((ATLAS, ATLAS, 4), np.float32)
    edit[10:22, 9:21] = (0.8, 0.2, 0.05, 1.0)
    edit[10:22, 15:21] = (0.05, 0.3, 0.7, 1.0)
    return edit


@pytest.fixture
def shifted_run(tmp_path) -> tuple[Path, Path, Path]:
    """A run with exports v001 and v002 (its mapping moved by 0.08 atlas units, ~2.6 texels) and paint made on v001."""
    plate = np.zeros((T, H, W, 3), np.float32)
    old = make_fake_export(tmp_path / "a", plate, _layers(0.0))
    other = make_fake_export(tmp_path / "b", plate, _layers(0.08))
    new = old.parent.parent / "v002" / C.MANIFEST_NAME
    shutil.copytree(other.parent, new.parent)
    fg = old.parent.parent.parent / EDITS_DIR / "Foreground.png"
    save_edit_like(fg, _paint())
    return old, new, fg


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_realign_puts_the_paint_back_where_it_was(shifted_run):
    _, new_path, fg = shifted_run
    painted = _digest(fg)
    new, report = realign_measured(new_path)  # --from: the export before v002
    assert report["from"] == "v001" and report["to"] == "v002" and report["layers"] == ["Foreground"]
    fixed, drifted = report["realigned"], report["not_realigned"]
    print("realigned", fixed, "not realigned", drifted)
    # not re-aligned, the paint drifts by the offset; re-aligned it covers the same pixels, colours within the
    # resampling's blur at the paint's edges
    assert drifted["iou"] < 0.75 and drifted["mean_error"] > 0.2
    assert fixed["iou"] > 0.93 and fixed["mean_error"] < 0.08
    assert fixed["max_error"] < drifted["max_error"]
    # the old edit layer is kept in history, byte for byte; the new one is a PNG like it
    (kept,) = (fg.parent / "history").iterdir()
    assert _digest(kept) == painted and kept.suffix == ".png"
    assert json.loads((fg.parent / EDITS_ALIGNED).read_text())["export"] == "v002"
    # the paint's colours are kept: the re-aligned layer's interior holds the two colours
    moved = load_edit(fg)
    assert moved[..., 3].sum() == pytest.approx(_paint()[..., 3].sum(), rel=0.15)
    # again: nothing to do, nothing written
    after = _digest(fg)
    _, written = realign(new.path)
    assert written == {} and _digest(fg) == after and len(list((fg.parent / "history").iterdir())) == 1


def test_unpainted_texels_and_unseen_paint_stay(shifted_run):
    """Paint where no frame shows the atlas (a corner outside the object's square) is kept where it was."""
    _, new_path, fg = shifted_run
    edit = _paint()
    edit[0:2, 0:2] = (0.0, 0.0, 0.5, 0.5)  # the atlas' corner: outside 0.1..0.9 of both mappings
    save_edit_like(fg, edit)
    realign(new_path, "v001")
    moved = load_edit(fg)
    assert np.allclose(
        moved[0:2, 0:2], load_edit(fg.parent / "history" / next((fg.parent / "history").iterdir()).name)[0:2, 0:2]
    )
    assert moved[0:2, 0:2, 3].min() > 0.49


def test_realign_cli_and_bad_input(shifted_run):
    old_path, new_path, fg = shifted_run
    code, lines = run_cli(C.VERB_REALIGN, str(new_path), "--from", "v009")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and "v009" in lines[0] and "--from" in lines[0], lines
    code, lines = run_cli(C.VERB_REALIGN, str(old_path.parent.parent.parent))  # the run folder: its newest export
    assert code == C.EXIT_OK and any("paint carried from v001 to v002" in line for line in lines), lines
    old, new = Manifest(old_path), Manifest(new_path)
    err = placement_error(old, new, load_edits(old, {"Foreground": next((fg.parent / "history").iterdir())}),
                          load_edits(new))  # fmt: skip
    assert err["iou"] > 0.93


@pytest.mark.slow
def test_refine_continues_a_finished_fit_and_keeps_the_paint(tmp_path):
    """fit -> export -> paint -> fit --refine -> export -> realign, through the CLI on a tiny clip: the refine adds
    its steps to the finished fit, records the export the paint was made on, keeps every export and edit layer, and
    realign carries the paint onto the new export. Refusals leave the folder as it was."""
    frames, masks = write_scene(make_scene(SceneSpec(width=32, height=24, frames=3, fg_size=(12, 10))), tmp_path / "c")
    run = tmp_path / "run"
    assert run_cli("fit", frames, "--mask", masks, "--out", run, *TINY_FIT)[0] == C.EXIT_OK
    assert run_cli(C.VERB_EXPORT, run, "--no-bar")[0] == C.EXIT_OK
    fg = run / EDITS_DIR / "Foreground.png"
    edit = np.zeros_like(load_edit(fg))
    edit[:, : edit.shape[1] // 2] = (0.5, 0.1, 0.1, 1.0)
    save_edit_like(fg, edit)
    painted = _digest(fg)
    v001 = _digest(run / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME)

    before = tree_digest(run)
    code, lines = run_cli(C.VERB_REALIGN, run)  # the first export: the paint was made on it, nothing to carry
    assert code == C.EXIT_OK and lines == ["edit layers already match v001: nothing to realign"], lines
    code, lines = run_cli("fit", "--out", run, C.FIT_REFINE_FLAG, "--preset", "final", "--no-bar")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and "w_mask_prior" in lines[0], lines
    code, lines = run_cli("fit", "--out", run, C.FIT_REFINE_FLAG, "3", "--resume", "--no-bar")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and "--resume" in lines[0], lines
    code, lines = run_cli("fit", "--out", run, C.FIT_REFINE_FLAG, "3", "--set", "batch=32", "--no-bar")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and "batch" in lines[0], lines
    assert tree_digest(run) == before, "a refused refine changed the run folder"

    code, lines = run_cli("fit", "--out", run, C.FIT_REFINE_FLAG, "3", "--preset", "balanced", "--no-bar")
    assert code == C.EXIT_OK, lines
    assert RunFolder(run).read_metrics()["steps"] == 5  # 2 + 3
    cfg = RunFolder(run).read_config()
    # balanced's schedule; the fit's own settings and loss phases
    assert (cfg.steps, cfg.preset, cfg.batch) == (5, "draft", 64)
    assert cfg.bootstrap_steps == PRESETS["draft"].bootstrap_steps != PRESETS["balanced"].bootstrap_steps
    assert json.loads((run / EDITS_DIR / EDITS_ALIGNED).read_text())["export"] == "v001"
    assert _digest(fg) == painted and _digest(run / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME) == v001

    assert run_cli(C.VERB_EXPORT, run, "--no-bar")[0] == C.EXIT_OK
    code, lines = run_cli(C.VERB_REALIGN, run)
    assert code == C.EXIT_OK, lines
    history = list((run / EDITS_DIR / "history").iterdir())
    assert [_digest(p) for p in history] == [painted]
    assert json.loads((run / EDITS_DIR / EDITS_ALIGNED).read_text())["export"] == "v002"
    assert load_edit(fg)[..., 3].sum() > 0.5 * edit[..., 3].sum()  # the paint is carried, not dropped


def test_a_float_edit_layer_stays_float(shifted_run):
    """A float edit layer (``<Layer>.exr`` beside the PNG, linear premultiplied, values over 1) is re-aligned as an
    EXR, its old self kept in history as an EXR, the PNG untouched."""
    _, new_path, fg = shifted_run
    png = _digest(fg)
    exr = fg.with_suffix(C.EDIT_LAYER_FLOAT_EXT)
    paint = _paint() * np.float32(3.0)
    paint[..., 3] = _paint()[..., 3]
    save_edit_like(exr, paint)
    _, report = realign_measured(new_path, "v001")
    assert report["realigned"]["iou"] > 0.93 and report["not_realigned"]["iou"] < 0.75
    (kept,) = (fg.parent / "history").iterdir()
    assert kept.suffix == ".exr" and np.array_equal(load_edit(kept), paint)
    moved = load_edit(exr)
    assert moved[..., :3].max() == pytest.approx(paint[..., :3].max(), rel=1e-4)  # float values kept, not clipped
    assert _digest(fg) == png
