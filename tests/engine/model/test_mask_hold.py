"""The mask hold: a thin object's masks stay fitted after the bootstrap, because the mask prior holds too little
of them; a thick object's fit is what it was."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from engine.config import SCHEMA_VERSION, FitConfig, preset_config
from engine.data.flow import FlowField
from engine.data.video import build_video_tensors, mask_hold_layers, mask_prior, prior_coverage
from engine.loss_terms import loss_weights
from engine.model.atlas_model import FastModel
from engine.model.losses import mask_bce
from engine.model.motion_init import LayerMotion

T, W, H = 4, 200, 120


def _masks() -> np.ndarray:
    """Layer 0: a 120x90 block; layer 1: a 40x20 body on two 4 px legs, 40 px long; layer 2: empty."""
    m = np.zeros((3, T, H, W), bool)
    m[0, :, 10:100, 10:130] = True
    m[1, :, 10:30, 150:190] = True
    m[1, :, 30:70, 155:159] = True
    m[1, :, 30:70, 180:184] = True
    return m


def test_coverage_is_the_share_of_the_mask_the_prior_holds():
    masks = _masks()
    prior = mask_prior(masks, 12.0)
    cover = prior_coverage(masks, prior)
    assert cover[0] == pytest.approx(float((prior[0] == 1).sum()) / masks[0].sum())
    # the block: farther than the 12 px margin from its outline, about 96 x 66 of 120 x 90
    assert cover[0] == pytest.approx(96 * 66 / (120 * 90), abs=0.02)
    # the body: farther than 0.4 of its 10 px depth, about 32 x 12 of its 800 px; the legs: nothing
    assert cover[1] == pytest.approx(32 * 12 / (800 + 2 * 160), abs=0.02)
    assert cover[2] is None  # no mask pixel: nothing to hold, and no division by zero
    assert mask_hold_layers(cover, 0.4).tolist() == [False, True, False]
    assert mask_hold_layers(cover, 0.0).tolist() == [False, False, False]
    assert mask_hold_layers(cover, 1.0).tolist() == [True, True, False]


def _motion() -> LayerMotion:
    return LayerMotion(
        to_ref=np.stack([np.eye(2, 3)] * T), center=np.array([W / 2, H / 2]), half_extent=W / 2, aspect=(1.0, 0.75)
    )


def _losses(cfg: FitConfig, masks: np.ndarray, step: int):
    from engine.model.objective import compute_losses

    frames = np.random.default_rng(0).random((T, H, W, 3), dtype=np.float32)
    zeros = np.zeros((T - 1, H, W, 2), np.float32)
    ok = np.ones((T - 1, H, W), bool)
    flow = FlowField(zeros, zeros, ok, ok, "none", 1.0)
    video = build_video_tensors(frames, masks, flow, cfg.mask_prior_margin_px, torch.device("cpu"))
    torch.manual_seed(0)
    model = FastModel(cfg, (W, H), T, [_motion()] * (1 + masks.shape[0]))
    gen = torch.Generator().manual_seed(0)
    ix, iy = torch.randint(0, W, (2000,), generator=gen), torch.randint(0, H, (2000,), generator=gen)
    t = torch.randint(0, T, (2000,), generator=gen)
    total, terms = compute_losses(model, video, cfg, step, ix, iy, t)
    return video, model, (ix, iy, t), total, terms


def test_after_the_bootstrap_only_the_thin_layer_keeps_its_mask_term():
    cfg = dataclasses.replace(preset_config("draft"), mask_hold_coverage=0.4)
    masks = _masks()
    after = cfg.bootstrap_steps
    assert loss_weights(cfg, after - 1)["mask_hold"] == 0.0 and loss_weights(cfg, after)["mask_hold"] == cfg.w_mask
    video, model, (ix, iy, t), _, terms = _losses(cfg, masks, after)
    assert mask_hold_layers(video.prior_coverage, cfg.mask_hold_coverage).tolist() == [False, True, False]
    with torch.no_grad():
        a = model.alpha(torch.stack((ix, iy), -1).float() + 0.5, t)[:, 1:]
        m = torch.from_numpy(masks)[:, t, iy, ix].t()
        valid = torch.zeros_like(m)
        valid[:, 1] = True  # the thin layer alone (every frame has its mask)
        expected = mask_bce(a, m, valid)
    assert float(terms["mask_hold"].detach()) == pytest.approx(float(expected), rel=1e-5)
    # during the bootstrap the mask term covers every layer; the hold adds nothing there
    terms_boot = _losses(cfg, masks, after - 1)[-1]
    assert "mask_hold" not in terms_boot and "mask" in terms_boot


def test_thick_objects_and_a_zero_threshold_fit_as_before():
    masks = _masks()[:1]  # the block alone
    held = dataclasses.replace(preset_config("draft"), mask_hold_coverage=0.4)
    plain = dataclasses.replace(preset_config("draft"), mask_hold_coverage=0.0)
    step = held.bootstrap_steps + 10
    video, _, _, total_held, terms_held = _losses(held, masks, step)
    assert not mask_hold_layers(video.prior_coverage, held.mask_hold_coverage).any()
    assert "mask_hold" not in terms_held
    _, _, _, total_plain, _ = _losses(plain, masks, step)
    assert float(total_held.detach()) == float(total_plain.detach())
    # a thin object with the hold off: no term either
    terms = _losses(plain, _masks(), step)[-1]
    assert "mask_hold" not in terms


def test_a_run_that_predates_the_hold_loads_without_it():
    cfg = FitConfig.from_json(json.dumps({"schema": SCHEMA_VERSION, "config": {"steps": 10}}))
    assert cfg.mask_hold_coverage == 0.0
    assert preset_config("draft").mask_hold_coverage == pytest.approx(0.4)
