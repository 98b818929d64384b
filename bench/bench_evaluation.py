"""A bench run's evaluation at one point of its training clock: full-frame PSNR, the decomposition's foreground
IoU, mapping consistency and point tracking, scored in TAP-Vid's terms (in aggregate, per point, by frame gap
and by where the query lies)."""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING

import numpy as np
import torch

from bench.bench_machine import rss_mb
from bench.tracking import anchor_spread, atlas_tracks, mapping_consistency, track_scores
from engine.fit.evaluation import render_frame
from engine.model.losses import psnr_from_mse

if TYPE_CHECKING:
    from bench.bench_runs import Run

#: A pixel is foreground (``fg_iou``) where the foreground layers' opacity weights sum to at least this.
FG_ALPHA_THRESHOLD = 0.5


def foreground(weights: np.ndarray) -> np.ndarray:
    """bool [H, W]: where the foreground layers together (every layer but the background, layer 0) hold at least
    FG_ALPHA_THRESHOLD of the pixel's opacity weights [H, W, L]."""
    return np.asarray(weights[..., 1:].sum(-1) >= FG_ALPHA_THRESHOLD)


@torch.no_grad()
def evaluate(run: Run, device: torch.device, stride: int) -> dict:
    """One curve point: PSNR over every pixel of the clip's eval frames, the decomposition's ``fg_iou`` (pooled
    over those frames: the ``foreground`` against the precise masks; None without them), mapping
    consistency, tracking."""
    t0 = time.perf_counter()
    clip = run.clip
    frames = clip.video.frames
    sq, n = 0.0, 0
    inter, union = 0, 0
    for t in clip.eval_frames:
        rec, wts = render_frame(run.trainer.model, t, clip.prepared.size, device)
        sq += float(((torch.from_numpy(rec).to(frames.device) - frames[t]) ** 2).sum())
        n += rec.size
        if clip.score_masks is not None:
            fg, gt = foreground(wts), clip.score_masks[t]
            inter += int((fg & gt).sum())
            union += int((fg | gt).sum())
    psnr = psnr_from_mse(sq / max(n, 1))
    fg_iou = None if clip.score_masks is None else (inter / union if union else 1.0)
    flow = clip.prepared.flow
    cons = mapping_consistency(run.trainer.model, flow.forward, flow.forward_ok, clip.eval_frames, device, stride)
    tracking = None
    if clip.tracks is not None and len(clip.query_t):
        pred, _ = atlas_tracks(
            run.trainer.model, clip.query_xy, clip.query_t, clip.track_frames, clip.prepared.size, device, stride
        )
        tracking = track_scores(pred * clip.to_native, clip.tracks)
        tracking["anchor_spread"] = anchor_spread(run.trainer.model, clip.tracks, clip.to_native, device)
    if math.isfinite(psnr):
        run.best_psnr = max(run.best_psnr, psnr)
    rss, peak = rss_mb()
    return {
        "train_seconds": round(run.trainer.train_seconds, 3),
        "step": run.trainer.step,
        "psnr": round(psnr, 4),
        "fg_iou": None if fg_iou is None else round(fg_iou, 4),
        "best_psnr": round(run.best_psnr, 4) if math.isfinite(run.best_psnr) else None,
        "consistency_texels": None if cons["mean_texels"] is None else round(cons["mean_texels"], 4),
        "consistency_pixels": cons["pixels"],
        "tracking": tracking,
        "eval_seconds": round(time.perf_counter() - t0, 3),
        "rss_mb": rss,
        "peak_rss_mb": peak,
    }
