"""The clip as training tensors: frames, masks, mask prior, flow; and the per-step pixel sampler."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from .flow import FlowField
from .long_flow import LongFlow

#: Prior label meaning "no opinion" (near a mask boundary, or a frame without a mask).
PRIOR_IGNORE = -1
#: A coarse mask's trusted core reaches at most this fraction of the object's thickness (its largest distance
#: inside), so an object thinner than twice the margin still keeps a core.
CORE_FRACTION = 0.4


@dataclass
class VideoTensors:
    frames: torch.Tensor  # float32 [T, H, W, 3]
    masks: torch.Tensor  # bool [F, T, H, W] (F foreground layers)
    mask_valid: torch.Tensor  # bool [F, T]: the frame has a (non-empty) mask for that layer
    prior: torch.Tensor  # int8 [F, T, H, W]: 1 / 0 far inside / outside the mask, PRIOR_IGNORE elsewhere
    fwd: torch.Tensor  # float32 [T-1, H, W, 2]
    bwd: torch.Tensor  # float32 [T-1, H, W, 2]
    fwd_ok: torch.Tensor  # bool [T-1, H, W]
    bwd_ok: torch.Tensor  # bool [T-1, H, W]
    #: Foreground layers (1-based model layers) each mask covers; None = mask f is layer f+1 alone. A mask
    #: split by scribbles covers several layers, and its BCE applies to the sum of their alphas (Sec. 4.4).
    mask_layers: tuple[tuple[int, ...], ...] | None = None
    #: per mask layer, the share of its mask pixels the prior holds as inside (``prior_coverage``): under a config's
    #: ``mask_hold_coverage`` the layer's mask term goes on after the bootstrap (``mask_hold_layers``)
    prior_coverage: tuple[float | None, ...] = ()
    scribble_xyt: torch.Tensor | None = None  # long [S, 3]: x, y, t of every scribbled pixel
    scribble_label: torch.Tensor | None = None  # long [S]: its 0-based foreground layer
    #: int32/int64 [R]: flat indices t*H*W + y*W + x of every pixel on or within the prior's margin of a mask (any
    #: layer, frames with a mask only), the pool ``sample_batch`` oversamples objects from.
    object_region: torch.Tensor | None = None
    #: Long-range correspondences (``engine.data.long_flow``; None: off), those whose source pixel is in the
    #: ``object_region`` first (``long_objects`` of them), so ``sample_long_flow`` draws from either part by index.
    long_src: torch.Tensor | None = None  # int32/int64 [N]: flat source index t*H*W + y*W + x
    long_dst: torch.Tensor | None = None  # float32 [N, 2]: target (x, y), pixel centres at integers
    long_dst_t: torch.Tensor | None = None  # int16/int32 [N]: target frame
    long_objects: int = 0
    #: (gaps, stride, threshold) the long-range correspondences were computed with; None: off
    long_settings: tuple[tuple[int, ...], int, float] | None = None

    @property
    def shape(self) -> tuple[int, int, int]:
        t, h, w, _ = self.frames.shape
        return t, h, w


def mask_core(mask: np.ndarray, margin_px: float) -> np.ndarray:
    """bool [H, W]: the pixels of a (non-empty) mask farther than ``margin_px`` from its boundary, or than
    CORE_FRACTION of the object's thickness when that is less."""
    inside = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
    return np.asarray(inside > min(margin_px, CORE_FRACTION * float(inside.max())))


def far_outside(mask: np.ndarray, margin_px: float) -> np.ndarray:
    """bool [H, W]: the pixels farther than ``margin_px`` from every pixel of ``mask``."""
    return np.asarray(cv2.distanceTransform(1 - mask.astype(np.uint8), cv2.DIST_L2, 5) > margin_px)


def mask_prior(masks: np.ndarray, margin_px: float) -> np.ndarray:
    """Trimap from coarse masks: trust only pixels farther than ``margin_px`` from the mask boundary
    (inside: the ``mask_core``, so small objects keep one)."""
    out = np.full(masks.shape, PRIOR_IGNORE, dtype=np.int8)
    for f in range(masks.shape[0]):
        for t in range(masks.shape[1]):
            m = masks[f, t]
            if not m.any():
                continue
            out[f, t][mask_core(m, margin_px)] = 1
            out[f, t][far_outside(m, margin_px)] = 0
    return out


def prior_coverage(masks: np.ndarray, prior: np.ndarray) -> list[float | None]:
    """Per mask layer, the share of its mask pixels that the prior holds as inside (``mask_prior``), over every
    frame; None for a layer without a mask pixel (nothing to hold)."""
    out: list[float | None] = []
    for f in range(masks.shape[0]):
        area = int(np.count_nonzero(masks[f]))
        out.append(float(np.count_nonzero(prior[f] == 1)) / area if area else None)
    return out


def mask_hold_layers(coverage: Sequence[float | None], hold_below: float) -> np.ndarray:
    """bool [F]: the layers whose prior holds less than ``hold_below`` of their mask (0: none is held)."""
    return np.array([c is not None and c < hold_below for c in coverage], dtype=bool)


def build_video_tensors(
    frames: np.ndarray,
    masks: np.ndarray,
    flow: FlowField,
    margin_px: float,
    device: torch.device,
    scribbles: np.ndarray | None = None,
    mask_layers: tuple[tuple[int, ...], ...] | None = None,
    long_flow: LongFlow | None = None,
) -> VideoTensors:
    """The clip's tensors on ``device``; ``long_flow``: its long-range correspondences (None: off)."""
    t = frames.shape[0]
    fl = masks.shape[0]
    valid = masks.reshape(fl, t, -1).any(-1) if fl else np.zeros((0, t), dtype=bool)

    def dev(a: np.ndarray) -> torch.Tensor:
        # on the CPU the tensor shares the prepared array's memory: no second copy of a long clip
        return torch.from_numpy(np.ascontiguousarray(a)).to(device)

    prior = mask_prior(masks, margin_px)
    region = object_region(prior, valid)
    video = VideoTensors(
        frames=dev(np.asarray(frames, dtype=np.float32)),
        masks=dev(masks),
        mask_valid=dev(valid),
        prior=dev(prior),
        fwd=dev(np.asarray(flow.forward, dtype=np.float32)),
        bwd=dev(np.asarray(flow.backward, dtype=np.float32)),
        fwd_ok=dev(flow.forward_ok),
        bwd_ok=dev(flow.backward_ok),
        mask_layers=mask_layers,
        scribble_xyt=None if scribbles is None else dev(np.argwhere(scribbles >= 0)[:, ::-1].astype(np.int64)),
        scribble_label=None if scribbles is None else dev(scribbles[scribbles >= 0].astype(np.int64)),
        object_region=dev(region),
        prior_coverage=tuple(prior_coverage(masks, prior)),
    )
    if long_flow is not None:
        # objects first: a boolean over the clip's pixels says which sources lie in the region
        inside = np.zeros(int(np.prod(frames.shape[:3])), dtype=bool)
        inside[region] = True
        on_object = inside[long_flow.src]
        del inside
        order = np.concatenate((np.flatnonzero(on_object), np.flatnonzero(~on_object)))
        video.long_src = dev(long_flow.src[order])
        video.long_dst = dev(long_flow.dst_xy[order])
        video.long_dst_t = dev(long_flow.dst_t[order])
        video.long_objects = int(on_object.sum())
        video.long_settings = (long_flow.gaps, long_flow.stride, long_flow.threshold_px)
    return video


def object_region(prior: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Flat pixel indices (ascending; int32 unless the clip has 2**31 pixels) of the objects and the band
    around them: wherever some layer's prior (``mask_prior``) is not "far outside", in frames where that
    layer has a mask. Frames without a mask have no prior at all (every pixel "ignore") and add nothing."""
    region = ((prior != 0) & np.asarray(valid, dtype=bool)[:, :, None, None]).any(axis=0)
    index_type = np.int32 if region.size <= np.iinfo(np.int32).max else np.int64  # half the memory when it fits
    return np.flatnonzero(region).astype(index_type)


def frame_pixels(size: tuple[int, int], t: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """Every pixel centre of frame ``t`` (row-major) as continuous coordinates, and the frame index."""
    w, h = size
    ys, xs = torch.meshgrid(torch.arange(h, device=device), torch.arange(w, device=device), indexing="ij")
    xy = torch.stack((xs.reshape(-1), ys.reshape(-1)), -1).float() + 0.5
    return xy, torch.full((xy.shape[0],), t, dtype=torch.long, device=device)


def sample_pixels(
    shape: tuple[int, int, int], n: int, gen: torch.Generator, device: torch.device
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``n`` random pixels; frames are drawn from a shuffled cycle so every frame gets its share each step."""
    t_count, h, w = shape
    reps = -(-n // t_count)
    t = torch.randperm(t_count, generator=gen).repeat(reps)[:n]
    t = t[torch.randperm(n, generator=gen)]
    x = torch.randint(0, w, (n,), generator=gen)
    y = torch.randint(0, h, (n,), generator=gen)
    return x.to(device), y.to(device), t.to(device)


def sample_batch(
    video: VideoTensors, n: int, share: float, gen: torch.Generator, device: torch.device
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A training batch: ``round(share * n)`` pixels drawn from the objects' region (``object_region``), the
    rest uniform (``sample_pixels``). Why: a uniform batch of 4000 gives an object covering 2.5% of the frame
    ~100 pixels a step, too few for its mapping to follow a deforming dog or rider. ``share`` 0, or a clip
    without masks, gives exactly ``sample_pixels`` (the same draws)."""
    region = video.object_region
    k = min(max(round(float(share) * n), 0), n)
    if k == 0 or region is None or region.numel() == 0:
        return sample_pixels(video.shape, n, gen, device)
    ux, uy, ut = sample_pixels(video.shape, n - k, gen, device)
    pick = region[torch.randint(0, region.numel(), (k,), generator=gen).to(region.device)].long()
    _, h, w = video.shape
    rt, rem = pick // (h * w), pick % (h * w)
    return (
        torch.cat((ux, (rem % w).to(device))),
        torch.cat((uy, (rem // w).to(device))),
        torch.cat((ut, rt.to(device))),
    )


def sample_long_flow(video: VideoTensors, n: int, share: float, gen: torch.Generator) -> torch.Tensor:
    """Indices of ``n`` long-range correspondences (``video.long_src``; on ``gen``'s device): ``round(share * n)``
    of them with their source in the objects' region, the rest uniform over all (as ``sample_batch``: a uniform
    draw gives a small object almost none, and its mapping is the one that drifts). None there: all uniform."""
    assert video.long_src is not None, "the clip has no long-range correspondences"
    total = int(video.long_src.shape[0])
    k = min(max(round(float(share) * n), 0), n) if video.long_objects else 0
    uniform = torch.randint(0, total, (n - k,), generator=gen, device=gen.device)
    if k == 0:
        return uniform
    on_objects = torch.randint(0, video.long_objects, (k,), generator=gen, device=gen.device)
    return torch.cat((uniform, on_objects))
