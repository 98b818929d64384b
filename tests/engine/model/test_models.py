"""Model contracts: the fast model starts at its flow-estimated motion, weights sum to one, the atlas is
empty outside its rectangle; the paper model has the paper's shapes and calibrates to scaled identity."""

from __future__ import annotations

import dataclasses

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


def _square_video(flow_px: float):
    """Random frames with a 20x20 square mask in every frame and a uniform flow of ``flow_px`` (forward-backward
    consistent everywhere): the tiny clip the objective tests evaluate the terms on."""
    from engine.data.flow import FlowField
    from engine.data.video import build_video_tensors

    w, h = SIZE
    frames = np.random.default_rng(0).random((T, h, w, 3), dtype=np.float32)
    masks = np.zeros((1, T, h, w), bool)
    masks[0, :, 10:30, 20:40] = True
    fwd = np.full((T - 1, h, w, 2), flow_px, np.float32)
    ok = np.ones((T - 1, h, w), bool)
    return build_video_tensors(frames, masks, FlowField(fwd, -fwd, ok, ok, "none", 1.0), 2.0, torch.device("cpu"))


def test_fast_mapping_starts_at_the_initial_motion():
    model = FastModel(preset_config("draft"), SIZE, T, [_motion(2.0), _motion(-1.0, 20.0)])
    xy, t = _xyt()
    uv = model.uv(0, xy, t)
    expected = (xy + torch.stack((2.0 * t, 0 * t), -1) - torch.tensor([32.0, 24.0])) / 40.0
    assert torch.allclose(uv, expected, atol=1e-5)
    assert model.uv_per_px(1) == pytest.approx(1 / 20.0)


def test_the_foreground_mapping_width_leaves_the_background_as_it_was():
    """``mapping_hidden_fg`` widens each foreground layer's residual MLP only; 0 keeps ``mapping_hidden`` for every
    layer, and a wider foreground still starts at its flow-fitted motion (the last layer starts at zero)."""
    plain = FastModel(preset_config("draft"), SIZE, T, [_motion(2.0), _motion(-1.0, 20.0), _motion(1.0, 10.0)])
    wide = FastModel(
        dataclasses.replace(preset_config("draft"), mapping_hidden_fg=96),
        SIZE,
        T,
        [_motion(2.0), _motion(-1.0, 20.0), _motion(1.0, 10.0)],
    )

    def widths(model: FastModel) -> list[int]:
        return [m.residual.linears[0].out_features for m in model.mappings]

    assert widths(plain) == [64, 64, 64] and widths(wide) == [64, 96, 96]
    xy, t = torch.rand(50, 2) * torch.tensor(SIZE, dtype=torch.float32), torch.randint(0, T, (50,))
    for layer in range(3):
        assert torch.allclose(wide.uv(layer, xy, t), plain.uv(layer, xy, t))


def test_anchor_term_sees_a_whole_mapping_slide_and_only_that():
    """The gauge term of the objective: a uniform slide of a foreground mapping costs its squared length in
    pixels; the starting mapping costs nothing. (Blackswan's mapping slid 147 px without it.)"""
    from engine.model.objective import compute_losses

    model = FastModel(preset_config("draft"), SIZE, T, [_motion(), _motion(-1.0, 20.0)])
    w, h = SIZE
    video = _square_video(0.0)
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


@pytest.mark.slow
def test_paper_calibration_reaches_scaled_identity():
    cfg = preset_config("paper")
    cfg.pretrain_iters = 150
    cfg.batch = 1000
    cfg.lr = 1e-3  # faster calibration for the test; the preset keeps the reference's 1e-4
    torch.manual_seed(cfg.seed)  # the initial weights as a fit draws them, not what earlier tests left
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


def test_atlas_opacity_starts_at_the_same_alpha_and_moves_with_the_mapping():
    """``alpha_atlas_density``: a logit texture in the foreground's atlas. At the start it adds nothing (the fit
    starts as without it); a mark painted in it appears in every frame where the mapping carries that atlas point,
    2 px further right per frame for an object moving 2 px per frame."""

    plain_cfg = preset_config("draft")
    cfg = dataclasses.replace(plain_cfg, alpha_atlas_density=1.0)
    torch.manual_seed(0)
    plain = FastModel(plain_cfg, SIZE, T, [_motion(), _motion(-2.0, 20.0)])
    torch.manual_seed(0)
    model = FastModel(cfg, SIZE, T, [_motion(), _motion(-2.0, 20.0)])
    xy, t = _xyt(200)
    assert torch.equal(model.alpha(xy, t), plain.alpha(xy, t))
    assert len(model.alpha_atlas) == 1
    group = next(g for g in model.param_groups(cfg) if g["name"] == "grids")
    assert all(any(p is q for q in group["params"]) for p in model.alpha_atlas.parameters())

    # a square of +8 logits around the atlas centre, on the finest level (one cell per reference pixel)
    finest = model.alpha_atlas[0].grid.grids[-1]
    _, _, gh, gw = finest.shape
    with torch.no_grad():
        finest[:, :, gh // 2 - 2 : gh // 2 + 3, gw // 2 - 2 : gw // 2 + 3] = 8.0
    for frame in range(T):
        ys, xs = torch.meshgrid(torch.arange(48) + 0.5, torch.arange(64) + 0.5, indexing="ij")
        pix = torch.stack((xs.flatten(), ys.flatten()), -1)
        a = model.alpha(pix, torch.full((pix.shape[0],), frame)).detach()[:, 1].view(48, 64)
        base = plain.alpha(pix, torch.full((pix.shape[0],), frame)).detach()[:, 1].view(48, 64)
        lifted = (a - base) > 0.3
        cx = float(xs[lifted].mean())
        # frame pixel x maps to reference x - 2 t: the atlas centre (reference 32) is at frame x = 32 + 2 t
        assert cx == pytest.approx(32.0 + 2.0 * frame, abs=0.6)
        assert float(ys[lifted].mean()) == pytest.approx(24.0, abs=0.6)


@pytest.mark.slow
def test_atlas_opacity_learns_a_thin_bar_from_every_frame():
    """A 2 px bar moving 3 px per frame over 12 frames of 512x96 (draft's alpha grid: 4 px cells), alpha trained
    on the bar's masks alone (BCE, 300 Adam steps, uniform batches: about two samples per step on the bar). In
    atlas space every frame's samples of the bar train the same cells; the (x, y, t) grid alone sees the bar's
    few samples per frame separately, through cells twice its width."""
    import dataclasses

    w, h, frames, speed = 512, 96, 12, 3.0
    to_ref = np.stack([np.array([[1.0, 0.0, -speed * t], [0.0, 1.0, 0.0]]) for t in range(frames)])
    bg = LayerMotion(to_ref=np.stack([np.eye(2, 3)] * frames), center=np.array([256.0, 48.0]), half_extent=256.0)
    fg = LayerMotion(to_ref=to_ref, center=np.array([200.0, 48.0]), half_extent=24.0)
    masks = np.zeros((frames, h, w), bool)
    for t in range(frames):
        x0 = round(200 + speed * t)
        masks[t, 24:72, x0 : x0 + 2] = True
    target = torch.from_numpy(masks).float()

    def fit(density: float) -> float:
        cfg = dataclasses.replace(preset_config("draft"), alpha_atlas_density=density)
        torch.manual_seed(0)
        model = FastModel(cfg, (w, h), frames, [bg, fg])
        params = list(model.alpha_grid.parameters()) + list(model.alpha_decoder.parameters())
        params += [] if model.alpha_atlas is None else list(model.alpha_atlas.parameters())
        opt = torch.optim.Adam(params, lr=cfg.lr_grid)
        gen = torch.Generator().manual_seed(1)
        for _ in range(300):
            t = torch.randint(0, frames, (2048,), generator=gen)
            ix, iy = torch.randint(0, w, (2048,), generator=gen), torch.randint(0, h, (2048,), generator=gen)
            a = model.alpha(torch.stack((ix, iy), -1).float() + 0.5, t)[:, 1]
            m = target[t, iy, ix]
            loss = torch.nn.functional.binary_cross_entropy(a, m)
            opt.zero_grad()
            loss.backward()
            opt.step()
        with torch.no_grad():
            ys, xs = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
            pix = torch.stack((xs.flatten(), ys.flatten()), -1).float() + 0.5
            inter = union = 0.0
            for t in range(frames):
                a = model.alpha(pix, torch.full((pix.shape[0],), t))[:, 1].view(h, w) > 0.5
                inter += float((a & torch.from_numpy(masks[t])).sum())
                union += float((a | torch.from_numpy(masks[t])).sum())
        return inter / union

    with_atlas, without = fit(1.0), fit(0.0)
    # measured: 0.876 against 0.603
    assert with_atlas > 0.8
    assert with_atlas > without + 0.2


def test_objective_gives_the_atlas_opacity_the_mappings_uvs():
    """The objective passes the uvs it has already computed to an alpha that reads them: every term is what the
    alpha gives when it maps the points itself."""
    import dataclasses

    from engine.model.objective import compute_losses

    cfg = dataclasses.replace(preset_config("draft"), alpha_atlas_density=1.0)
    torch.manual_seed(0)
    model = FastModel(cfg, SIZE, T, [_motion(), _motion(-1.0, 20.0)])
    with torch.no_grad():
        for g in model.alpha_atlas[0].grid.grids:
            g.normal_(0.0, 2.0)
    w, h = SIZE
    video = _square_video(1.0)
    ix, iy, t = torch.randint(0, w, (500,)), torch.randint(0, h, (500,)), torch.randint(0, T, (500,))
    total, terms = compute_losses(model, video, cfg, 0, ix, iy, t)
    model.alpha_reads_uv = False
    total_self, terms_self = compute_losses(model, video, cfg, 0, ix, iy, t)
    assert {"alpha_flow", "mask", "sparsity"} <= set(terms)
    for k, v in terms.items():
        assert float(v.detach()) == pytest.approx(float(terms_self[k].detach()), rel=1e-5, abs=1e-7), k
    assert float(total.detach()) == pytest.approx(float(total_self.detach()), rel=1e-5)


def test_a_clip_no_longer_than_mapping_time_frames_maps_as_before_and_a_longer_one_keeps_a_frames_step_in_t():
    """``mapping_time_frames``: a clip that long or shorter gives its residual MLP the same time input, bit for bit,
    as without it; a longer clip's frames are 2 / mapping_time_frames apart in t (centred on the clip), not
    2 / frames, so a long shot asks the MLP for no faster change per unit of t than a short clip does."""
    from engine.model.atlas_model import FastLayerMapping

    plain, timed = preset_config("draft"), dataclasses.replace(preset_config("draft"), mapping_time_frames=70)
    for frames in (1, 5, 70):
        a, b = FastLayerMapping(_motion(), SIZE, frames, plain), FastLayerMapping(_motion(), SIZE, frames, timed)
        t = torch.arange(frames, dtype=torch.float32)
        assert torch.equal(t / max(frames / 2.0, 0.5) - 1.0, t / b.t_scale - b.t_offset)
        assert (a.t_scale, a.t_offset) == (b.t_scale, b.t_offset)
    long = FastLayerMapping(_motion(), SIZE, 300, timed)
    tn = torch.arange(300, dtype=torch.float32) / long.t_scale - long.t_offset
    assert torch.allclose(tn[1:] - tn[:-1], torch.full((299,), 2.0 / 70), atol=1e-6)
    assert tn[0].item() == pytest.approx(-300 / 70) and tn[150].item() == pytest.approx(0.0, abs=1e-6)
