"""Loss terms at degenerate and adversarial inputs: float64 gradcheck where the guards bite, hypothesis
properties over random and adversarial values, and the whole objective on a built model with a collapsed
mapping, flow far outside the frame and alpha saturated at exactly 0 and 1.

Extends tests/engine/model/test_losses.py (which covers values, the collapsed J = 0 forward pass, a near-singular
gradcheck, zero flow distance, saturated BCE and two finiteness properties) without repeating it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from engine.config import apply_overrides, preset_config
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.data.video import build_video_tensors
from engine.fit.fit_inputs import FitInputs
from engine.fit.model_build import build_model
from engine.fit.prepare import prepare_clip
from engine.model import losses as L
from engine.model.objective import TARGET_RANGE, compute_losses
from tests.stability.fitcheck import QUICK

F64 = torch.float64
#: The minimum of the symmetric Dirichlet energy with the RIGIDITY_EPS guard, reached at rotations with
#: J^T J = (1 - eps) I: sqrt(2) * ((1 - eps) + 1) (Eq. 9 in the reference's form).
RIGIDITY_MIN = math.sqrt(2.0) * (2.0 - L.RIGIDITY_EPS)
#: Bound of the rigidity energy of a fully collapsed mapping (J = 0): the inverse is eps^-1 I.
RIGIDITY_COLLAPSED = math.sqrt(2.0) / L.RIGIDITY_EPS


def _rig(uv, ux, uy):
    return L.rigidity_loss(uv, ux, uy, 1.0, 1.0)


def _jac_inputs(j: list[list[float]], n: int = 3, seed: int = 0):
    """uv at n random points and at +1 px in x and y for the affine map with Jacobian ``j`` (float64)."""
    g = torch.Generator().manual_seed(seed)
    m = torch.tensor(j, dtype=F64)
    xy = torch.rand(n, 2, generator=g, dtype=F64) * 10
    uv = xy @ m.T
    ux = (xy + torch.tensor([1.0, 0.0], dtype=F64)) @ m.T
    uy = (xy + torch.tensor([0.0, 1.0], dtype=F64)) @ m.T
    return tuple(t.clone().requires_grad_() for t in (uv, ux, uy))


# --- float64 gradcheck at the degenerate inputs each guard exists for ----------------------------------------


@pytest.mark.parametrize(
    "jac",
    [
        pytest.param([[0.0, 0.0], [0.0, 0.0]], id="collapsed_to_a_point"),
        pytest.param([[1.0, 0.0], [0.0, 0.0]], id="collapsed_to_a_line"),
        pytest.param([[1.0, 1.0], [1.0, 1.0]], id="rank_one_shear"),
        pytest.param([[1e3, 0.0], [0.0, 1e-3]], id="huge_anisotropy"),
        pytest.param([[0.0, -1.0], [1.0, 0.0]], id="rotation_at_the_minimum"),
    ],
)
def test_rigidity_gradcheck_at_degenerate_jacobians(jac):
    inputs = _jac_inputs(jac)
    assert torch.autograd.gradcheck(_rig, inputs)
    value = _rig(*inputs).item()
    assert RIGIDITY_MIN - 1e-9 <= value <= RIGIDITY_COLLAPSED + 2.0 * max(abs(v) for r in jac for v in r) ** 2 + 1.0


def test_rigidity_collapsed_mapping_value_is_the_named_bound():
    """J = 0 exactly: ||J^T J|| is 0 and ||(eps I)^-1|| = sqrt(2) / eps: the inverse stays bounded."""
    uv, ux, uy = _jac_inputs([[0.0, 0.0], [0.0, 0.0]])
    assert _rig(uv, ux, uy).item() == pytest.approx(RIGIDITY_COLLAPSED, rel=1e-9)


@pytest.mark.parametrize(
    "case",
    ["coincident", "no_valid_samples", "zero_weight", "huge_distance", "tiny_uv_per_px"],
)
def test_flow_loss_gradcheck_at_degenerate_inputs(case):
    g = torch.Generator().manual_seed(1)
    uv = torch.rand(4, 2, generator=g, dtype=F64)
    match = uv + torch.rand(4, 2, generator=g, dtype=F64)
    w = torch.rand(4, generator=g, dtype=F64)
    valid = torch.ones(4, dtype=torch.bool)
    upp = 0.01
    if case == "coincident":
        match = uv.clone()
    elif case == "no_valid_samples":
        valid = torch.zeros(4, dtype=torch.bool)
    elif case == "zero_weight":
        w = torch.zeros(4, dtype=F64)
    elif case == "huge_distance":
        match = uv + 1e3  # 1e5 px at 0.01 atlas units per px
    elif case == "tiny_uv_per_px":
        upp = 1e-9
    args = tuple(t.clone().requires_grad_() for t in (uv, match, w))
    assert torch.autograd.gradcheck(lambda a, b, c: L.flow_loss(a, b, c, valid, upp), args)
    assert math.isfinite(L.flow_loss(*args, valid, upp).item())


@pytest.mark.parametrize("alpha", [0.0, 1.0], ids=["alpha_exactly_0", "alpha_exactly_1"])
def test_sparsity_gradcheck_at_saturated_alpha_and_black(alpha):
    a = torch.full((4, 1), alpha, dtype=F64, requires_grad=True)
    c = torch.rand(4, 3, dtype=F64)
    c[0] = 0.0  # a black atlas sample
    assert torch.autograd.gradcheck(L.sparsity_loss, (a, c.requires_grad_()))


@pytest.mark.parametrize(
    "alpha",
    [1e-4, 1.0 - 1e-4, -0.5, 1.5],
    ids=["nearly_0", "nearly_1", "below_0_clamped", "above_1_clamped"],
)
def test_mask_bce_gradcheck_near_and_beyond_saturation(alpha):
    """Near 0/1 the log is steep but smooth; beyond [LOG_EPS, 1 - LOG_EPS] the clamp holds it flat."""
    a = torch.full((4, 1), alpha, dtype=F64, requires_grad=True)
    m = torch.tensor([[0.0], [1.0], [0.0], [1.0]], dtype=F64)
    assert torch.autograd.gradcheck(lambda x: L.mask_bce(x, m), (a,), eps=1e-7, atol=1e-4)
    assert L.mask_bce(a, m).item() <= -math.log(L.LOG_EPS) + 1e-6


@pytest.mark.parametrize("alpha", [0.0, 1.0], ids=["alpha_exactly_0", "alpha_exactly_1"])
def test_mask_bce_saturated_alpha_agreeing_with_the_label_is_almost_free(alpha):
    """The clamp costs at most -log(1 - LOG_EPS) ~ 1e-6 when alpha is exactly right; gradients stay finite."""
    a = torch.full((4, 1), alpha, requires_grad=True)
    out = L.mask_bce(a, torch.full((4, 1), alpha))
    assert 0.0 <= out.item() <= 2e-6
    out.backward()
    assert torch.isfinite(a.grad).all()


def test_masked_mean_of_nothing_gradcheck():
    v = torch.rand(5, dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: L.masked_mean(x, torch.zeros(5, dtype=torch.bool)), (v,))
    assert L.masked_mean(v[:0]).item() == 0.0


# --- properties over random and adversarial inputs -------------------------------------------------------------

_finite = st.floats(-1e4, 1e4, allow_nan=False, allow_infinity=False, width=32)
_adversarial = st.one_of(_finite, st.sampled_from([0.0, -0.0, 1e-30, -1e-30, 1e4, -1e4, 1.0, -1.0]))


@settings(max_examples=80, deadline=None)
@given(st.lists(_adversarial, min_size=4, max_size=4), st.floats(0.0, 2 * math.pi))
def test_property_rigidity_is_rotation_invariant_and_above_its_minimum(j, angle):
    jac = torch.tensor(j, dtype=F64).view(1, 2, 2)
    c, s = math.cos(angle), math.sin(angle)
    rot = torch.tensor([[c, -s], [s, c]], dtype=F64)
    e = L.symmetric_dirichlet(jac)
    assert torch.isfinite(e).all()
    assert e.item() >= RIGIDITY_MIN * (1 - 1e-9)
    assert e.item() <= RIGIDITY_COLLAPSED + math.sqrt(2.0) * float((jac**2).sum()) + 1e-6
    assert L.symmetric_dirichlet(rot @ jac).item() == pytest.approx(e.item(), rel=1e-6, abs=1e-9)


@settings(max_examples=80, deadline=None)
@given(
    st.lists(_adversarial, min_size=8, max_size=8),
    st.lists(st.floats(0.0, 1.0), min_size=2, max_size=2),
    st.lists(st.booleans(), min_size=2, max_size=2),
    st.floats(1e-6, 1e3),
)
def test_property_flow_loss_finite_nonnegative_symmetric(vals, weights, valid, upp):
    t = torch.tensor(vals, dtype=torch.float32).view(2, 2, 2)
    uv = t[0].clone().requires_grad_()
    match = t[1].clone().requires_grad_()
    w = torch.tensor(weights)
    v = torch.tensor(valid)
    out = L.flow_loss(uv, match, w, v, upp)
    assert torch.isfinite(out) and out.item() >= 0.0
    assert L.flow_loss(match, uv, w, v, upp).item() == pytest.approx(out.item(), rel=1e-5, abs=1e-6)
    out.backward()
    assert torch.isfinite(uv.grad).all() and torch.isfinite(match.grad).all()


@settings(max_examples=80, deadline=None)
@given(
    st.lists(st.one_of(st.floats(allow_nan=False), st.sampled_from([0.0, 1.0, -0.0])), min_size=6, max_size=6),
    st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6),
)
def test_property_mask_bce_bounded_for_any_alpha(alphas, labels):
    """Any alpha, even outside [0, 1] or infinite, with any soft label: 0 <= BCE <= -log(LOG_EPS)."""
    a = torch.tensor(alphas, dtype=torch.float32).view(6, 1).requires_grad_()
    m = torch.tensor(labels, dtype=torch.float32).view(6, 1)
    out = L.mask_bce(a, m)
    assert torch.isfinite(out)
    assert -1e-6 <= out.item() <= -math.log(L.LOG_EPS) * (1 + 1e-5)
    out.backward()
    assert torch.isfinite(a.grad).all()


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-60.0, 60.0, allow_nan=False), min_size=24, max_size=24))
def test_property_reconstruction_terms_finite_on_hdr_values(vals):
    """Colour and gradient terms on HDR-range values (plates up to 50, negatives): finite, >= 0."""
    t = torch.tensor(vals, dtype=torch.float32).view(2, 4, 3)
    pred = t[0].clone().requires_grad_()
    out = L.rgb_loss(pred, t[1]) + L.gradient_loss(pred, pred, t[1], t[1], torch.tensor([True, False, True, True]))
    assert torch.isfinite(out) and out.item() >= 0.0
    out.backward()
    assert torch.isfinite(pred.grad).all()


@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, 1e30, allow_nan=False))
def test_property_psnr_is_finite_and_capped(mse):
    p = L.psnr_from_mse(mse)
    assert math.isfinite(p) and p <= 10.0 * math.log10(1.0 / L.MSE_EPS) + 1e-9


# --- the whole objective on a built model at degenerate states ------------------------------------------------


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """A tiny prepared clip (32x24, 3 frames, one mask layer) and its config."""
    tmp = tmp_path_factory.mktemp("objective")
    spec = SceneSpec(width=32, height=24, frames=3, fg_size=(12, 10), fg_start=(8.0, 6.0))
    frames, masks = write_scene(make_scene(spec), tmp / "clip")
    cfg = apply_overrides(preset_config("draft"), QUICK)
    prepared = prepare_clip(FitInputs(frames, [masks]), cfg, tmp / "run")
    return prepared, cfg


def _objective(prepared, cfg, flow=None, step=0, seed=0):
    torch.manual_seed(seed)
    model = build_model(cfg, prepared)
    video = build_video_tensors(
        prepared.frames, prepared.masks, flow or prepared.flow, cfg.mask_prior_margin_px, torch.device("cpu")
    )
    g = torch.Generator().manual_seed(seed)
    t, h, w = video.shape
    n = 600
    ix, iy, tt = (
        torch.randint(0, w, (n,), generator=g),
        torch.randint(0, h, (n,), generator=g),
        torch.randint(0, t, (n,), generator=g),
    )
    return model, video, (ix, iy, tt)


def _check_finite(model, total, terms):
    assert all(torch.isfinite(v) for v in terms.values()), {k: float(v) for k, v in terms.items()}
    total.backward()
    bad = [n for n, p in model.named_parameters() if p.grad is not None and not torch.isfinite(p.grad).all()]
    assert not bad, bad


def test_objective_collapsed_mapping_rigidity_stays_bounded(built):
    """Every layer's mapping collapsed to a point (J = 0 everywhere): the rigidity term is at most
    layers x sqrt(2)/RIGIDITY_EPS, and every gradient is finite."""
    prepared, cfg = built
    model, video, (ix, iy, tt) = _objective(prepared, cfg)
    with torch.no_grad():
        for m in model.mappings:
            m.to_ref.zero_()
    total, terms = compute_losses(model, video, cfg, 0, ix, iy, tt)
    assert terms["rigidity"].item() <= model.num_layers * RIGIDITY_COLLAPSED * (1 + 1e-4)
    assert terms["rigidity"].item() >= model.num_layers * RIGIDITY_COLLAPSED * 0.99
    _check_finite(model, total, terms)


@pytest.mark.parametrize("scale", [3.0, 1e4], ids=["flow_3x_frame_size", "flow_1e4_frame_sizes"])
@pytest.mark.parametrize("sign", [1.0, -1.0], ids=["right_down", "left_up"])
def test_objective_extreme_flow_pointing_out_of_frame(built, scale, sign):
    """|flow| far larger than the frame, forced 'consistent' (the consistency check would reject it): the
    flow terms sample the fields far outside the frame and stay finite, with finite gradients."""
    prepared, cfg = built
    f = prepared.flow
    h, w = prepared.frames.shape[1:3]
    vec = np.array([sign * scale * w, sign * scale * h], np.float32)
    huge = type(f)(
        forward=np.broadcast_to(vec, f.forward.shape).copy(),
        backward=np.broadcast_to(-vec, f.backward.shape).copy(),
        forward_ok=np.ones_like(f.forward_ok),
        backward_ok=np.ones_like(f.backward_ok),
        backend="huge",
        threshold_px=1.0,
    )
    model, video, batch = _objective(prepared, cfg, flow=huge)
    total, terms = compute_losses(model, video, cfg, 0, *batch)
    assert terms["flow"].item() > 0.0
    _check_finite(model, total, terms)


@pytest.mark.parametrize("step", [0, 30], ids=["mask_bootstrap", "mask_prior"])
def test_objective_alpha_saturated_at_exactly_0_and_1(built, step):
    """The model's alpha forced to exactly 0 or 1 (its ALPHA_FLOOR squeeze bypassed): the BCE terms stay
    within -log(LOG_EPS) and every gradient is finite."""
    prepared, cfg = built
    model, video, batch = _objective(prepared, cfg)
    real_alpha = model.alpha

    def hard_alpha(xy, t):
        w = real_alpha(xy, t)
        a = (w[:, 1:2] > 0.5).float() + 0.0 * w[:, 1:2]  # exactly 0/1, still attached to the graph
        return torch.cat((1.0 - a, a), -1)

    model.alpha = hard_alpha  # type: ignore[method-assign]
    total, terms = compute_losses(model, video, cfg, step, *batch)
    key = "mask" if step < cfg.bootstrap_steps else "mask_prior"
    assert 0.0 < terms[key].item() <= -math.log(L.LOG_EPS) * (1 + 1e-5)
    _check_finite(model, total, terms)


def test_objective_hdr_targets_are_clamped_to_the_reachable_range(built):
    """Plate values above display white (HDR highlights) or below black: the colour and gradient terms see
    the plate clamped to TARGET_RANGE, exactly as if the plate had been clipped."""
    prepared, cfg = built
    model, video, batch = _objective(prepared, cfg)
    hdr = video.frames.clone()
    hdr[:, :8] = 5.3
    hdr[:, -4:] = -0.2
    clipped = hdr.clamp(*TARGET_RANGE)
    out = {}
    for name, frames in (("hdr", hdr), ("clipped", clipped)):
        video.frames = frames
        with torch.no_grad():
            _, terms = compute_losses(model, video, cfg, 0, *batch)
        out[name] = terms
    for key in ("rgb", "gradient"):
        assert out["hdr"][key].item() == pytest.approx(out["clipped"][key].item(), rel=1e-6)
