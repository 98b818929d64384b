"""Measuring a fit: the reconstruction's error at sampled pixels (the live PSNR), whole frames rendered at
working resolution, and the full-frame PSNR and alpha IoU the fit's metrics record."""

from __future__ import annotations

import numpy as np
import torch

from ..data.video import VideoTensors, frame_pixels
from ..model.atlas_model import AtlasModel
from ..model.losses import psnr_from_mse
from ..model.objective import TARGET_RANGE

#: Pixels per forward chunk when evaluating whole frames (bounds memory of the evaluation).
EVAL_CHUNK = 65536
#: A foreground alpha above this counts as the layer's when comparing it with its mask (alpha IoU).
ALPHA_IOU_THRESHOLD = 0.5


@torch.no_grad()
def evaluate_pixels(
    model: AtlasModel, video: VideoTensors, ix: torch.Tensor, iy: torch.Tensor, t: torch.Tensor
) -> float:
    """Mean squared error of the reconstruction at the given pixels, against the plate in the objective's
    ``TARGET_RANGE`` (what a reconstruction can reach: an HDR highlight, or an absurd value clamped to
    ``prepare.PLATE_VALUE_LIMIT``, counts as the range's top, so one pixel cannot decide the PSNR; a no-op for
    8/16-bit plates)."""
    lo, hi = TARGET_RANGE
    total, count = 0.0, 0
    for s in range(0, ix.shape[0], EVAL_CHUNK):
        sl = slice(s, s + EVAL_CHUNK)
        xy = torch.stack((ix[sl], iy[sl]), -1).float() + 0.5
        rec, _ = model.reconstruct(xy, t[sl])
        total += float(((rec - video.frames[t[sl], iy[sl], ix[sl]].clamp(lo, hi)) ** 2).sum())
        count += rec.shape[0] * 3
    return total / max(count, 1)


@torch.no_grad()
def render_frame(
    model: AtlasModel, t: int, size: tuple[int, int], device: torch.device
) -> tuple[np.ndarray, np.ndarray]:
    """Reconstruction [H, W, 3] and layer weights [H, W, L] of one frame at working resolution."""
    w, h = size
    xy, tt = frame_pixels(size, t, device)
    recs, ws = [], []
    for s in range(0, xy.shape[0], EVAL_CHUNK):
        r, wgt = model.reconstruct(xy[s : s + EVAL_CHUNK], tt[s : s + EVAL_CHUNK])
        recs.append(r)
        ws.append(wgt)
    return torch.cat(recs).reshape(h, w, 3).cpu().numpy(), torch.cat(ws).reshape(h, w, -1).cpu().numpy()


@torch.no_grad()
def evaluate_full(model: AtlasModel, video: VideoTensors, size: tuple[int, int], device: torch.device) -> dict:
    """Full-frame PSNR over every pixel of every frame (against the plate in ``TARGET_RANGE``, as
    ``evaluate_pixels``), and per-layer alpha IoU against the masks."""
    t_count = video.shape[0]
    sq, n = 0.0, 0
    inter = np.zeros(video.masks.shape[0])
    union = np.zeros(video.masks.shape[0])
    frames_np = video.frames.cpu().numpy()
    masks_np = video.masks.cpu().numpy()
    lo, hi = TARGET_RANGE
    for t in range(t_count):
        rec, wts = render_frame(model, t, size, device)
        sq += float(((rec - np.clip(frames_np[t], lo, hi)) ** 2).sum())
        n += rec.size
        for f in range(masks_np.shape[0]):
            group = video.mask_layers[f] if video.mask_layers is not None else (f + 1,)
            a = wts[..., list(group)].sum(-1) > ALPHA_IOU_THRESHOLD
            m = masks_np[f, t]
            inter[f] += float((a & m).sum())
            union[f] += float((a | m).sum())
    mse = sq / max(n, 1)
    iou = [float(i / u) if u > 0 else 1.0 for i, u in zip(inter, union, strict=True)]
    return {"psnr": psnr_from_mse(mse), "mse": mse, "alpha_iou": iou}
