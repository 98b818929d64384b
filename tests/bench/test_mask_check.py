"""`bench masks`: the mask snap alone on every clip of a folder, scored against the precise masks."""

from __future__ import annotations

import numpy as np
import pytest

from bench.__main__ import main as bench_main
from bench.degrade import Degradation, write_degraded
from bench.mask_check import check_all, check_clip, pooled_iou
from engine import contract as C
from engine.data.synthetic import SceneSpec, make_scene, write_scene

SPEC = SceneSpec(width=160, height=112, frames=5, fg_size=(60, 44), fg_start=(40.0, 30.0))


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    base = tmp_path_factory.mktemp("maskcheck")
    write_scene(make_scene(SPEC), base / "sprite")
    return base


def test_pooled_iou_counts_only_frames_with_a_mask():
    truth = np.zeros((3, 4, 4), bool)
    truth[:, 1:3, 1:3] = True
    masks = truth.copy()
    masks[1] = False  # a dropped frame: no opinion, not a miss
    masks[2, 0, 0] = True
    assert pooled_iou(masks, truth) == pytest.approx(8 / 9)
    assert pooled_iou(np.zeros_like(truth), truth) is None


def test_a_dilated_mask_is_snapped_back_and_a_precise_one_kept(root, tmp_path):
    clip = root / "sprite"
    loose = write_degraded(clip / "masks", tmp_path / "loose", Degradation(dilate_px=6, drop_fraction=0.2))
    row = check_clip(clip, loose, reach_px=12)
    assert row["frames"] == SPEC.frames and row["snap_px"] < 0
    assert row["given_iou"] < 0.85 < 0.95 < row["snapped_iou"]
    (exact,) = check_all(root, tmp_path / "out", "exact")
    assert exact["clip"] == "sprite" and exact["snap_px"] == 0
    assert exact["given_iou"] == exact["snapped_iou"] == pytest.approx(1.0)
    # the 60x44 sprite: the prior holds what lies deeper than 0.4 of its 22 px depth, about 42 x 26 px of it
    assert exact["prior_coverage"] == pytest.approx(42.4 * 26.4 / (60 * 44), abs=0.03)
    assert exact["held"] is False  # above the 0.4 under which a fit holds the masks for all its steps
    assert (tmp_path / "out" / "masks" / "exact" / "sprite").is_dir()


def test_the_cli_prints_the_table(root, tmp_path, capsys):
    assert bench_main(["masks", str(root), "--degrade", "exact", "--out", str(tmp_path)]) == C.EXIT_OK
    out = capsys.readouterr().out
    assert "| sprite | 5 | 1.000 | 0 | 1.000 |" in out
    assert bench_main(["masks", str(tmp_path / "nothing")]) == C.EXIT_BAD_INPUT
