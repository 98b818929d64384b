"""Model contracts: the fast model starts at its flow-estimated motion, weights sum to one, the atlas is
empty outside its rectangle; the paper model has the paper's shapes and calibrates to scaled identity."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from engine.config import preset_config
from engine.model.atlas_model import FastModel, motion_regions
from engine.model.fields import Grid2D, Grid3D, PositionalEncoding, level_resolutions
from engine.model.motion_init import LayerMotion, chain_motion
from engine.model.paper_model import PaperModel

SIZE, T = (64, 48), 5


def _motion(shift: float = 0.0, half: float = 40.0, aspect=(1.0, 0.75)) -> LayerMotion:
    to_ref = np.stack([np.array([[1.0, 0.0, shift * t], [0.0, 1.0, 0.0]]) for t in range(T)])
    return LayerMotion(to_ref=to_ref, center=np.array([32.0, 24.0]), half_extent=half, aspect=aspect)


def _xyt(n=50, seed=0):
    g = torch.Generator().manual_seed(seed)
    xy = torch.rand(n, 2, generator=g) * torch.tensor(SIZE, dtype=torch.float32)
    return xy, torch.randint(0, T, (n,), generator=g)


def test_fast_mapping_starts_at_the_initial_motion():
    model = FastModel(preset_config("draft"), SIZE, T, [_motion(2.0), _motion(-1.0, 20.0)])
    xy, t = _xyt()
    uv = model.uv(0, xy, t)
    expected = (xy + torch.stack((2.0 * t, 0 * t), -1) - torch.tensor([32.0, 24.0])) / 40.0
    assert torch.allclose(uv, expected, atol=1e-5)
    assert model.uv_per_px(1) == pytest.approx(1 / 20.0)


def test_anchor_term_sees_a_whole_mapping_slide_and_only_that():
    """The gauge term of the objective: a uniform slide of a foreground mapping costs its squared length in
    pixels; the starting mapping costs nothing. (Blackswan's mapping slid 147 px without it.)"""
    from engine.data.flow import FlowField
    from engine.data.video import build_video_tensors
    from engine.model.objective import compute_losses

    model = FastModel(preset_config("draft"), SIZE, T, [_motion(), _motion(-1.0, 20.0)])
    w, h = SIZE
    frames = np.random.default_rng(0).random((T, h, w, 3), dtype=np.float32)
    masks = np.zeros((1, T, h, w), bool)
    masks[0, :, 10:30, 20:40] = True
    zeros = np.zeros((T - 1, h, w, 2), np.float32)
    ok = np.ones((T - 1, h, w), bool)
    video = build_video_tensors(frames, masks, FlowField(zeros, zeros, ok, ok, "none", 1.0), 2.0, torch.device("cpu"))
    ix, iy, t = torch.randint(0, w, (500,)), torch.randint(0, h, (500,)), torch.randint(0, T, (500,))
    cfg = preset_config("draft")
    _, terms = compute_losses(model, video, cfg, 0, ix, iy, t)
    assert float(terms["anchor"].detach()) < 1e-10
    with torch.no_grad():
        model.mappings[1].delta[:, 0, 2] += 3.0 / 20.0  # 3 px at 20 px per atlas unit
    _, terms = compute_losses(model, video, cfg, 0, ix, iy, t)
    assert float(terms["anchor"].detach()) == pytest.approx(9.0, rel=1e-4)


def test_fast_alpha_weights_sum_to_one_and_stay_in_open_interval():
    model = FastModel(preset_config("draft"), SIZE, T, [_motion(), _motion()])
    w = model.alpha(*_xyt())
    assert torch.allclose(w.sum(-1), torch.ones(len(w)))
    assert (w > 0).all() and (w < 1).all()


def test_fast_atlas_is_empty_outside_its_rectangle():
    model = FastModel(preset_config("draft"), SIZE, T, [_motion(aspect=(1.0, 0.5))])
    c = model.color(0, torch.tensor([[0.0, 0.0], [0.0, 0.6], [1.2, 0.0], [0.99, 0.49]]))
    assert (c[1] == 0).all() and (c[2] == 0).all()
    assert (c[0] > 0).all() and (c[3] > 0).all()


def test_paper_model_shapes_and_quadrants():
    cfg = preset_config("paper")
    m = PaperModel(cfg, SIZE, T)
    assert [lin.out_features for lin in m.map_fg.linears] == [256] * 5 + [2]
    assert [lin.out_features for lin in m.map_bg.linears] == [256] * 3 + [2]
    assert len(m.atlas.linears) == 8 and m.atlas.skips == (4, 7)
    assert m.atlas.linears[0].in_features == 2 * 2 * 10 and m.atlas.linears[4].in_features == 256 + 40
    assert len(m.alpha_mlp.linears) == 8 and m.alpha_mlp.linears[0].in_features == 2 * 3 * 5
    assert m.uv_per_px(0) == pytest.approx(0.8 / 32.0)  # the reference's atlas scale over half the long side


def test_paper_calibration_reaches_scaled_identity():
    cfg = preset_config("paper")
    cfg.pretrain_iters = 150
    cfg.batch = 1000
    cfg.lr = 1e-3  # faster calibration for the test; the preset keeps the reference's 1e-4
    m = PaperModel(cfg, SIZE, T)
    m.prepare(cfg, torch.device("cpu"))
    xy, t = _xyt(200, seed=3)
    target = 0.8 * m.normalized_xyt(xy, t)[:, :2]
    for layer in (0, 1):
        err_px = (m.uv(layer, xy, t) - target).norm(dim=-1) / m.uv_per_px(layer)
        assert err_px.median() < 1.5


def test_chain_motion_composes_translations():
    s = np.array([[1.0, 0.0, 2.0], [0.0, 1.0, -1.0]])  # frame t -> t+1 moves content by (2, -1)
    to_ref = chain_motion([s, s, s])
    assert np.allclose(to_ref[3][:, 2], [-6.0, 3.0]) and np.allclose(to_ref[3][:, :2], np.eye(2))


def test_motion_regions_keep_a_core_for_small_objects():
    masks = np.zeros((1, 2, 40, 40), dtype=bool)
    masks[0, 0, 10:16, 10:16] = True  # a 6 px object: a 6 px erosion would delete it
    bg, fgs = motion_regions(masks, margin_px=6)
    assert fgs[0][0].sum() > 0 and fgs[0][1].sum() == 0
    assert not bg[0, 8:18, 8:18].any() and bg[1].all()


def test_level_ladder_and_grids():
    assert level_resolutions(1024, 6) == [16, 37, 84, 194, 446, 1024]
    assert level_resolutions(8, 4) == [8]
    g2 = Grid2D([(4, 3), (8, 6)], 2)
    assert g2(torch.zeros(5, 2)).shape == (5, 4)
    g3 = Grid3D([(4, 3, 2)], 3)
    assert g3(torch.zeros(7, 3)).shape == (7, 3)
    pe = PositionalEncoding(3)
    assert pe(torch.zeros(2, 2)).shape == (2, pe.out_dim(2))
