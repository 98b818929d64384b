"""Long-range correspondences: accuracy against a synthetic pan's known motion, occlusion and frame-edge rejection,
the chained start DIS needs for large displacements, the on-disk cache, and the per-step sampler."""

from __future__ import annotations

import functools
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from engine.data.flow import DISFlow, FlowField, compute_flow
from engine.data.long_flow import (
    LONG_FLOW_CACHE_VERSION,
    LongFlow,
    chain,
    compute_long_flow,
    long_content_key,
    long_flow_gaps,
    long_flow_pairs,
)
from engine.data.synthetic import SceneSpec, SyntheticScene, make_scene
from engine.data.video import build_video_tensors, sample_long_flow

CPU = torch.device("cpu")
#: A pan of 3 px a frame with an object moving across it (192x108, 9 frames): gaps 2 and 4 are 6 and 12 px.
PAN = SceneSpec(frames=9, bg_velocity=(3.0, 1.0), fg_velocity=(4.0, 1.0))
#: A fast pan on a small frame: 56 px over 8 frames, beyond what DIS finds from zero at 256x160.
FAST_PAN = SceneSpec(width=256, height=160, frames=9, bg_velocity=(7.0, 1.0), fg_velocity=(3.0, 1.0))


class CountingDIS:
    """DIS that counts its calls (to prove the cache is used)."""

    def __init__(self, preset: str = "medium") -> None:
        self.dis = DISFlow(preset)
        self.name = self.dis.name
        self.calls = 0

    def __call__(self, a: np.ndarray, b: np.ndarray, init: np.ndarray | None = None) -> np.ndarray:
        self.calls += 1
        return self.dis(a, b, init)


@functools.cache
def _scene(spec: SceneSpec) -> SyntheticScene:
    return make_scene(spec)


@functools.cache
def _adjacent(spec: SceneSpec) -> FlowField:
    return compute_flow(_scene(spec).frames, DISFlow("medium"))


@functools.cache
def _long(spec: SceneSpec, gaps: tuple[int, ...]) -> LongFlow:
    return compute_long_flow(_scene(spec).frames, _adjacent(spec), gaps, DISFlow("medium"), stride=2)


def _truth(scene: SyntheticScene, lf: LongFlow) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(source frame, target frame, true target [N, 2], source on the object) of every correspondence."""
    _, h, w = scene.frames.shape[:3]
    src = lf.src.astype(np.int64)
    t, y, x = src // (h * w), (src // w) % h, src % w
    tt = lf.dst_t.astype(np.int64)
    fg = scene.masks[t, y, x]
    true = np.stack(
        (x + scene.bg_offset[t, 0] - scene.bg_offset[tt, 0], y + scene.bg_offset[t, 1] - scene.bg_offset[tt, 1]), -1
    )
    true[fg] = np.stack(
        (
            x[fg] - scene.fg_offset[t[fg], 0] + scene.fg_offset[tt[fg], 0],
            y[fg] - scene.fg_offset[t[fg], 1] + scene.fg_offset[tt[fg], 1],
        ),
        -1,
    )
    return t, tt, true, fg


# --- gaps ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("max_gap", "frames", "gaps"),
    [(0, 50, ()), (1, 50, ()), (2, 50, (2,)), (6, 50, (2, 4)), (8, 50, (2, 4, 8)), (8, 5, (2, 4)), (8, 2, ())],
)
def test_gaps_are_the_powers_of_two_the_clip_has_pairs_for(max_gap: int, frames: int, gaps: tuple[int, ...]) -> None:
    assert long_flow_gaps(max_gap, frames) == gaps


def test_pairs_count_each_gap_once() -> None:
    assert long_flow_pairs((2, 4, 8), 9) == 7 + 5 + 1
    assert long_flow_pairs((), 9) == 0


def test_chain_of_two_uniform_flows_adds_them() -> None:
    a = np.zeros((20, 30, 2), np.float32)
    a[..., 0], a[..., 1] = 2.0, -1.0
    b = np.zeros_like(a)
    b[..., 0], b[..., 1] = 0.5, 3.0
    np.testing.assert_allclose(chain(a, b), np.broadcast_to([2.5, 2.0], a.shape), atol=1e-6)


# --- accuracy -----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("gap", [2, 4])
def test_correspondences_land_on_the_true_positions(gap: int) -> None:
    scene, lf = _scene(PAN), _long(PAN, (2, 4))
    t, tt, true, fg = _truth(scene, lf)
    sel = np.abs(tt - t) == gap
    err = np.linalg.norm(lf.dst_xy[sel] - true[sel], axis=1)
    # both directions, every frame pair of the gap, on the object and off it
    assert sel.sum() > 0.6 * 2 * (PAN.frames - gap) * (PAN.width // 2) * (PAN.height // 2)
    assert ((tt - t)[sel] > 0).any() and ((tt - t)[sel] < 0).any() and fg[sel].sum() > 1000
    assert np.median(err) < 0.3
    assert np.mean(err > 2.0) < 0.01
    assert np.median(err[fg[sel]]) < 0.3


def test_occluded_and_out_of_frame_points_are_rejected() -> None:
    scene, lf = _scene(PAN), _long(PAN, (2, 4))
    h, w = PAN.height, PAN.width
    _, tt, true, _ = _truth(scene, lf)
    # nothing kept whose true target is more than a pixel outside the frame
    outside = (true[:, 0] < -1) | (true[:, 0] > w) | (true[:, 1] < -1) | (true[:, 1] > h)
    assert not outside.any()
    # background points (clear of the object's anti-aliased rim, which moves with it) that the object covers in
    # the target frame (2 px inside its mask): almost none kept, out of many candidates
    kernel = np.ones((5, 5), np.uint8)
    core = np.stack([cv2.erode(m.astype(np.uint8), kernel) > 0 for m in scene.masks])
    clear = np.stack([cv2.distanceTransform(1 - m.astype(np.uint8), cv2.DIST_L2, 5) > 3 for m in scene.masks])
    src = lf.src.astype(np.int64)
    t, y, x = src // (h * w), (src // w) % h, src % w
    ti = np.clip(np.rint(true).astype(int), 0, [w - 1, h - 1])
    kept_hidden = int((clear[t, y, x] & core[tt, ti[:, 1], ti[:, 0]]).sum())
    ys, xs = np.mgrid[0:h:2, 0:w:2]
    candidates = out_candidates = 0
    for k in (2, 4):
        for a in range(PAN.frames - k):
            for s, b in ((a, a + k), (a + k, a)):  # both directions
                tx = xs + scene.bg_offset[s, 0] - scene.bg_offset[b, 0]
                ty = ys + scene.bg_offset[s, 1] - scene.bg_offset[b, 1]
                inside = (tx >= 0) & (tx <= w - 1) & (ty >= 0) & (ty <= h - 1)
                txi, tyi = np.clip(np.rint(tx).astype(int), 0, w - 1), np.clip(np.rint(ty).astype(int), 0, h - 1)
                candidates += int((clear[s, ys, xs] & inside & core[b, tyi, txi]).sum())
                out_candidates += int((~inside).sum())
    assert candidates > 1000 and out_candidates > 4000
    assert kept_hidden < 0.01 * candidates, (kept_hidden, candidates)


def test_chained_start_finds_a_displacement_dis_alone_misses() -> None:
    scene = _scene(FAST_PAN)
    background = ~scene.masks[0]
    truth = scene.bg_offset[0] - scene.bg_offset[8]  # (-56, -8)
    plain = DISFlow("medium")(scene.frames[0], scene.frames[8])
    plain_err = float(np.median(np.linalg.norm(plain[background] - truth, axis=1)))
    lf = _long(FAST_PAN, (2, 4, 8))
    t, tt, true, fg = _truth(scene, lf)
    sel = (t == 0) & (tt == 8) & ~fg
    assert sel.sum() > 2000
    ours = float(np.median(np.linalg.norm(lf.dst_xy[sel] - true[sel], axis=1)))
    assert plain_err > 5.0 and ours < 1.0, (plain_err, ours)


# --- cache --------------------------------------------------------------------------------------------------


def _tiny() -> tuple[np.ndarray, FlowField]:
    spec = SceneSpec(width=64, height=40, frames=5, bg_velocity=(1.0, 0.5), fg_size=(16, 12), fg_start=(20.0, 10.0))
    frames = make_scene(spec).frames
    return frames, compute_flow(frames, DISFlow("ultrafast"))


def test_cache_hit_reads_instead_of_computing(tmp_path: Path) -> None:
    frames, adj = _tiny()
    backend = CountingDIS("ultrafast")
    progress: list[tuple[int, int]] = []
    first = compute_long_flow(frames, adj, (2, 4), backend, tmp_path, progress=lambda d, n: progress.append((d, n)))
    assert backend.calls == 2 * long_flow_pairs((2, 4), 5) == 8
    assert progress == [(1, 4), (2, 4), (3, 4), (4, 4)]
    name = f"long-{long_content_key(frames, adj, (2, 4), backend, 2)}.npz"
    assert [p.name for p in tmp_path.iterdir()] == [name]
    progress.clear()
    second = compute_long_flow(frames, adj, (2, 4), backend, tmp_path, progress=lambda d, n: progress.append((d, n)))
    assert backend.calls == 8 and progress == [(4, 4)]
    for field in ("src", "dst_xy", "dst_t"):
        assert getattr(first, field).tobytes() == getattr(second, field).tobytes()
        assert getattr(first, field).dtype == getattr(second, field).dtype
    assert (second.gaps, second.stride, second.backend, second.threshold_px) == ((2, 4), 2, "dis-ultrafast", 1.0)
    assert first.count > 0 and first.src.dtype == np.int32 and first.dst_t.dtype == np.int16
    # other settings: other files
    compute_long_flow(frames, adj, (2, 4), backend, tmp_path, stride=3)
    compute_long_flow(frames, adj, (2,), backend, tmp_path)
    assert backend.calls == 8 + 8 + 6 and len(list(tmp_path.iterdir())) == 3


@pytest.mark.parametrize("garbage", [b"", b"not a zip file", b"PK\x03\x04truncated", "foreign"])
def test_corrupt_or_foreign_cache_is_a_miss(tmp_path: Path, garbage: bytes | str) -> None:
    frames, adj = _tiny()
    backend = CountingDIS("ultrafast")
    path = tmp_path / f"long-{long_content_key(frames, adj, (2,), backend, 2)}.npz"
    if garbage == "foreign":  # this key's settings, but a source beyond this clip's pixels
        np.savez(
            path,
            src=np.array([10**9], np.int32),
            dst_xy=np.zeros((1, 2), np.float32),
            dst_t=np.zeros(1, np.int16),
            gaps=np.array([2]),
            stride=np.array(2),
            backend=np.array(backend.name),
            threshold_px=np.array(1.0),
            version=np.array(LONG_FLOW_CACHE_VERSION),
        )
    else:
        path.write_bytes(garbage)
    lf = compute_long_flow(frames, adj, (2,), backend, tmp_path)
    assert backend.calls == 6 and lf.count > 0
    compute_long_flow(frames, adj, (2,), backend, tmp_path)  # overwritten with a good file
    assert backend.calls == 6


# --- tensors and sampler ------------------------------------------------------------------------------------


def test_sampler_draws_the_configured_share_from_the_objects() -> None:
    scene, lf = _scene(PAN), _long(PAN, (2, 4))
    masks = scene.masks[None]
    adj = _adjacent(PAN)
    video = build_video_tensors(scene.frames, masks, adj, 4.0, CPU, long_flow=lf)
    assert video.long_src is not None and video.long_dst is not None and video.long_dst_t is not None
    assert video.long_settings == ((2, 4), 2, 1.0) and video.long_src.shape[0] == lf.count
    region = np.zeros(scene.frames.shape[:3], bool).reshape(-1)
    region[video.object_region.numpy()] = True
    src = video.long_src.numpy()
    on = region[src]
    # objects first, and exactly the correspondences whose source is in the region
    assert on[: video.long_objects].all() and not on[video.long_objects :].any()
    base = on.mean()
    assert 0.02 < base < 0.3
    n = 20000
    for share in (0.0, 0.25, 0.5):
        pick = sample_long_flow(video, n, share, torch.Generator().manual_seed(3)).numpy()
        assert pick.shape == (n,)
        k = round(share * n)
        assert (pick[n - k :] < video.long_objects).all()
        got = on[pick].mean()
        assert got == pytest.approx(share + (1 - share) * base, abs=0.01), share
    again = sample_long_flow(video, n, 0.25, torch.Generator().manual_seed(3))
    assert torch.equal(again, sample_long_flow(video, n, 0.25, torch.Generator().manual_seed(3)))
    # reordered, each target stays with its source: (source, target frame) is unique
    mine = np.lexsort((video.long_dst_t.numpy(), src))
    ref = np.lexsort((lf.dst_t, lf.src))
    np.testing.assert_array_equal(src[mine], lf.src[ref])
    np.testing.assert_array_equal(video.long_dst.numpy()[mine], lf.dst_xy[ref])
