"""The training batch sampler: uniform by default, a fixed share from the objects' region when asked."""

from __future__ import annotations

import numpy as np
import torch

from engine.data.flow import FlowField
from engine.data.video import build_video_tensors, mask_prior, object_region, sample_batch, sample_pixels

CPU = torch.device("cpu")


def _video(masks: np.ndarray, margin: float = 2.0):
    _, t, h, w = masks.shape
    frames = np.zeros((t, h, w, 3), np.float32)
    zeros = np.zeros((max(t - 1, 0), h, w, 2), np.float32)
    ok = np.ones((max(t - 1, 0), h, w), bool)
    return build_video_tensors(frames, masks, FlowField(zeros, zeros, ok, ok, "none", 1.0), margin, CPU)


def _square_masks(t: int = 4, h: int = 40, w: int = 60) -> np.ndarray:
    masks = np.zeros((1, t, h, w), bool)
    masks[0, :, 10:20, 30:40] = True  # 100 of 2400 pixels a frame
    return masks


def test_region_is_the_masks_grown_by_the_prior_margin():
    masks = _square_masks()
    video = _video(masks, margin=2.0)
    region = video.object_region.numpy()
    grown = np.zeros(masks.shape[1:], bool)
    grown.reshape(-1)[region] = True
    assert grown[masks[0]].all()  # every masked pixel
    assert grown[:, 9:21, 29:41].all() and grown[:, 8, 35].all() and grown[:, 15, 28].all()  # the ignored band
    assert not grown[:, :5].any() and not grown[:, :, :25].any()  # far outside: never
    assert 4 * 100 < region.size < 4 * 20 * 20


def test_frames_without_a_mask_add_nothing_to_the_region():
    masks = _square_masks()
    masks[0, 2] = False  # frame 2 has no mask: its prior is "ignore" everywhere, not "object"
    prior = mask_prior(masks, 2.0)
    valid = masks.reshape(1, 4, -1).any(-1)
    region = object_region(prior, valid)
    frames = region // (40 * 60)
    assert set(frames.tolist()) == {0, 1, 3}


def test_share_of_the_batch_lands_on_the_objects():
    video = _video(_square_masks())
    gen = torch.Generator().manual_seed(0)
    x, y, t = sample_batch(video, 4000, 0.25, gen, CPU)
    assert x.shape == y.shape == t.shape == (4000,)
    assert int(x.min()) >= 0 and int(x.max()) < 60 and int(y.max()) < 40 and int(t.max()) < 4
    on = ((x >= 28) & (x < 42) & (y >= 8) & (y < 22)).float().mean().item()
    # 25% drawn from the region plus the uniform 75%'s chance (14*14/2400) of landing there
    assert abs(on - (0.25 + 0.75 * 196 / 2400)) < 0.03
    # the region's pixels come from every masked frame
    assert set(t[-1000:].tolist()) == {0, 1, 2, 3}


def test_zero_share_or_no_masks_is_the_uniform_sampler_draw_for_draw():
    video = _video(_square_masks())
    a = sample_batch(video, 500, 0.0, torch.Generator().manual_seed(3), CPU)
    b = sample_pixels(video.shape, 500, torch.Generator().manual_seed(3), CPU)
    assert all(torch.equal(u, v) for u, v in zip(a, b, strict=True))
    empty = _video(np.zeros((1, 4, 40, 60), bool))
    assert empty.object_region.numel() == 0
    c = sample_batch(empty, 500, 0.5, torch.Generator().manual_seed(3), CPU)
    assert all(torch.equal(u, v) for u, v in zip(c, b, strict=True))
    background_only = _video(np.zeros((0, 4, 40, 60), bool))
    d = sample_batch(background_only, 500, 1.0, torch.Generator().manual_seed(3), CPU)
    assert all(torch.equal(u, v) for u, v in zip(d, b, strict=True))


def test_share_is_clamped_to_the_batch():
    video = _video(_square_masks())
    x, y, _ = sample_batch(video, 100, 1.7, torch.Generator().manual_seed(1), CPU)
    assert x.shape == (100,)
    assert ((x >= 28) & (x < 42) & (y >= 8) & (y < 22)).all()
    x, _, _ = sample_batch(video, 100, -0.5, torch.Generator().manual_seed(1), CPU)
    assert x.shape == (100,)
