"""Accuracy of a fitted atlas as a motion model: point tracking through the atlas, a chained-flow
baseline, TAP-Vid scoring, and the flow consistency of the mappings.

Coordinates: continuous working-resolution pixels, pixel i's centre at i + 0.5 (the models' convention).
TAP-Vid tracks (``tracks_tapvid.npz``) are in native pixels with the same convention (x = x_norm * W), so
converting is a pure scale per axis; scores are computed back in NATIVE pixels, the tracks' own frame
(TAP-Vid itself scores at 256x256: ``tapvid_scores(..., scale=...)`` gives that too).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from engine.model.atlas_model import AtlasModel

#: TAP-Vid's thresholds in pixels; delta_avg is the mean of the fractions within each.
TAPVID_THRESHOLDS: tuple[float, ...] = (1.0, 2.0, 4.0, 8.0, 16.0)
#: TAP-Vid scores positions in a 256x256 frame.
TAPVID_EVAL_SIZE = (256, 256)
#: A sub-pixel refinement step of the nearest-UV search is ignored when the mapping's 2x2 Jacobian is
#: this close to singular (the UV barely moves with the pixel there: no direction to refine in).
JACOBIAN_MIN_DET = 1e-12
#: Frame-gap bands of ``scores_by_gap`` (frames between the query and the scored position): [1, 3), [3, 8), [8, 16),
#: [16, 32), [32, ...). Short gaps show the mapping's local precision, long ones drift.
GAP_EDGES: tuple[int, ...] = (1, 3, 8, 16, 32)
#: Pixels per forward chunk of the tracking and consistency evaluations.
CHUNK = 65536


@dataclass
class Tracks:
    """Ground-truth point tracks (TAP-Vid layout), in native pixels."""

    xy: np.ndarray  # float32 [N, T, 2]
    occluded: np.ndarray  # bool [N, T]
    query_txy: np.ndarray  # float32 [N, 3]: (t, x, y)
    image_size: tuple[int, int]  # native (W, H)
    #: bool [N]: the query pixel lies on the clip's mask (None: unknown). Scores are split by it because an
    #: atlas can only follow what its layers model: a point on a car driving through the background moves
    #: against the background layer, which chained flow follows and a background atlas cannot.
    on_mask: np.ndarray | None = None

    @property
    def num_frames(self) -> int:
        return int(self.xy.shape[1])

    def subset(self, keep: np.ndarray, frames: int) -> Tracks:
        """The tracks ``keep`` selects, cut to the first ``frames`` frames."""
        on_mask = None if self.on_mask is None else self.on_mask[keep]
        return Tracks(
            self.xy[keep, :frames], self.occluded[keep, :frames], self.query_txy[keep], self.image_size, on_mask
        )

    def cut(self, frames: int) -> Tracks:
        """The tracks of a clip of ``frames`` frames: cut to them, queries beyond them dropped."""
        n = min(self.num_frames, frames)
        return self.subset(np.rint(self.query_txy[:, 0]).astype(int) < n, n)


def load_tracks(path: str | Path) -> Tracks:
    """``tracks_tapvid.npz``: ``tracks_xy`` [N, T, 2] and ``occluded`` [N, T] (native pixels), ``query_points_txy``
    [N, 3], ``frame_indices`` (0..T-1: the clip's frames), ``image_size_wh`` and optionally ``on_mask_at_query``
    [N] (whether each query lies on the clip's mask)."""
    with np.load(path, allow_pickle=False) as d:
        frames = d["frame_indices"]
        if not np.array_equal(frames, np.arange(len(frames))):
            raise ValueError(f"{path}: frame_indices must be 0..T-1, got {frames.tolist()}")
        w, h = (int(v) for v in d["image_size_wh"])
        return Tracks(
            d["tracks_xy"].astype(np.float32),
            d["occluded"].astype(bool),
            d["query_points_txy"].astype(np.float32),
            (w, h),
            d["on_mask_at_query"].astype(bool) if "on_mask_at_query" in d.files else None,
        )


def save_tracks(path: str | Path, tracks: Tracks) -> None:
    """Write ``tracks`` in the ``tracks_tapvid.npz`` layout (synthetic clips, tests)."""
    n, t = tracks.occluded.shape
    np.savez(
        path,
        tracks_xy=np.where(tracks.occluded[..., None], 0.0, tracks.xy).astype(np.float32),
        occluded=tracks.occluded,
        query_points_txy=tracks.query_txy.astype(np.float32),
        frame_indices=np.arange(t, dtype=np.int32),
        on_mask_at_query=np.zeros(n, dtype=bool) if tracks.on_mask is None else tracks.on_mask.astype(bool),
        image_size_wh=np.asarray(tracks.image_size, dtype=np.int32),
    )


def scored_positions(occluded: np.ndarray, query_t: np.ndarray) -> np.ndarray:
    """bool [N, T]: the positions TAP-Vid scores, visible ones other than each track's query frame."""
    occ = np.asarray(occluded, dtype=bool)
    return ~occ & (np.arange(occ.shape[1])[None, :] != np.asarray(query_t, dtype=np.int64)[:, None])


def tapvid_scores(
    pred_xy: np.ndarray,
    gt_xy: np.ndarray,
    occluded: np.ndarray,
    query_t: np.ndarray,
    thresholds: tuple[float, ...] = TAPVID_THRESHOLDS,
    scale: tuple[float, float] = (1.0, 1.0),
) -> dict:
    """TAP-Vid position accuracy: over visible points other than each track's query frame, the fraction
    within each threshold (strictly less, as TAP-Vid), and their mean ``delta_avg``.

    ``pred_xy``, ``gt_xy`` [N, T, 2]; ``occluded`` [N, T]; ``query_t`` [N]. ``scale`` multiplies x and y
    before measuring (e.g. 256 / W, 256 / H for TAP-Vid's own 256x256 convention). ``delta_avg`` is None
    when there is nothing to score.
    """
    pred = np.asarray(pred_xy, dtype=np.float64) * np.asarray(scale, dtype=np.float64)
    gt = np.asarray(gt_xy, dtype=np.float64) * np.asarray(scale, dtype=np.float64)
    evaluated = scored_positions(occluded, query_t)
    count = int(evaluated.sum())
    d2 = ((pred - gt) ** 2).sum(-1)
    fractions = {}
    for thr in thresholds:
        hit = (d2 < thr * thr) & evaluated
        fractions[f"{thr:g}"] = float(hit.sum() / count) if count else None
    avg = float(np.mean([fractions[f"{thr:g}"] for thr in thresholds])) if count else None
    return {"delta_avg": avg, "delta": fractions, "scored_points": count}


def scores_by_gap(
    pred_xy: np.ndarray,
    gt_xy: np.ndarray,
    occluded: np.ndarray,
    query_t: np.ndarray,
    edges: tuple[int, ...] = GAP_EDGES,
) -> list[dict]:
    """``tapvid_scores`` per band of frames between each position and its track's query (``edges``), with each
    band's median error in pixels: an aggregate hides whether a tracker is imprecise from one frame to the next
    (short gaps) or drifts over the clip (long gaps), and the two call for different cures. Bands with nothing to
    score report ``delta_avg`` and ``median_px`` None."""
    occ = np.asarray(occluded, dtype=bool)
    qt = np.asarray(query_t, dtype=np.int64)
    gap = np.abs(np.arange(occ.shape[1])[None, :] - qt[:, None])
    err = np.linalg.norm(np.asarray(pred_xy, np.float64) - np.asarray(gt_xy, np.float64), axis=-1)
    scored = scored_positions(occ, qt)
    out = []
    for lo, hi in zip(edges, (*edges[1:], None), strict=True):
        band = (gap >= lo) if hi is None else (gap >= lo) & (gap < hi)
        s = tapvid_scores(pred_xy, gt_xy, occ | ~band, qt)
        sel = scored & band
        median = round(float(np.median(err[sel])), 3) if sel.any() else None
        out.append(
            {"gap": [lo, hi], "delta_avg": s["delta_avg"], "scored_points": s["scored_points"], "median_px": median}
        )
    return out


def track_report(pred_native: np.ndarray, tracks: Tracks) -> dict:
    """A tracker's TAP-Vid scores against ``tracks``: ``delta_avg`` in native pixels, ``delta_avg_256`` at TAP-Vid's
    own 256x256 (the two differ a lot on a wide plate: 1 px at 256 is 3.3 native px across 854), ``by_gap`` and,
    when the tracks know it, ``by_query_mask``. An infinite prediction (no position) counts as a miss."""
    qt = np.rint(tracks.query_txy[:, 0]).astype(int)
    w, h = tracks.image_size
    native = tapvid_scores(pred_native, tracks.xy, tracks.occluded, qt)
    s256 = tapvid_scores(
        pred_native, tracks.xy, tracks.occluded, qt, scale=(TAPVID_EVAL_SIZE[0] / w, TAPVID_EVAL_SIZE[1] / h)
    )
    by_gap = scores_by_gap(pred_native, tracks.xy, tracks.occluded, qt)
    for band in by_gap:  # a band whose median is a miss has no finite error to show
        if band["median_px"] is not None and not np.isfinite(band["median_px"]):
            band["median_px"] = None
    out = {**native, "coords": "native", "delta_avg_256": s256["delta_avg"], "delta_256": s256["delta"]}
    out["by_gap"] = by_gap
    if tracks.on_mask is not None:
        out["by_query_mask"] = {
            name: {
                "delta_avg": tapvid_scores(pred_native[sel], tracks.xy[sel], tracks.occluded[sel], qt[sel])[
                    "delta_avg"
                ],
                "delta_avg_256": tapvid_scores(
                    pred_native[sel],
                    tracks.xy[sel],
                    tracks.occluded[sel],
                    qt[sel],
                    scale=(TAPVID_EVAL_SIZE[0] / w, TAPVID_EVAL_SIZE[1] / h),
                )["delta_avg"],
            }
            for name, sel in (("on_mask", tracks.on_mask), ("off_mask", ~tracks.on_mask))
        }
    return out


def track_scores(pred_native: np.ndarray, tracks: Tracks) -> dict:
    qt = np.rint(tracks.query_txy[:, 0]).astype(int)
    native = tapvid_scores(pred_native, tracks.xy, tracks.occluded, qt)
    w, h = tracks.image_size
    s256 = tapvid_scores(
        pred_native, tracks.xy, tracks.occluded, qt, scale=(TAPVID_EVAL_SIZE[0] / w, TAPVID_EVAL_SIZE[1] / h)
    )
    out = {**native, "coords": "native", "delta_avg_256": s256["delta_avg"]}
    out["per_point"] = _per_point(pred_native, tracks)
    out["by_gap"] = scores_by_gap(pred_native, tracks.xy, tracks.occluded, qt)
    if tracks.on_mask is not None:  # where an atlas falls short: on the masked object or in the background
        out["by_query_mask"] = {
            name: tapvid_scores(pred_native[sel], tracks.xy[sel], tracks.occluded[sel], qt[sel])
            for name, sel in (("on_mask", tracks.on_mask), ("off_mask", ~tracks.on_mask))
        }
    return out


def _per_point(pred_native: np.ndarray, tracks: Tracks) -> list[dict]:
    """Each track's own score, in the file's order: an aggregate hides which points fall short, and a few
    points on something a layer cannot follow (seen through a window, driving through the background) can
    decide a clip. ``delta_avg`` weighted by ``scored_points`` gives the aggregate back."""
    qt = np.rint(tracks.query_txy[:, 0]).astype(int)
    err = np.linalg.norm(np.asarray(pred_native, np.float64) - tracks.xy, axis=-1)
    scored = scored_positions(tracks.occluded, qt)
    out = []
    for i in range(len(qt)):
        s = tapvid_scores(pred_native[i : i + 1], tracks.xy[i : i + 1], tracks.occluded[i : i + 1], qt[i : i + 1])
        out.append(
            {
                "delta_avg": s["delta_avg"],
                "scored_points": s["scored_points"],
                "median_px": round(float(np.median(err[i][scored[i]])), 3) if scored[i].any() else None,
            }
        )
    return out


def sample_bilinear(field: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``field`` [H, W, C] at continuous points ``xy`` [N, 2] (pixel centre i + 0.5), edge-clamped."""
    h, w = field.shape[:2]
    x = np.clip(xy[:, 0] - 0.5, 0.0, w - 1.0)
    y = np.clip(xy[:, 1] - 0.5, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), max(w - 2, 0))
    y0 = np.minimum(np.floor(y).astype(np.int64), max(h - 2, 0))
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    top = field[y0, x0] * (1 - fx) + field[y0, x1] * fx
    bottom = field[y1, x0] * (1 - fx) + field[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def chained_flow_tracks(
    forward: np.ndarray, backward: np.ndarray, query_txy: np.ndarray, num_frames: int
) -> np.ndarray:
    """The baseline: follow each query point through the adjacent-frame flow, forward and backward from its
    query frame, sampling the flow bilinearly. ``forward[t]``: frame t -> t+1, ``backward[t]``: t+1 -> t
    (``FlowField`` layout); query and result in the same continuous pixel frame. Returns [N, num_frames, 2].
    """
    return chain_flow(query_txy, num_frames, lambda t: forward[t], lambda t: backward[t - 1])


def chain_flow(
    query_txy: np.ndarray,
    num_frames: int,
    flow_ahead: Callable[[int], np.ndarray],
    flow_back: Callable[[int], np.ndarray],
) -> np.ndarray:
    """Each query (t, x, y) followed frame by frame, forward and backward from its query frame, by adding the
    bilinearly sampled flow: ``flow_ahead(t)`` moves frame t to t+1, ``flow_back(t)`` frame t to t-1, each asked
    for only when some query's chain reaches it (a caller may compute flow on demand). Returns [N, num_frames, 2].
    """
    q = np.asarray(query_txy, dtype=np.float64)
    n = q.shape[0]
    tq = np.rint(q[:, 0]).astype(np.int64)
    out = np.zeros((n, num_frames, 2), dtype=np.float64)
    out[np.arange(n), np.clip(tq, 0, num_frames - 1)] = q[:, 1:3]
    for t in range(num_frames - 1):  # forward: frames after the query
        sel = tq <= t
        if sel.any():
            p = out[sel, t]
            out[sel, t + 1] = p + sample_bilinear(flow_ahead(t), p)
    for t in range(num_frames - 1, 0, -1):  # backward: frames before the query
        sel = tq >= t
        if sel.any():
            p = out[sel, t]
            out[sel, t - 1] = p + sample_bilinear(flow_back(t), p)
    return out


def _forward_chunks(fn, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    return torch.cat([fn(xy[s : s + CHUNK], t[s : s + CHUNK]) for s in range(0, xy.shape[0], CHUNK)])


@torch.no_grad()
def owners(model: AtlasModel, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """The layer that owns each pixel: the largest opacity weight."""
    return _forward_chunks(model.alpha, xy, t).argmax(-1)


def _frame_grid(size: tuple[int, int], stride: int, device: torch.device) -> torch.Tensor:
    w, h = size
    ys, xs = torch.meshgrid(
        torch.arange(0, h, stride, device=device), torch.arange(0, w, stride, device=device), indexing="ij"
    )
    return torch.stack((xs.reshape(-1), ys.reshape(-1)), -1).float() + 0.5


@torch.no_grad()
def atlas_tracks(
    model: AtlasModel,
    query_xy: np.ndarray,
    query_t: np.ndarray,
    num_frames: int,
    size: tuple[int, int],
    device: torch.device,
    stride: int = 4,
) -> tuple[np.ndarray, np.ndarray]:
    """Track points through the atlas: each query is mapped to the atlas of the layer that owns it; in
    every frame the prediction is the pixel, among those that layer owns, whose UV is nearest (a search
    on a ``stride`` grid, then at every pixel around the best, then one Newton step on the mapping for
    sub-pixel position). A frame where the layer owns no pixel falls back to every pixel.

    ``query_xy`` [N, 2] working pixels, ``query_t`` [N]. Returns (tracks [N, num_frames, 2], owner [N]).
    """
    w, h = size
    n = len(query_xy)
    qxy = torch.as_tensor(np.asarray(query_xy), dtype=torch.float32, device=device).reshape(n, 2)
    qt = torch.as_tensor(np.asarray(query_t), dtype=torch.long, device=device).reshape(n)
    owner = owners(model, qxy, qt) if n else torch.zeros(0, dtype=torch.long, device=device)
    quv = torch.zeros(n, 2, device=device)
    for layer in owner.unique().tolist():
        sel = owner == layer
        quv[sel] = model.uv(layer, qxy[sel], qt[sel]).float()
    out = np.zeros((n, num_frames, 2), dtype=np.float64)
    grid = _frame_grid(size, stride, device)
    r = torch.arange(-stride, stride + 1, device=device, dtype=torch.float32)
    offs = torch.stack(torch.meshgrid(r, r, indexing="xy"), -1).reshape(-1, 2)  # [K, 2]
    lo = torch.tensor([0.5, 0.5], device=device)
    hi = torch.tensor([w - 0.5, h - 0.5], device=device)
    for t in range(num_frames):
        tt = torch.full((grid.shape[0],), t, dtype=torch.long, device=device)
        grid_owner = owners(model, grid, tt)
        for layer in owner.unique().tolist():
            idx = (owner == layer).nonzero().squeeze(1)
            target = quv[idx]  # [M, 2]
            uv = _forward_chunks(lambda a, b, _l=layer: model.uv(_l, a, b).float(), grid, tt)
            best = _nearest(uv, grid_owner == layer, target)  # [M]
            # refine at every pixel of a window around the coarse best
            cand = (grid[best][:, None, :] + offs[None]).clamp(lo, hi).reshape(-1, 2)  # [M*K, 2]
            tc = torch.full((cand.shape[0],), t, dtype=torch.long, device=device)
            cuv = _forward_chunks(lambda a, b, _l=layer: model.uv(_l, a, b).float(), cand, tc)
            cown = owners(model, cand, tc) == layer
            k = offs.shape[0]
            d2 = ((cuv.reshape(-1, k, 2) - target[:, None]) ** 2).sum(-1)
            own = cown.reshape(-1, k)
            d2 = torch.where(own.any(1, keepdim=True), torch.where(own, d2, torch.inf), d2)
            p0 = cand.reshape(-1, k, 2)[torch.arange(len(idx), device=device), d2.argmin(1)]  # [M, 2]
            out[idx.cpu().numpy(), t] = _newton_step(model, layer, p0, t, target, lo, hi).cpu().numpy()
    return out, owner.cpu().numpy()


def _nearest(uv: torch.Tensor, owned: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Index of the grid point nearest each target UV, among owned points when there are any."""
    best = torch.empty(target.shape[0], dtype=torch.long, device=uv.device)
    pool = uv[owned] if bool(owned.any()) else uv
    index = owned.nonzero().squeeze(1) if bool(owned.any()) else torch.arange(uv.shape[0], device=uv.device)
    for s in range(0, target.shape[0], 64):
        d2 = torch.cdist(target[s : s + 64], pool)
        best[s : s + 64] = index[d2.argmin(1)]
    return best


def _newton_step(
    model: AtlasModel,
    layer: int,
    p0: torch.Tensor,
    t: int,
    target: torch.Tensor,
    lo: torch.Tensor,
    hi: torch.Tensor,
) -> torch.Tensor:
    """One Gauss-Newton step from pixel ``p0`` towards the UV ``target``, at most one pixel per axis."""
    m = p0.shape[0]
    ex = torch.tensor([1.0, 0.0], device=p0.device)
    ey = torch.tensor([0.0, 1.0], device=p0.device)
    pts = torch.cat((p0, p0 + ex, p0 + ey))
    uv = model.uv(layer, pts, torch.full((3 * m,), t, dtype=torch.long, device=p0.device)).float()
    u0, ux, uy = uv[:m], uv[m : 2 * m], uv[2 * m :]
    jac = torch.stack((ux - u0, uy - u0), -1).double()  # [M, 2 (uv), 2 (xy)]
    det = torch.linalg.det(jac)
    ok = det.abs() > JACOBIAN_MIN_DET
    step = torch.zeros_like(p0)
    if bool(ok.any()):
        rhs = (target - u0).double()[ok][..., None]
        step[ok] = torch.linalg.solve(jac[ok], rhs).squeeze(-1).float().clamp(-1.0, 1.0)
    return (p0 + step).clamp(lo, hi)


@torch.no_grad()
def mapping_consistency(
    model: AtlasModel,
    forward: np.ndarray,
    forward_ok: np.ndarray,
    frames: list[int],
    device: torch.device,
    stride: int = 4,
) -> dict:
    """Mean atlas distance between the UV of a pixel and the UV of its flow correspondent in the next
    frame, both in the layer that owns the pixel, over the pixels (on a ``stride`` grid) of ``frames``
    whose forward flow is consistent (``forward_ok``). Distances are in texels: atlas units divided by
    ``uv_per_px`` (the atlas distance one working pixel spans under a rigid mapping; one finest-grid texel
    of the fast model at atlas_density 1). Frames without a successor are skipped.
    """
    pairs = forward.shape[0]
    total, count, per_layer = 0.0, 0, {}
    for t in frames:
        if t >= pairs:
            continue
        h, w = forward_ok.shape[1:]
        iy, ix = np.mgrid[0:h:stride, 0:w:stride]
        iy, ix = iy.reshape(-1), ix.reshape(-1)
        ok = forward_ok[t, iy, ix]
        iy, ix = iy[ok], ix[ok]
        if len(ix) == 0:
            continue
        xy = torch.as_tensor(np.stack((ix, iy), -1) + 0.5, dtype=torch.float32, device=device)
        q = xy + torch.as_tensor(forward[t, iy, ix], dtype=torch.float32, device=device)
        tt = torch.full((len(ix),), t, dtype=torch.long, device=device)
        own = owners(model, xy, tt)
        for layer in own.unique().tolist():
            sel = own == layer
            a = _forward_chunks(lambda p, s, _l=layer: model.uv(_l, p, s).float(), xy[sel], tt[sel])
            b = _forward_chunks(lambda p, s, _l=layer: model.uv(_l, p, s).float(), q[sel], tt[sel] + 1)
            d = (a - b).norm(dim=-1) / model.uv_per_px(layer)
            total += float(d.sum())
            count += int(d.numel())
            s, c = per_layer.get(layer, (0.0, 0))
            per_layer[layer] = (s + float(d.sum()), c + int(d.numel()))
    return {
        "mean_texels": total / count if count else None,
        "pixels": count,
        "per_layer": {str(k): v[0] / v[1] for k, v in sorted(per_layer.items())},
    }


@torch.no_grad()
def anchor_spread(model: AtlasModel, tracks: Tracks, to_native: np.ndarray, device: torch.device) -> dict | None:
    """How far each track's true positions land from its query's in the starting mapping (``uv_anchor``: the
    motion fitted to the flow before any training, the gauge the atlas is drawn in) of the foreground layer most
    opaque at the query: a starting motion that loses the object (an occluder's flow taken for it) puts the object
    in a second place in its atlas, and training seldom brings it back. Native pixels (atlas distance /
    ``uv_per_px``, times the mean scale ``to_native`` [2]); points queried on the mask only when the tracks say.
    None for a model without a starting motion or without a foreground layer."""
    qt = np.rint(tracks.query_txy[:, 0]).astype(int)
    keep = np.ones(len(qt), bool) if tracks.on_mask is None else tracks.on_mask.astype(bool)
    scored = scored_positions(tracks.occluded, qt) & keep[:, None]
    if not scored.any() or model.num_layers < 2:
        return None
    frames = scored.shape[1]
    per_px = float(np.sqrt(np.prod(np.asarray(to_native, np.float64))))
    qxy = torch.as_tensor(tracks.query_txy[:, 1:3] / to_native, dtype=torch.float32, device=device)
    layer_of = (model.alpha(qxy, torch.as_tensor(qt, device=device))[:, 1:].argmax(-1) + 1).cpu().numpy()
    dist: list[np.ndarray] = []
    for layer in np.unique(layer_of[keep]).tolist():
        idx = np.nonzero(keep & (layer_of == layer))[0]
        xy = torch.as_tensor(tracks.xy[idx] / to_native, dtype=torch.float32, device=device).reshape(-1, 2)
        uv = model.uv_anchor(int(layer), xy, torch.arange(frames, device=device).repeat(len(idx)))
        if uv is None:
            return None
        uv = uv.float().reshape(len(idx), frames, 2)
        at_query = uv[torch.arange(len(idx), device=device), torch.as_tensor(qt[idx], device=device)]
        d = ((uv - at_query[:, None]).norm(dim=-1) / model.uv_per_px(int(layer)) * per_px).cpu().numpy()
        dist.append(d[scored[idx]])
    every = np.concatenate(dist)
    return {
        "mean_px": round(float(every.mean()), 3),
        "median_px": round(float(np.median(every)), 3),
        "positions": int(every.size),
        "on_mask_only": tracks.on_mask is not None,
    }


__all__ = [
    "GAP_EDGES",
    "TAPVID_THRESHOLDS",
    "Tracks",
    "anchor_spread",
    "atlas_tracks",
    "chained_flow_tracks",
    "load_tracks",
    "mapping_consistency",
    "owners",
    "sample_bilinear",
    "save_tracks",
    "scored_positions",
    "scores_by_gap",
    "tapvid_scores",
    "track_report",
    "track_scores",
]
