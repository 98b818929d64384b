"""Fits that must run on any clip shape: portrait, a single frame, no mask, and the paper model."""

from __future__ import annotations

import math

import pytest

from engine.config import apply_overrides, preset_config
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.fit.fit_inputs import FitInputs
from tests.engine.fit_helpers import quiet_fit

QUICK = {"steps": "120", "batch": "500", "eval_every": "40", "bootstrap_steps": "60", "global_rigidity_steps": "30"}


#: 120 steps on these small synthetic plates (textures in [0.1, 0.9]); a grey guess scores about 13 dB.
MIN_PSNR = 18.0


def _fit(tmp_path, spec: SceneSpec, masks: bool = True, preset: str = "draft", **extra: str) -> dict:
    frames, mask_dir = write_scene(make_scene(spec), tmp_path / "clip")
    cfg = apply_overrides(preset_config(preset), {**QUICK, **extra})
    return quiet_fit(tmp_path / "run", cfg, FitInputs(frames, [mask_dir] if masks else []))


def test_portrait_clip(tmp_path):
    m = _fit(tmp_path, SceneSpec(width=64, height=112, frames=4, fg_size=(24, 30), fg_start=(15.0, 30.0)))
    assert m["working_size"] == [64, 112] and math.isfinite(m["psnr"]) and m["psnr"] > MIN_PSNR


def test_single_frame_clip(tmp_path):
    m = _fit(tmp_path, SceneSpec(width=80, height=48, frames=1, fg_size=(20, 16), fg_start=(20.0, 10.0)))
    assert m["frames"] == 1 and math.isfinite(m["psnr"]) and m["psnr"] > MIN_PSNR


def test_background_only_fit_without_masks(tmp_path):
    m = _fit(tmp_path, SceneSpec(width=80, height=48, frames=3, fg_size=(20, 16), fg_start=(20.0, 10.0)), masks=False)
    assert m["alpha_iou"] == [] and math.isfinite(m["psnr"]) and m["psnr"] > MIN_PSNR


@pytest.mark.slow
def test_paper_model_runs(tmp_path):
    m = _fit(
        tmp_path,
        SceneSpec(width=64, height=48, frames=3, fg_size=(20, 16), fg_start=(20.0, 10.0)),
        preset="paper",
        steps="5",
        batch="256",
        pretrain_iters="5",
    )
    assert m["model"] == "paper" and m["steps"] == 5 and math.isfinite(m["psnr"])
