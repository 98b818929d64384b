"""Loss terms: values on hand-made inputs, finite gradients at degenerate inputs, float64 gradcheck."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from engine.model import losses as L


def test_rgb_loss_value():
    pred = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    target = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]])
    assert L.rgb_loss(pred, target).item() == pytest.approx(1.0)


def test_gradient_loss_ignores_invalid_border_samples():
    pdx = torch.zeros(2, 3)
    gdx = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    valid = torch.tensor([True, False])
    assert L.gradient_loss(pdx, pdx, gdx, gdx, valid, valid).item() == 0.0
    assert L.gradient_loss(pdx, pdx, gdx, gdx).item() == pytest.approx(1.0)


def _uv_from_matrix(m: torch.Tensor, n: int = 4, delta: float = 1.0):
    xy = torch.rand(n, 2, dtype=m.dtype) * 10
    uv = xy @ m.T
    return (
        uv,
        (xy + torch.tensor([delta, 0.0], dtype=m.dtype)) @ m.T,
        (xy + torch.tensor([0.0, delta], dtype=m.dtype)) @ m.T,
    )


def test_rigidity_identity_and_rotation_are_minimal():
    # ||J^T J||_F + ||(J^T J + eps)^-1||_F for a rotation: sqrt(2) + sqrt(2)/(1+eps)
    expected = math.sqrt(2) + math.sqrt(2) / (1 + L.RIGIDITY_EPS)
    for angle in (0.0, 0.7, 2.5):
        c, s = math.cos(angle), math.sin(angle)
        m = torch.tensor([[c, -s], [s, c]], dtype=torch.float64)
        uv, ux, uy = _uv_from_matrix(m)
        assert L.rigidity_loss(uv, ux, uy, 1.0, 1.0).item() == pytest.approx(expected, rel=1e-6)


def test_rigidity_penalises_scale_and_shear():
    base = L.rigidity_loss(*_uv_from_matrix(torch.eye(2, dtype=torch.float64)), 1.0, 1.0).item()
    for m in ([[2.0, 0.0], [0.0, 2.0]], [[0.5, 0.0], [0.0, 0.5]], [[1.0, 0.8], [0.0, 1.0]]):
        uv, ux, uy = _uv_from_matrix(torch.tensor(m, dtype=torch.float64))
        assert L.rigidity_loss(uv, ux, uy, 1.0, 1.0).item() > base + 0.1


def test_rigidity_uses_uv_per_px_units():
    s = 0.01  # atlas units per pixel: a mapping uv = s * xy is rigid in pixel units
    uv, ux, uy = _uv_from_matrix(torch.eye(2, dtype=torch.float64) * s)
    ident = L.rigidity_loss(*_uv_from_matrix(torch.eye(2, dtype=torch.float64)), 1.0, 1.0).item()
    assert L.rigidity_loss(uv, ux, uy, 1.0, s).item() == pytest.approx(ident, rel=1e-6)


def test_rigidity_collapsed_mapping_is_bounded_and_differentiable():
    """A mapping that collapses to a point (J = 0): the inverse is bounded by the named epsilon."""
    uv = torch.zeros(5, 2, requires_grad=True)
    loss = L.rigidity_loss(uv, uv.detach().clone().requires_grad_(), uv.detach().clone(), 1.0, 1.0)
    assert math.isfinite(loss.item())
    assert loss.item() == pytest.approx(math.sqrt(2) / L.RIGIDITY_EPS, rel=1e-3)
    loss.backward()
    assert torch.isfinite(uv.grad).all()


def test_rigidity_gradcheck_near_singular():
    torch.manual_seed(0)
    uv = torch.randn(3, 2, dtype=torch.float64, requires_grad=True)
    ux = (uv.detach() + torch.tensor([1e-4, 0.0], dtype=torch.float64)).requires_grad_()
    uy = (uv.detach() + torch.tensor([1e-4, 1e-8], dtype=torch.float64)).requires_grad_()
    assert torch.autograd.gradcheck(lambda a, b, c: L.rigidity_loss(a, b, c, 1.0, 1.0), (uv, ux, uy))


def test_flow_loss_in_pixels_and_weighted():
    uv = torch.zeros(2, 2)
    uv_match = torch.tensor([[0.03, 0.04], [1.0, 1.0]])
    w = torch.tensor([1.0, 0.5])
    valid = torch.tensor([True, False])
    # 0.05 atlas units at 0.01 units/px = 5 px; the second sample is not valid
    assert L.flow_loss(uv, uv_match, w, valid, 0.01).item() == pytest.approx(5.0, rel=1e-4)


def test_flow_loss_no_valid_samples_is_zero_not_nan():
    uv = torch.zeros(3, 2, requires_grad=True)
    out = L.flow_loss(uv, uv + 1, torch.ones(3), torch.zeros(3, dtype=torch.bool), 1.0)
    assert out.item() == 0.0
    out.backward()
    assert torch.isfinite(uv.grad).all()


def test_flow_loss_zero_distance_has_finite_gradient():
    uv = torch.zeros(3, 2, dtype=torch.float64, requires_grad=True)
    m = torch.zeros(3, 2, dtype=torch.float64, requires_grad=True)
    w = torch.ones(3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b, c: L.flow_loss(a, b, c, None, 1.0), (uv, m, w))


def test_alpha_flow_loss_value():
    a = torch.tensor([[0.2], [0.9]])
    b = torch.tensor([[0.5], [0.9]])
    assert L.alpha_flow_loss(a, b, None).item() == pytest.approx(0.15)


def test_sparsity_value_and_zero_when_opaque():
    rgb = torch.tensor([[1.0, 0.0, 0.0]])
    assert L.sparsity_loss(torch.tensor([[0.5]]), rgb).item() == pytest.approx(0.25)
    assert L.sparsity_loss(torch.tensor([[1.0]]), rgb).item() == 0.0


def test_sparsity_gradcheck():
    a = torch.rand(4, 1, dtype=torch.float64, requires_grad=True)
    c = torch.rand(4, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(L.sparsity_loss, (a, c))


@pytest.mark.parametrize("alpha", [0.0, 1.0])
def test_mask_bce_saturated_alpha_is_finite(alpha):
    """Alpha at exactly 0 or 1 against the opposite label: bounded by -log(LOG_EPS), finite gradient."""
    a = torch.full((4, 1), alpha, requires_grad=True)
    m = torch.full((4, 1), 1.0 - alpha)
    out = L.mask_bce(a, m)
    assert out.item() == pytest.approx(-math.log(L.LOG_EPS), rel=1e-3)
    out.backward()
    assert torch.isfinite(a.grad).all()


def test_mask_bce_value_and_ignore():
    a = torch.tensor([[0.5], [0.9]])
    m = torch.tensor([[1.0], [0.0]])
    valid = torch.tensor([[True], [False]])
    assert L.mask_bce(a, m, valid).item() == pytest.approx(math.log(2.0), rel=1e-5)


def test_mask_bce_gradcheck_interior():
    a = (torch.rand(5, 1, dtype=torch.float64) * 0.8 + 0.1).requires_grad_()
    m = (torch.rand(5, 1) > 0.5).double()
    assert torch.autograd.gradcheck(lambda x: L.mask_bce(x, m), (a,))


def test_psnr_guard_perfect_match_is_finite():
    assert L.psnr_from_mse(0.0) == pytest.approx(100.0)
    assert L.psnr_from_mse(0.01) == pytest.approx(20.0)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(-1e3, 1e3, allow_nan=False, width=32), min_size=12, max_size=12),
    st.floats(1e-4, 10.0),
)
def test_rigidity_finite_for_any_jacobian(vals, uv_per_px):
    """Property: any finite mapping differences (including collapse and huge stretch) give finite loss/grad."""
    t = torch.tensor(vals, dtype=torch.float32).view(2, 3, 2)
    uv = t[0, 0:2].clone().requires_grad_()
    ux = t[1, 0:2].clone().requires_grad_()
    uy = (t[0, 2:3].repeat(2, 1)).clone().requires_grad_()
    loss = L.rigidity_loss(uv, ux, uy, 1.0, uv_per_px)
    assert torch.isfinite(loss)
    loss.backward()
    for g in (uv.grad, ux.grad, uy.grad):
        assert torch.isfinite(g).all()


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6), st.lists(st.booleans(), min_size=6, max_size=6))
def test_bce_and_sparsity_finite_on_closed_unit_interval(alphas, labels):
    a = torch.tensor(alphas).view(6, 1).requires_grad_()
    m = torch.tensor(labels, dtype=torch.float32).view(6, 1)
    out = L.mask_bce(a, m) + L.sparsity_loss(a, torch.ones(6, 3))
    assert torch.isfinite(out)
    out.backward()
    assert torch.isfinite(a.grad).all()


def test_anchor_loss_penalises_only_the_mean_drift():
    g = torch.Generator().manual_seed(0)
    uv0 = torch.rand(200, 2, generator=g) * 2 - 1
    wiggle = torch.randn(200, 2, generator=g) * 0.05
    wiggle = wiggle - wiggle.mean(0)  # a deformation with zero mean displacement
    w = torch.ones(200)
    assert float(L.anchor_loss(uv0 + wiggle, uv0, w, 0.01)) < 1e-8
    # a uniform slide of 0.03 atlas units at 100 px per unit is 3 px: 9 px^2
    shifted = uv0 + torch.tensor([0.03, 0.0])
    assert math.isclose(float(L.anchor_loss(shifted, uv0, w, 0.01)), 9.0, rel_tol=1e-4)
    # only weighted (mask) pixels count: unweighted ones may move freely
    half = torch.cat((torch.ones(100), torch.zeros(100)))
    moved = torch.cat((uv0[:100], uv0[100:] + 5.0))
    assert float(L.anchor_loss(moved, uv0, half, 0.01)) < 1e-8


def test_anchor_loss_without_weighted_pixels_is_zero_with_finite_gradient():
    uv = torch.rand(10, 2, requires_grad=True)
    loss = L.anchor_loss(uv, torch.zeros(10, 2), torch.zeros(10), 0.01)
    loss.backward()
    assert float(loss.detach()) == 0.0 and torch.isfinite(uv.grad).all()


def test_atlas_sparsity_is_mean_l1_and_zero_when_empty():
    rgb = torch.tensor([[0.0, 0.0, 0.0], [0.5, 0.25, 0.25]])
    assert L.atlas_sparsity_loss(rgb).item() == pytest.approx(0.5)
    empty = L.atlas_sparsity_loss(torch.zeros(0, 3, requires_grad=True))
    assert empty.item() == 0.0 and math.isfinite(empty.item())


def test_scribble_loss_value_and_unlabelled_pixels_ignored():
    alpha = torch.tensor([[0.5, 0.25], [0.9, 0.1], [0.2, 0.8]])
    labels = torch.tensor([0, -1, 1])
    assert L.scribble_loss(alpha, labels).item() == pytest.approx(-(math.log(0.5) + math.log(0.8)) / 2)


def test_scribble_loss_no_scribbled_sample_is_zero_not_nan():
    alpha = torch.full((4, 2), 0.5, requires_grad=True)
    loss = L.scribble_loss(alpha, torch.full((4,), -1))
    loss.backward()
    assert loss.item() == 0.0 and torch.isfinite(alpha.grad).all()


def test_scribble_loss_zero_alpha_is_clamped_by_log_eps():
    alpha = torch.tensor([[0.0, 1.0]], requires_grad=True)
    loss = L.scribble_loss(alpha, torch.tensor([0]))
    loss.backward()
    assert loss.item() == pytest.approx(-math.log(L.LOG_EPS)) and torch.isfinite(alpha.grad).all()


def test_scribble_loss_gradcheck_interior():
    alpha = torch.tensor([[0.3, 0.6], [0.7, 0.2]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a: L.scribble_loss(a, torch.tensor([1, 0])), (alpha,))
