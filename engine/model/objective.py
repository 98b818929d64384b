"""One training step's losses: the paper's terms evaluated on a random pixel batch.

Model-agnostic: it only calls ``AtlasModel.uv/color/alpha``. Points are stacked so each field runs once
per step on [pixel, pixel+dx, pixel+dy] (reconstruction, gradient loss and local rigidity share them).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from ..config import FitConfig
from ..data.video import PRIOR_IGNORE, VideoTensors, mask_hold_layers, sample_long_flow
from ..loss_terms import loss_weights
from . import losses as L
from .atlas_model import AtlasModel

#: What a reconstruction can reach: a convex combination of atlas colours in [0, 1]. Plate values outside
#: it (a linear EXR's highlights, display-encoded, stay far above 1) cannot be fitted, so the colour and
#: gradient terms compare against the plate clamped to this range; otherwise those pixels dominate the
#: gradient of the shared decoders and cost the fit everywhere else (docs/robustness.md).
TARGET_RANGE = (0.0, 1.0)
#: The per-step generator's seed is ``seed * SEED_STRIDE + step``: a prime above any step count, so no two
#: (seed, step) pairs share a stream.
SEED_STRIDE = 1_000_003
#: The long-range correspondences' per-step stream is the step's stream plus this: above any ``seed * SEED_STRIDE
#: + step`` (seeds are at most 2**31), so it is its own stream and the other draws do not change with it.
LONG_FLOW_SEED_OFFSET = 2**62


def _step_generator(cfg: FitConfig, step: int, device: torch.device) -> torch.Generator:
    """Random atlas points and scribble samples depend on (seed, step) only, so a resumed fit draws the same."""
    return torch.Generator(device=device).manual_seed(cfg.seed * SEED_STRIDE + step)


def _long_flow_points(
    video: VideoTensors, cfg: FitConfig, step: int, device: torch.device
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """This step's long-range correspondences (``sample_long_flow``, from (seed, step) only: a resumed fit
    draws the same): source points and frames, target points and frames, as continuous pixel coordinates."""
    gen = torch.Generator(device=device).manual_seed(LONG_FLOW_SEED_OFFSET + cfg.seed * SEED_STRIDE + step)
    pick = sample_long_flow(video, cfg.long_flow_samples, cfg.object_sample_share, gen)
    assert video.long_src is not None and video.long_dst is not None and video.long_dst_t is not None
    _, h, w = video.shape
    src = video.long_src[pick].long()
    p = torch.stack((src % w, (src // w) % h), -1).float() + 0.5
    return p, src // (h * w), video.long_dst[pick] + 0.5, video.long_dst_t[pick].long()


def mask_alphas(weights: torch.Tensor, mask_layers: tuple[tuple[int, ...], ...] | None) -> torch.Tensor:
    """[N, F] alpha each mask is compared with: its layer's weight, or the sum over the layers it covers."""
    if mask_layers is None:
        return weights[:, 1:]
    return torch.stack([weights[:, list(group)].sum(-1) for group in mask_layers], -1)


def _evaluate(
    field: Callable[[torch.Tensor, torch.Tensor], torch.Tensor], chunks: list[tuple[torch.Tensor, torch.Tensor]]
) -> list[torch.Tensor]:
    """``field`` on every chunk of (points, frames) in one call, split back into one output per chunk."""
    if len(chunks) == 1:
        return [field(*chunks[0])]
    out = field(torch.cat([c[0] for c in chunks]), torch.cat([c[1] for c in chunks]))
    return list(out.split([c[0].shape[0] for c in chunks]))


#: A per-layer flow target: (the batch samples it belongs to, their points moved by the flow, the frame they land in).
FlowPart = tuple[torch.Tensor, torch.Tensor, torch.Tensor]


@dataclass
class _Batch:
    """One step's pixel batch and what the fields answered about it, each field called once per layer on every
    point the terms need (``_evaluate_fields``); the loss groups read their parts from here."""

    ix: torch.Tensor
    iy: torch.Tensor
    t: torch.Tensor
    xy: torch.Tensor  # [N, 2] pixel centres
    n: int
    nl: int
    flow_parts: list[FlowPart]
    want_flow: bool
    want_alpha_flow: bool
    long_pts: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor] | None
    glob_bg: bool
    glob_fg: bool
    glob_on: bool
    glob_layers: list[int]
    local_extra: bool
    local_at: int
    glob_at: int
    flow_at: list[int]
    uv_parts: list[list[torch.Tensor]]
    alpha_parts: list[torch.Tensor]
    uvs: list[torch.Tensor]  # each layer's uv at [pixel, pixel+dx, pixel+dy]
    cols: list[torch.Tensor]
    rec: torch.Tensor  # the reconstruction at the samples
    rec_dx: torch.Tensor  # ... at their +x neighbours
    rec_dy: torch.Tensor  # ... at their +y neighbours
    wts0: torch.Tensor  # [N, L] the samples' layer weights
    # the step's context: what every loss group reads besides the fields' answers
    model: AtlasModel
    video: VideoTensors
    cfg: FitConfig
    step: int
    wts: dict[str, float]
    on: Callable[[str], bool]


def compute_losses(
    model: AtlasModel,
    video: VideoTensors,
    cfg: FitConfig,
    step: int,
    ix: torch.Tensor,
    iy: torch.Tensor,
    t: torch.Tensor,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Total weighted loss and each unweighted term (for logging).

    Only the terms in ``model.active_terms`` (engine.data.scene_analysis; None = all) are evaluated at all: a term the
    scene does not call for costs nothing, not just weight 0, and is absent from the returned dict.

    The groups run in a fixed order (each one's tensors are created in the same sequence on every step, so the
    backward pass sums the gradients in the same order and a resumed fit continues bit for bit).
    """
    b = _evaluate_fields(model, video, cfg, step, ix, iy, t)
    terms: dict[str, torch.Tensor] = {}
    _photometric_terms(terms, b)
    _rigidity_terms(terms, b)
    zero = _flow_terms(terms, b)
    gen = _sparsity_terms(terms, b, zero)
    _scribble_term(terms, b, gen)
    _anchor_term(terms, b)
    _mask_terms(terms, b)

    total = sum(b.wts[k] * v for k, v in terms.items() if b.wts.get(k, 0.0) != 0.0)
    return total, terms


def _evaluate_fields(
    model: AtlasModel,
    video: VideoTensors,
    cfg: FitConfig,
    step: int,
    ix: torch.Tensor,
    iy: torch.Tensor,
    t: torch.Tensor,
) -> _Batch:
    """Every point a field is asked about this step, and its answers: the samples and their +x/+y neighbours,
    the rigidity neighbours, the flow targets both ways and the long-range correspondences; with the step's loss
    weights and which terms the scene calls for."""
    wts = loss_weights(cfg, step)
    active = model.active_terms

    def on(term: str) -> bool:
        return active is None or term in active

    n = ix.shape[0]
    nl = model.num_layers
    xy = torch.stack((ix, iy), -1).float() + 0.5
    one_x = torch.tensor([1.0, 0.0], device=xy.device)
    one_y = torch.tensor([0.0, 1.0], device=xy.device)
    xy3 = torch.cat((xy, xy + one_x, xy + one_y))
    t3 = t.repeat(3)

    # Every point a field is asked about this step, gathered so each field runs ONCE per layer: a grid's
    # backward zero-fills a gradient the size of the whole grid per call, so one call instead of five
    # (pixels, global-rigidity neighbours, flow targets both ways) is most of a step's saving.
    want_flow, want_alpha_flow = on("flow"), on("alpha_flow") and nl > 1
    flow_parts = _flow_targets(video, xy, ix, iy, t, want_flow or want_alpha_flow)

    # long-range correspondences (t -> t +- k): their source and target points join each layer's one call
    want_long = (
        on("long_flow") and video.long_src is not None and cfg.long_flow_max_gap >= 2 and video.long_src.shape[0] > 0
    )
    long_pts = _long_flow_points(video, cfg, step, xy.device) if want_long else None

    glob_bg = on("global_rigidity_bg") and (active is None or wts["global_rigidity_bg"] > 0)
    glob_fg = on("global_rigidity_fg") and (active is None or wts["global_rigidity_fg"] > 0)
    glob_on = (wts["global_rigidity_fg"] > 0 or wts["global_rigidity_bg"] > 0) and (glob_bg or glob_fg)
    glob_layers = [i for i in range(nl) if glob_on and ((i == 0 and glob_bg) or (i > 0 and glob_fg))]
    local_extra = on("rigidity") and cfg.rigidity_delta != 1.0

    def neighbours(d: float) -> list[tuple[torch.Tensor, torch.Tensor]]:
        return [(xy + d * one_x, t), (xy + d * one_y, t)]

    # where each kind of point starts in a layer's chunk list (the same for every layer that has it)
    local_at = 1
    glob_at = local_at + (2 if local_extra else 0)
    uv_parts: list[list[torch.Tensor]] = []
    flow_at: list[int] = []
    for i in range(nl):
        chunks = [(xy3, t3)]
        if local_extra:
            chunks += neighbours(cfg.rigidity_delta)
        if i in glob_layers:
            chunks += neighbours(cfg.global_rigidity_delta)
        flow_at.append(len(chunks))
        if want_flow:
            chunks += [(q, tq) for _, q, tq in flow_parts]
        if long_pts is not None:
            chunks += [(long_pts[0], long_pts[1]), (long_pts[2], long_pts[3])]
        uv_parts.append(_evaluate(lambda a, b, _i=i: model.uv(_i, a, b), chunks))
    alpha_parts = _layer_alphas(model, (xy3, t3), flow_parts, long_pts, uv_parts, flow_at, want_flow, want_alpha_flow)

    weights3 = alpha_parts[0]  # [3N, L]
    uvs = [parts[0] for parts in uv_parts]
    cols = [model.color(i, uv) for i, uv in enumerate(uvs)]
    rec3 = sum(weights3[:, i : i + 1] * cols[i] for i in range(nl))
    rec, rec_dx, rec_dy = rec3[:n], rec3[n : 2 * n], rec3[2 * n :]
    wts0 = weights3[:n]
    return _Batch(
        ix, iy, t, xy, n, nl, flow_parts, want_flow, want_alpha_flow, long_pts, glob_bg, glob_fg, glob_on,
        glob_layers, local_extra, local_at, glob_at, flow_at, uv_parts, alpha_parts, uvs, cols, rec, rec_dx,
        rec_dy, wts0, model, video, cfg, step, wts, on,
    )  # fmt: skip


def _flow_targets(
    video: VideoTensors, xy: torch.Tensor, ix: torch.Tensor, iy: torch.Tensor, t: torch.Tensor, wanted: bool
) -> list[FlowPart]:
    """The samples whose flow to the next (then the previous) frame is reliable, with where it takes them."""
    t_count = video.shape[0]
    flow_parts: list[FlowPart] = []  # (selected samples, q, t of q)
    for direction in (1, -1):
        if t_count < 2 or not wanted:
            break
        if direction == 1:
            has = t < t_count - 1
            tt = t.clamp(max=t_count - 2)
            vec, ok = video.fwd[tt, iy, ix], video.fwd_ok[tt, iy, ix]
        else:
            has = t > 0
            tt = (t - 1).clamp(min=0)
            vec, ok = video.bwd[tt, iy, ix], video.bwd_ok[tt, iy, ix]
        sel = (has & ok).nonzero().squeeze(1)
        if sel.numel():
            flow_parts.append((sel, xy[sel] + vec[sel], t[sel] + direction))
    return flow_parts


def _layer_alphas(
    model: AtlasModel,
    samples: tuple[torch.Tensor, torch.Tensor],
    flow_parts: list[FlowPart],
    long_pts: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor] | None,
    uv_parts: list[list[torch.Tensor]],
    flow_at: list[int],
    want_flow: bool,
    want_alpha_flow: bool,
) -> list[torch.Tensor]:
    """The layer weights at the ``samples`` (their points and their +x/+y neighbours, with their frames), the flow
    targets and the long-range sources."""
    nl = model.num_layers
    alpha_chunks = [samples] + ([(q, tq) for _, q, tq in flow_parts] if want_alpha_flow else [])
    if long_pts is not None:
        alpha_chunks.append((long_pts[0], long_pts[1]))
    # the alpha's points are among the mappings' (the samples, their flow targets, the long-range sources): an
    # alpha that reads atlas coordinates takes those uvs instead of mapping the same points again
    if model.alpha_reads_uv and (want_flow or not want_alpha_flow):

        def alpha_uvs(i: int) -> torch.Tensor:
            picked = [uv_parts[i][0]]
            if want_alpha_flow:
                picked += uv_parts[i][flow_at[i] : flow_at[i] + len(flow_parts)]
            if long_pts is not None:
                picked.append(uv_parts[i][-2])
            return torch.cat(picked)

        joined = model.alpha(
            torch.cat([c[0] for c in alpha_chunks]),
            torch.cat([c[1] for c in alpha_chunks]),
            [alpha_uvs(i) for i in range(nl)],
        )
        return list(joined.split([c[0].shape[0] for c in alpha_chunks]))
    return _evaluate(model.alpha, alpha_chunks)


def _photometric_terms(terms: dict[str, torch.Tensor], b: _Batch) -> None:
    """``rgb`` and ``gradient``: the reconstruction against the plate in ``TARGET_RANGE``."""
    video = b.video
    ix, iy, t, rec, rec_dx, rec_dy = b.ix, b.iy, b.t, b.rec, b.rec_dx, b.rec_dy
    _, h, w = video.shape

    lo, hi = TARGET_RANGE
    target = video.frames[t, iy, ix].clamp(lo, hi)
    nx = (ix + 1).clamp(max=w - 1)
    ny = (iy + 1).clamp(max=h - 1)
    gt_dx = video.frames[t, iy, nx].clamp(lo, hi) - target
    gt_dy = video.frames[t, ny, ix].clamp(lo, hi) - target

    terms["rgb"] = L.rgb_loss(rec, target)
    terms["gradient"] = L.gradient_loss(rec_dx - rec, rec_dy - rec, gt_dx, gt_dy, ix < w - 1, iy < h - 1)


def _rigidity_terms(terms: dict[str, torch.Tensor], b: _Batch) -> None:
    """``rigidity`` (each mapping locally rigid) and the global rigidity terms (over a wider neighbourhood)."""
    model, cfg, on = b.model, b.cfg, b.on
    n, nl, uvs, uv_parts = b.n, b.nl, b.uvs, b.uv_parts
    local_at, glob_at = b.local_at, b.glob_at
    if on("rigidity"):
        rig = []
        for i in range(nl):
            u = uvs[i]
            u_dx, u_dy = uv_parts[i][local_at : local_at + 2] if b.local_extra else (u[n : 2 * n], u[2 * n :])
            rig.append(L.rigidity_loss(u[:n], u_dx, u_dy, cfg.rigidity_delta, model.uv_per_px(i)))
        terms["rigidity"] = sum(rig)

    if b.glob_on:
        g = {
            i: L.rigidity_loss(
                uvs[i][:n], *uv_parts[i][glob_at : glob_at + 2], cfg.global_rigidity_delta, model.uv_per_px(i)
            )
            for i in b.glob_layers
        }
        if b.glob_bg:
            terms["global_rigidity_bg"] = g[0]
        if b.glob_fg:
            fg = [g[i] for i in range(1, nl)]
            terms["global_rigidity_fg"] = sum(fg) if fg else torch.zeros((), device=b.xy.device)


def _flow_terms(terms: dict[str, torch.Tensor], b: _Batch) -> torch.Tensor:
    """``flow``, ``alpha_flow`` and ``long_flow``: points the flow pairs map to the same atlas point with the same
    layer weights. Returns the zero an absent group counts as."""
    model, on = b.model, b.on
    n, nl, uvs, uv_parts, wts0, alpha_parts = b.n, b.nl, b.uvs, b.uv_parts, b.wts0, b.alpha_parts
    # flow consistency, forward (t -> t+1) and backward (t -> t-1), only where the flow is reliable
    flow_terms, alpha_terms = [], []
    for k, (sel, _, _) in enumerate(b.flow_parts):
        if b.want_flow:
            per_layer = []
            for i in range(nl):
                uq = uv_parts[i][b.flow_at[i] + k]
                per_layer.append(L.flow_loss(uvs[i][:n][sel], uq, wts0[sel, i], None, model.uv_per_px(i)))
            flow_terms.append(sum(per_layer))
        if b.want_alpha_flow:
            alpha_terms.append(L.alpha_flow_loss(wts0[sel, 1:], alpha_parts[1 + k][:, 1:], None))
    zero = torch.zeros((), device=b.xy.device)
    # forward and backward count half each
    if on("flow"):
        terms["flow"] = 0.5 * sum(flow_terms) if flow_terms else zero
    if on("alpha_flow"):
        terms["alpha_flow"] = 0.5 * sum(alpha_terms) if alpha_terms else zero

    if b.long_pts is not None:
        # the source's alpha (the last alpha chunk) weighs each layer, as in the adjacent term
        alpha_long = alpha_parts[-1]
        terms["long_flow"] = sum(
            L.flow_loss(uv_parts[i][-2], uv_parts[i][-1], alpha_long[:, i], None, model.uv_per_px(i)) for i in range(nl)
        )
    return zero


def _sparsity_terms(terms: dict[str, torch.Tensor], b: _Batch, zero: torch.Tensor) -> torch.Generator | None:
    """``atlas_sparsity`` (several foreground layers) or ``sparsity``: foreground colour only where it is needed.
    Returns the step's generator when it drew from it (the scribble samples continue its stream)."""
    model, cfg, step, on = b.model, b.cfg, b.step, b.on
    nl, xy = b.nl, b.xy
    gen = None
    if nl > 2:
        # several foreground layers (Sec. 4.3): an object hidden behind another keeps its atlas colours, so
        # the alpha-weighted term would be wrong; an l1 on random atlas points replaces it
        if on("atlas_sparsity"):
            gen = _step_generator(cfg, step, xy.device)
            cols_s = []
            for i in range(1, nl):
                ax, ay = model.atlas_extent(i)
                r = torch.rand((cfg.atlas_sparsity_samples, 2), generator=gen, device=xy.device) * 2.0 - 1.0
                cols_s.append(model.color(i, r * torch.tensor([ax, ay], device=xy.device)))
            terms["atlas_sparsity"] = L.atlas_sparsity_loss(torch.cat(cols_s))
    elif on("sparsity"):
        sp = [L.sparsity_loss(b.wts0[:, i : i + 1], b.cols[i][: b.n]) for i in range(1, nl)]
        terms["sparsity"] = sum(sp) if sp else zero
    return gen


def _scribble_term(terms: dict[str, torch.Tensor], b: _Batch, gen: torch.Generator | None) -> None:
    """``scribble``: the layer weights at sampled scribble pixels against their strokes' labels (drawn from the
    step's generator after the atlas sparsity's points, when that drew any)."""
    model, video, cfg, step, wts, on = b.model, b.video, b.cfg, b.step, b.wts, b.on
    xy = b.xy
    if on("scribble") and video.scribble_xyt is not None and wts["scribble"] > 0 and video.scribble_xyt.shape[0]:
        gen = gen or _step_generator(cfg, step, xy.device)
        pick = torch.randint(0, video.scribble_xyt.shape[0], (cfg.scribble_samples,), generator=gen, device=xy.device)
        sxyt = video.scribble_xyt[pick]
        a = model.alpha(sxyt[:, :2].float() + 0.5, sxyt[:, 2])
        terms["scribble"] = L.scribble_loss(a[:, 1:], video.scribble_label[pick])


def _anchor_term(terms: dict[str, torch.Tensor], b: _Batch) -> None:
    """``anchor``: a bounded atlas (the fast model) keeps each foreground where its atlas box was drawn (gauge
    fixing)."""
    model, video, wts, on = b.model, b.video, b.wts, b.on
    n, nl, t, ix, iy, xy = b.n, b.nl, b.t, b.ix, b.iy, b.xy
    if nl > 1 and on("anchor") and wts["anchor"] > 0:
        m_all = video.masks[:, t, iy, ix]  # [F, N]
        groups = video.mask_layers or tuple((f + 1,) for f in range(m_all.shape[0]))
        anchor = []
        for f, group in enumerate(groups):
            for i in group:  # scribbled parts share their object's mask
                u0 = model.uv_anchor(i, xy, t)
                if u0 is not None:
                    anchor.append(L.anchor_loss(b.uvs[i][:n], u0, m_all[f], model.uv_per_px(i)))
        if anchor:
            terms["anchor"] = sum(anchor)


def _mask_terms(terms: dict[str, torch.Tensor], b: _Batch) -> None:
    """``mask``, ``mask_prior`` and ``mask_hold``: the foreground alphas against the masks and the mask prior."""
    video, cfg, wts, on = b.video, b.cfg, b.wts, b.on
    t, ix, iy, xy = b.t, b.ix, b.iy, b.xy
    # bool [F]: the mask layers held after the bootstrap (only looked up once the hold's weight is on)
    held: torch.Tensor | None = None
    if wts["mask_hold"] > 0 and on("mask_hold"):
        hold = mask_hold_layers(video.prior_coverage, cfg.mask_hold_coverage)
        held = torch.as_tensor(hold, device=xy.device) if hold.any() else None
    on_masks = on("mask") or on("mask_prior") or held is not None
    if b.nl > 1 and on_masks and (wts["mask"] > 0 or wts["mask_prior"] > 0 or held is not None):
        fg_alpha = mask_alphas(b.wts0, video.mask_layers)
        m = video.masks[:, t, iy, ix].t()  # [N, F]
        valid = video.mask_valid[:, t].t()
        terms["mask"] = L.mask_bce(fg_alpha, m, valid)
        prior = video.prior[:, t, iy, ix].t()
        terms["mask_prior"] = L.mask_bce(fg_alpha, prior.clamp(min=0), prior != PRIOR_IGNORE)
        if held is not None:
            # small and thin objects' layers: the bootstrap's term on their masks alone, after the bootstrap
            terms["mask_hold"] = L.mask_bce(fg_alpha, m, valid & held[None, :])
