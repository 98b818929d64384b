"""The bench's decomposition score: ``fg_iou``, the foreground layers' alpha (>= 0.5) against the precise masks,
pooled over the evaluation frames, on a tiny synthetic clip fitted with degraded masks. It is recorded in every
curve point, equals a direct computation from the same model's alpha, and is high on an easy scene."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from bench.__main__ import main as bench_main
from bench.bench import BENCH_JSON, BenchPlan, run_bench
from bench.bench_clip import resolve_clip
from bench.bench_evaluation import FG_ALPHA_THRESHOLD, evaluate, foreground
from bench.bench_runs import Run, _prepare
from bench.bench_summary import summary_table
from bench.degrade import Degradation, write_degraded
from engine import contract as C
from engine.config import apply_overrides, preset_config
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.fit.device import torch_threads
from engine.fit.evaluation import render_frame
from engine.fit.trainer import Trainer

SPEC = SceneSpec(width=64, height=48, frames=6, fg_size=(24, 18), fg_start=(12.0, 10.0), fg_velocity=(3.0, 1.0))
#: Enough for the foreground alpha to settle on this scene (about 3 s on one thread).
STEPS = 300
#: The tiny scene's object is 24 x 18 px: a standard recipe's 10 px would swallow it; this one is to scale.
TINY_DEGRADATION = Degradation(dilate_px=2, drop_fraction=0.2)


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("decomp") / "synth"
    write_scene(make_scene(SPEC), root)
    return root


@pytest.fixture(scope="module")
def dilated(clip, tmp_path_factory) -> Path:
    return write_degraded(clip / "masks", tmp_path_factory.mktemp("deg") / "synth", TINY_DEGRADATION)


def test_score_masks_default_to_the_clip_folders_own(clip, dilated, tmp_path, capsys):
    assert resolve_clip(clip).score_masks == [clip / "masks"]
    assert resolve_clip(clip, [dilated]).score_masks == [clip / "masks"]  # degraded fit, precise score
    assert resolve_clip(clip / "frames", [dilated]).score_masks == []
    assert resolve_clip(clip / "frames", [dilated], score_masks=[clip / "masks"]).score_masks == [clip / "masks"]
    other = tmp_path / "other"
    other.mkdir()
    args = ["bench", str(clip), str(clip), "--score-masks", str(other), "--budget-seconds", "1"]
    assert bench_main(args) == C.EXIT_BAD_INPUT  # --score-masks is for one clip
    assert "--score-masks need exactly one clip" in capsys.readouterr().err


@pytest.mark.slow
def test_fg_iou_is_the_foreground_alpha_against_the_precise_masks(clip, dilated):
    torch.manual_seed(0)
    spec = resolve_clip(clip, [dilated])
    cfg = apply_overrides(preset_config("draft"), {"steps": str(STEPS), "batch": "200"})
    device = torch.device("cpu")
    with torch_threads(1):
        point, wts = _fit_and_evaluate(spec, cfg, clip.parent / "work", device)
    gt = make_scene(SPEC).masks
    inter = union = 0
    for t, w in wts.items():
        fg = (1.0 - w[..., 0]) >= FG_ALPHA_THRESHOLD - 1e-6  # two layers: foreground = 1 - background
        assert (fg == foreground(w)).mean() > 0.999
        inter += int((foreground(w) & gt[t]).sum())
        union += int((foreground(w) | gt[t]).sum())
    assert point["fg_iou"] == pytest.approx(inter / union, abs=1e-4)
    # the alpha follows the 2-px grown masks it was given, whose own IoU against the precise ones is about 0.7
    assert point["fg_iou"] > 0.6, point


def _fit_and_evaluate(spec, cfg, work, device) -> tuple[dict, dict[int, np.ndarray]]:
    """A fit as the bench trains it, its evaluation, and the eval frames' layer weights rendered again."""
    state = _prepare(spec, cfg, work, 3, device)
    gt = make_scene(SPEC).masks
    assert state.score_masks is not None and (state.score_masks == gt).all()
    assert not (state.video.masks[0].cpu().numpy() == gt).all()  # the fit got the degraded ones
    prep = state.prepared
    trainer = Trainer(cfg, prep, prep.analyse(cfg), device, video=state.video)
    trainer.calibrate()
    while not trainer.finished:
        trainer.train_step()
    point = evaluate(Run(state, trainer, []), device, 4)
    return point, {t: render_frame(trainer.model, t, prep.size, device)[1] for t in state.eval_frames}


def test_the_bench_records_fg_iou_in_every_point(clip, dilated, tmp_path):
    spec = resolve_clip(clip, [dilated])
    plan = BenchPlan(("draft",), 30.0, {"steps": "4", "batch": "200"}, evals=1, eval_frames=0, sequential=True,
                     device_name="cpu", threads=1)  # fmt: skip
    rec = run_bench([spec], plan, tmp_path, plot=False)
    assert rec["clips"][0]["score_masks"] == [str((clip / "masks").resolve())]
    assert rec["clips"][0]["masks"] == [str(dilated.resolve())]
    for point in rec["runs"][0]["curve"]:
        assert 0.0 <= point["fg_iou"] <= 1.0
    assert json.loads((tmp_path / BENCH_JSON).read_text())["runs"][0]["curve"][-1]["fg_iou"] == point["fg_iou"]
    assert f"| {point['fg_iou']:.3f} |" in summary_table(rec).splitlines()[-1]
    plan = BenchPlan(("draft",), 30.0, {"steps": "2", "batch": "200"}, evals=1, sequential=True, device_name="cpu",
                     threads=1)  # fmt: skip
    bare = run_bench([resolve_clip(clip / "frames", [dilated])], plan, tmp_path / "bare", plot=False)
    assert bare["runs"][0]["curve"][-1]["fg_iou"] is None  # nothing to score against
