"""The paper's loss terms (Sec. 3, App. A), each a small pure function on tensors.

Every inverse, log and division is guarded by a named epsilon; tests probe each guard at the degenerate
input it exists for (kornia style). Losses are computed in float32 whatever precision the fields use.
"""

from __future__ import annotations

import torch

#: Added to the diagonal of J^T J before inverting it (the reference's value): bounds the inverse's
#: Frobenius norm by about 1/RIGIDITY_EPS when a mapping collapses (J -> 0).
RIGIDITY_EPS = 1e-3
#: Alpha is clamped to [LOG_EPS, 1 - LOG_EPS] inside every log (BCE, scribbles).
LOG_EPS = 1e-6
#: A mean over zero selected samples is 0, not NaN: counts are clamped to at least this.
MIN_COUNT = 1.0
#: PSNR of a perfect reconstruction is capped (MSE clamped to this) instead of being +inf.
MSE_EPS = 1e-10


def _f32(x: torch.Tensor) -> torch.Tensor:
    """Half-precision field outputs are promoted to float32; float64 (gradcheck) is kept."""
    return x if x.dtype in (torch.float32, torch.float64) else x.float()


def masked_mean(values: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean of ``values`` over ``mask`` (all when None); 0 when nothing is selected."""
    if mask is None:
        return values.mean() if values.numel() else values.sum()
    m = mask.to(values.dtype)
    return (values * m).sum() / m.sum().clamp_min(MIN_COUNT)


def rgb_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared colour error ||c - c_gt||^2 (Eq. 4)."""
    return ((_f32(pred) - _f32(target)) ** 2).sum(-1).mean()


def gradient_loss(
    pred_dx: torch.Tensor,
    pred_dy: torch.Tensor,
    gt_dx: torch.Tensor,
    gt_dy: torch.Tensor,
    valid_dx: torch.Tensor | None = None,
    valid_dy: torch.Tensor | None = None,
) -> torch.Tensor:
    """Image-gradient reconstruction (Eq. 7) on forward differences; samples on the last column/row excluded."""
    ex = ((_f32(pred_dx) - _f32(gt_dx)) ** 2).sum(-1)
    ey = ((_f32(pred_dy) - _f32(gt_dy)) ** 2).sum(-1)
    return masked_mean(ex, valid_dx) + masked_mean(ey, valid_dy)


def jacobian_fd(
    uv: torch.Tensor, uv_dx: torch.Tensor, uv_dy: torch.Tensor, delta: float, uv_per_px: float
) -> torch.Tensor:
    """Finite-difference Jacobian d(uv)/d(xy) in atlas pixels per frame pixel: [N, 2, 2], columns x, y."""
    scale = 1.0 / (float(delta) * float(uv_per_px))
    jx = (_f32(uv_dx) - _f32(uv)) * scale
    jy = (_f32(uv_dy) - _f32(uv)) * scale
    return torch.stack((jx, jy), dim=-1)


def symmetric_dirichlet(jac: torch.Tensor) -> torch.Tensor:
    """Per-sample ||J^T J||_F + ||(J^T J + eps I)^-1||_F (Eq. 9, the reference's form); minimal at rotations."""
    jtj = jac.transpose(-1, -2) @ jac
    a = jtj[..., 0, 0] + RIGIDITY_EPS
    b = jtj[..., 0, 1]
    c = jtj[..., 1, 0]
    d = jtj[..., 1, 1] + RIGIDITY_EPS
    # det >= RIGIDITY_EPS^2 because J^T J is positive semi-definite; the clamp only guards round-off.
    det = (a * d - b * c).clamp_min(RIGIDITY_EPS**2)
    inv_norm = torch.sqrt(a * a + b * b + c * c + d * d) / det
    jtj_norm = torch.sqrt((jtj**2).sum((-1, -2)) + LOG_EPS**2)
    return jtj_norm + inv_norm


def rigidity_loss(
    uv: torch.Tensor, uv_dx: torch.Tensor, uv_dy: torch.Tensor, delta: float, uv_per_px: float
) -> torch.Tensor:
    """Mean symmetric Dirichlet energy of a mapping at finite-difference step ``delta`` pixels."""
    return symmetric_dirichlet(jacobian_fd(uv, uv_dx, uv_dy, delta, uv_per_px)).mean()


def flow_loss(
    uv: torch.Tensor, uv_match: torch.Tensor, weight: torch.Tensor, valid: torch.Tensor, uv_per_px: float
) -> torch.Tensor:
    """Flow consistency of a mapping (Eq. 11): atlas distance, in pixels, between flow correspondents.

    ``weight`` is the layer's alpha at the source pixel; only ``valid`` (consistent-flow) samples count.
    """
    dist = torch.sqrt(((_f32(uv_match) - _f32(uv)) ** 2).sum(-1) + LOG_EPS**2) / float(uv_per_px)
    return masked_mean(dist * _f32(weight), valid)


def alpha_flow_loss(alpha: torch.Tensor, alpha_match: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Flow consistency of alpha (Eq. 12): |alpha(p) - alpha(p + flow)| on valid samples."""
    return masked_mean((_f32(alpha) - _f32(alpha_match)).abs().sum(-1), valid)


def sparsity_loss(alpha_fg: torch.Tensor, rgb_fg: torch.Tensor) -> torch.Tensor:
    """||(1 - alpha) c_f||^2: the foreground atlas is empty (black) where the foreground is absent (Eq. 13)."""
    return (((1.0 - _f32(alpha_fg)) * _f32(rgb_fg)) ** 2).sum(-1).mean()


def anchor_loss(uv: torch.Tensor, uv_anchor: torch.Tensor, weight: torch.Tensor, uv_per_px: float) -> torch.Tensor:
    """Squared length, in pixels, of the weighted MEAN displacement of a mapping from its anchor.

    A layer's atlas is defined only up to a translation of the whole mapping; only the mean is penalised,
    so this fixes that gauge without resisting any deformation. Zero weight (no mask in the batch) gives 0.
    """
    w = _f32(weight)[:, None]
    mean = ((_f32(uv) - _f32(uv_anchor)) * w).sum(0) / w.sum().clamp_min(MIN_COUNT)
    return (mean**2).sum() / float(uv_per_px) ** 2


def atlas_sparsity_loss(rgb: torch.Tensor) -> torch.Tensor:
    """Mean l1 norm of atlas colours [N, 3] sampled at random atlas points (paper Sec. 4.3, N > 1 layers).

    With several foreground layers an object is often hidden behind another, so "black where alpha is 0"
    (``sparsity_loss``) would blacken texels that other frames show; an l1 pull on the atlas itself only
    keeps each atlas from holding content no frame needs, which is what decides which layer owns an object.
    """
    return _f32(rgb).abs().sum(-1).mean() if rgb.numel() else _f32(rgb).sum()


def scribble_loss(alpha_fg: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
    """-log(alpha_i) at pixels scribbled for foreground layer i (paper Sec. 4.4), alpha clamped by LOG_EPS.

    ``alpha_fg`` [N, F] are the foreground layers' weights, ``labels`` [N] the scribbled layer (0-based
    foreground index) of each sample, -1 where nothing is scribbled; no scribbled sample gives 0.
    """
    a = _f32(alpha_fg)
    lab = labels.long()
    has = lab >= 0
    picked = a.gather(1, lab.clamp(min=0)[:, None]).squeeze(1).clamp(LOG_EPS, 1.0)
    return masked_mean(-torch.log(picked), has)


def mask_bce(alpha: torch.Tensor, target: torch.Tensor, valid: torch.Tensor | None = None) -> torch.Tensor:
    """Binary cross-entropy of alpha against a (coarse) mask, alpha clamped away from 0 and 1 by LOG_EPS."""
    a = _f32(alpha).clamp(LOG_EPS, 1.0 - LOG_EPS)
    m = _f32(target)
    bce = -(m * torch.log(a) + (1.0 - m) * torch.log1p(-a))
    return masked_mean(bce, valid)


def psnr_from_mse(mse: float | torch.Tensor, peak: float = 1.0) -> float:
    """PSNR in dB, with the MSE clamped by MSE_EPS so a perfect match is finite."""
    mse_v = float(mse)
    mse_v = max(mse_v, MSE_EPS)
    return 10.0 * float(torch.log10(torch.tensor(peak * peak / mse_v)))
