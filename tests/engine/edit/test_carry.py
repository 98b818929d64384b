"""Paint carried to a new fit of the same plate (``realign --from`` an export of another run folder): a split fit's
paint (one atlas per part) onto a one-layer fit of the same object, and back; measured on the plate, where the paint
shows, as the share of the old paint's pixels the new paint covers (``landed``) and their IoU.

Two hand-made fits of one moving square: the split fit maps its left half to ``Foreground1``'s atlas and its right
half to ``Foreground2``'s; the one-layer fit maps the whole square to ``Foreground``'s atlas, differently placed and
sized. Paint on each part's atlas lands on the one layer where those parts of the square are, and the reverse.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from engine import contract as C
from engine.edit.equations import load_edit
from engine.edit.project_frame import save_edit_like
from engine.edit.realign import realign_measured
from engine.terms.export_names import EDITS_ALIGNED, EDITS_DIR
from tests.engine.fake_export import make_fake_export
from tests.engine_cli import run_cli

W, H, T = 64, 48, 5
SIDE = 28
ATLAS = 32
WHOLE_ATLAS = 64  # the one layer's atlas: finer than the plate's pixels, as a fit's atlases are


def _square(t: int, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The square's own coordinates (a, b in 0..1) at frame ``t`` (it moves right and down), and inside it."""
    ox, oy = 6.0 + 6.0 * t, 8.0 + 1.5 * t
    a, b = (xs - ox) / SIDE, (ys - oy) / SIDE
    return a, b, (a >= 0) & (a < 1) & (b >= 0) & (b < 1)


def _background(t: int, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    _, _, inside = _square(t, xs, ys)
    return xs / W, 1.0 - ys / H, (~inside).astype(np.float64)


def _part(left: bool):  # type: ignore[no-untyped-def]
    """One half of the square, filling its own atlas (0.1..0.9 of it)."""

    def layer(t: int, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        a, b, inside = _square(t, xs, ys)
        half = inside & ((a < 0.5) if left else (a >= 0.5))
        local = a * 2.0 if left else a * 2.0 - 1.0
        return 0.1 + 0.8 * local, 1.0 - (0.1 + 0.8 * b), half.astype(np.float64)

    return layer


def _whole(t: int, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The whole square in one atlas, smaller and off-centre (another fit places it elsewhere)."""
    a, b, inside = _square(t, xs, ys)
    return 0.2 + 0.6 * a, 1.0 - (0.15 + 0.6 * b), inside.astype(np.float64)


def _fits(root: Path) -> tuple[Path, Path]:
    """(the split fit's manifest, the one-layer fit's), two run folders of the same plate."""
    plate = np.zeros((T, H, W, 3), np.float32)
    split = make_fake_export(root / "split", plate, [(_background, (W, H)), (_part(True), (ATLAS, ATLAS)),
                                                     (_part(False), (ATLAS, ATLAS))])  # fmt: skip
    whole = make_fake_export(root / "whole", plate, [(_background, (W, H)), (_whole, (WHOLE_ATLAS, WHOLE_ATLAS))])
    return split, whole


def _stripe(colour: tuple[float, float, float]) -> np.ndarray:
    """A band of ``colour`` across the middle of an atlas (premultiplied linear, opaque)."""
    edit = np.zeros((ATLAS, ATLAS, 4), np.float32)
    edit[12:20, 6:26] = (*colour, 1.0)
    return edit


def _edit(manifest: Path, layer: str) -> Path:
    return manifest.parent.parent.parent / EDITS_DIR / f"{layer}.png"


def test_a_split_fits_paint_lands_on_a_one_layer_fit_and_back(tmp_path):
    split, whole = _fits(tmp_path)
    save_edit_like(_edit(split, "Foreground1"), _stripe((0.8, 0.1, 0.05)))
    save_edit_like(_edit(split, "Foreground2"), _stripe((0.05, 0.2, 0.8)))
    _, report = realign_measured(whole, split)
    carried, before = report["realigned"], report["not_realigned"]
    print(f"split -> one layer: landed {carried['landed']:.3f}, IoU {carried['iou']:.3f}, "
          f"mean colour error {carried['mean_error']:.3f} (before: landed {before['landed']:.3f})")  # fmt: skip
    assert report["layers"] == ["Foreground"] and before["landed"] == 0.0
    assert carried["landed"] > 0.95 and carried["iou"] > 0.9 and carried["mean_error"] < 0.08
    assert json.loads((_edit(whole, "Foreground").parent / EDITS_ALIGNED).read_text())["export"] == "v001"
    # the one layer's atlas now holds both colours, and the blank edit layer it replaced is in its history
    fg = load_edit(_edit(whole, "Foreground"))
    assert (fg[..., 0] > 0.5).sum() > 20 and (fg[..., 2] > 0.5).sum() > 20
    assert len(list((_edit(whole, "Foreground").parent / "history").iterdir())) == 1
    # carried again from the same fit: nothing is laid on twice
    painted = _edit(whole, "Foreground").read_bytes()
    code, lines = run_cli(C.VERB_REALIGN, whole, "--from", split)
    assert code == C.EXIT_OK and lines == [f"v001 already holds the paint of {split}: nothing to carry"], lines
    assert _edit(whole, "Foreground").read_bytes() == painted

    # and back: the one layer's paint onto a fresh split fit of the same plate, each half on its part's atlas
    again = tmp_path / "again"
    shutil.copytree(tmp_path / "split", again)
    back = again / split.relative_to(tmp_path / "split")
    for name in ("Foreground1", "Foreground2"):
        save_edit_like(_edit(back, name), np.zeros((ATLAS, ATLAS, 4), np.float32))
    _, report = realign_measured(back, whole)
    print(f"one layer -> split: landed {report['realigned']['landed']:.3f}, IoU {report['realigned']['iou']:.3f}")
    assert report["layers"] == ["Foreground1", "Foreground2"]
    assert report["realigned"]["landed"] > 0.95 and report["realigned"]["iou"] > 0.9


def test_carrying_from_another_plate_is_one_line_and_changes_nothing(tmp_path):
    split, _ = _fits(tmp_path)
    save_edit_like(_edit(split, "Foreground1"), _stripe((0.8, 0.1, 0.05)))
    other = make_fake_export(tmp_path / "other", np.zeros((T, H, W + 8, 3), np.float32),
                             [(_background, (W + 8, H)), (_whole, (WHOLE_ATLAS, WHOLE_ATLAS))])  # fmt: skip
    before = _edit(other, "Foreground").read_bytes()
    code, lines = run_cli(C.VERB_REALIGN, other, "--from", split)
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1, lines
    assert lines[0].startswith(f"error: {split}: is an export of a {W}x{H} plate, not the {W + 8}x{H} plate"), lines
    assert _edit(other, "Foreground").read_bytes() == before


@pytest.mark.parametrize("paint", [False, True])
def test_a_fit_without_paint_carries_nothing(tmp_path, paint):
    split, whole = _fits(tmp_path)
    if paint:  # paint only where no frame shows it (the atlas corner): nothing lands either
        edit = np.zeros((ATLAS, ATLAS, 4), np.float32)
        edit[0:2, 0:2] = (0.5, 0.5, 0.5, 1.0)
        save_edit_like(_edit(split, "Foreground1"), edit)
    before = _edit(whole, "Foreground").read_bytes()
    code, lines = run_cli(C.VERB_REALIGN, whole, "--from", split)
    assert code == C.EXIT_OK and lines == [f"no painted texel of {split} is seen where {whole} shows the plate"], lines
    assert _edit(whole, "Foreground").read_bytes() == before


@pytest.mark.slow
def test_paint_carried_from_one_real_fit_to_another_of_the_same_clip(tmp_path):
    """Two tiny real fits of one clip (the draft schedule, and twice its steps with another seed: a better preset
    in miniature), each exported: paint on the first's foreground atlas lands on the second's where the object is."""
    from engine.data.synthetic import SceneSpec, make_scene, write_scene
    from tests.engine.export.tiny_run import TINY, export

    spec = SceneSpec(width=64, height=48, frames=5, fg_size=(24, 18), fg_start=(12.0, 12.0))
    frames, masks = write_scene(make_scene(spec), tmp_path / "clip")
    for run, steps, seed in (("a", 100, 0), ("b", 200, 1)):  # long enough for the alpha to hold the object
        held = {**TINY, "steps": str(steps), "bootstrap_steps": str(steps), "seed": str(seed), "batch": "4096"}
        sets = [a for k, v in held.items() for a in ("--set", f"{k}={v}")]
        code, lines = run_cli("fit", frames, "--mask", masks, "--out", tmp_path / run / "run", "--preset", "draft",
                              *sets, "--no-bar")  # fmt: skip
        assert code == C.EXIT_OK, lines
    old, new = export(tmp_path / "a" / "run"), export(tmp_path / "b" / "run")
    edit = load_edit(_edit(old, "Foreground"))
    h, w = edit.shape[:2]
    edit[h // 4 : 3 * h // 4, w // 4 : 3 * w // 4] = (0.7, 0.2, 0.1, 1.0)  # the middle of the object's atlas
    save_edit_like(_edit(old, "Foreground"), edit)
    _, report = realign_measured(new, old)
    done = report["realigned"]
    print(f"carried between two real fits: landed {done['landed']:.3f}, IoU {done['iou']:.3f}, "
          f"over {done['painted_pixels']} painted pixels")  # fmt: skip
    assert report["layers"] == ["Foreground"] and done["landed"] > 0.8 and done["iou"] > 0.7
