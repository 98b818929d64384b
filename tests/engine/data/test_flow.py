"""Optical flow preprocessing: DIS accuracy, consistency masks, resizing and the on-disk cache."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from engine.data.flow import (
    DIS_PRESETS,
    DISFlow,
    FlowBackend,
    FlowField,
    cached_flow,
    compute_flow,
    consistency_mask,
    content_key,
    resize_flow,
    sample_points,
)
from engine.data.synthetic import SceneSpec, make_scene

H, W = 64, 96


def _texture(h: int, w: int, seed: int = 0, blur: float = 1.5) -> np.ndarray:
    """Random texture, blurred so DIS has gradients everywhere but nothing aliases."""
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.random((h, w, 3)).astype(np.float32), (0, 0), blur)
    return ((img - img.min()) / (img.max() - img.min())).astype(np.float32)


def _shifted_pair(dx: int, dy: int) -> tuple[np.ndarray, np.ndarray]:
    """Two crops of one texture such that pixel (x, y) of a is pixel (x + dx, y + dy) of b."""
    pad = 8
    big = _texture(H + 2 * pad, W + 2 * pad)
    a = big[pad : pad + H, pad : pad + W]
    b = big[pad - dy : pad - dy + H, pad - dx : pad - dx + W]
    return np.ascontiguousarray(a), np.ascontiguousarray(b)


def _uniform(dx: float, dy: float, h: int = H, w: int = W) -> np.ndarray:
    f = np.empty((h, w, 2), dtype=np.float32)
    f[..., 0], f[..., 1] = dx, dy
    return f


class CountingBackend:
    """A fake backend: zero flow, counts its calls (to prove the cache is used)."""

    def __init__(self, name: str = "fake") -> None:
        self.name = name
        self.calls = 0

    def __call__(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        self.calls += 1
        return np.zeros((*a.shape[:2], 2), dtype=np.float32)


def _clip(t: int = 3, seed: int = 0) -> np.ndarray:
    return np.stack([_texture(32, 48, seed + i) for i in range(t)])


# --- DIS ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("preset", DIS_PRESETS)
def test_dis_recovers_translation(preset: str) -> None:
    a, b = _shifted_pair(3, -2)
    flow = DISFlow(preset)(a, b)
    assert flow.shape == (H, W, 2) and flow.dtype == np.float32
    interior = flow[10:-10, 10:-10]
    err = np.hypot(interior[..., 0] - 3.0, interior[..., 1] + 2.0)
    assert np.median(err) < 0.3


def test_fine_follows_a_turning_growing_plate_closer_than_medium() -> None:
    """``fine`` refines DIS down to full resolution where ``medium`` stops at half: on a plate turning by 3 degrees
    and growing by 3% (every pixel moves by a different sub-pixel amount) it halves the error. The paint follows the
    export's flow point by point, so this error, chained over a clip's frames, is the paint's."""
    h, w = 96, 128
    big = _texture(2 * h, 2 * w, blur=1.0)  # detail finer than half resolution holds
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    centre, angle = np.array([w / 2, h / 2], np.float32), np.deg2rad(3.0)
    turn = 1.03 * np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]], np.float32)
    pixels = np.stack([gx, gy], -1) - centre
    truth = pixels @ turn.T - pixels  # pixel x of a is at turn (x - c) + c in b
    src = pixels @ np.linalg.inv(turn).T + centre + np.array([w // 2, h // 2], np.float32)
    a = np.ascontiguousarray(big[h // 2 : h // 2 + h, w // 2 : w // 2 + w])
    b = cv2.remap(big, src[..., 0].astype(np.float32), src[..., 1].astype(np.float32), cv2.INTER_CUBIC)
    errors = {}
    for preset in ("medium", "fine"):
        err = np.linalg.norm(DISFlow(preset)(a, b) - truth, axis=-1)[16:-16, 16:-16]
        errors[preset] = float(np.median(err))
    assert errors["fine"] < 0.6 * errors["medium"] and errors["fine"] < 0.08, errors


def test_dis_names_and_presets() -> None:
    assert DISFlow().name == "dis-medium"
    assert DISFlow("ultrafast").name == "dis-ultrafast"
    assert DISFlow("fine").name == "dis-fine"  # its own cache key: never taken for medium's flow
    assert isinstance(DISFlow(), FlowBackend)
    assert isinstance(CountingBackend(), FlowBackend)  # a RAFT-like backend just needs name + __call__
    with pytest.raises(ValueError, match="preset"):
        DISFlow("slow")


def test_dis_tiny_and_thin_frames() -> None:
    # OpenCV's DIS rejects < 12 px and crashes on thin frames such as 20x300; we pad internally.
    for h, w in ((1, 1), (8, 8), (20, 300), (300, 20)):
        img = _texture(h + 4, w + 4)[:h, :w]
        assert DISFlow("ultrafast")(img, img).shape == (h, w, 2)


# --- consistency ------------------------------------------------------------------------------------------


def test_consistency_interior_true_and_out_of_frame_false() -> None:
    ok = consistency_mask(_uniform(3.0, -2.0), _uniform(-3.0, 2.0), 1.0)
    assert ok.shape == (H, W) and ok.dtype == bool
    assert ok[2:, : W - 3].all()  # target inside the frame
    assert not ok[:, W - 3 :].any()  # x + 3 > W - 1: leaves the frame on the right
    assert not ok[:2].any()  # y - 2 < 0: leaves at the top


def test_consistency_rejects_round_trip_error_and_nan() -> None:
    fwd, bwd = _uniform(1.0, 0.0), _uniform(-1.0, 0.0)
    assert consistency_mask(fwd, bwd + 0.6, 1.0)[10:-10, 10:-10].all()  # error 0.85 < 1
    assert not consistency_mask(fwd, bwd + 0.8, 1.0).any()  # error 1.13 > 1
    fwd[5, 5] = np.nan
    bwd[20, 20] = np.inf
    ok = consistency_mask(fwd, bwd, 1.0)
    assert not ok[5, 5] and not ok[20, 19] and ok[30, 30]
    batch = consistency_mask(np.stack([fwd, fwd]), np.stack([bwd, bwd]), 1.0)
    assert batch.shape == (2, H, W) and (batch == ok).all()


def test_consistency_samples_bilinearly() -> None:
    # fwd moves half a pixel right onto the midpoint of two bwd pixels of -2.5 and 1.5: only their
    # average (-0.5) closes the round trip; nearest-neighbour sampling would see an error of 2.
    fwd = _uniform(0.5, 0.0)
    bwd = _uniform(0.0, 0.0)
    bwd[..., 0] = np.where(np.arange(W) % 2 == 0, -2.5, 1.5)
    ok = consistency_mask(fwd, bwd, 0.1)
    assert ok[:, : W - 1].all() and not ok[:, W - 1].any()


def test_occlusion_is_inconsistent() -> None:
    """A square slides right over a static background: the background it covers has no valid flow."""
    bg = _texture(H, W, seed=1)
    sq = _texture(20, 20, seed=2)[..., ::-1] * 0.5 + 0.5
    a, b = bg.copy(), bg.copy()
    a[20:40, 30:50] = sq
    b[20:40, 36:56] = sq  # moved by +6 px
    fwd, bwd = DISFlow("medium")(a, b), DISFlow("medium")(b, a)
    ok = consistency_mask(fwd, bwd, 1.0)
    covered = np.zeros((H, W), dtype=bool)
    covered[22:38, 51:55] = True  # background of a that is under the square in b (away from edges)
    assert ok[covered].mean() < 0.5
    static = np.zeros((H, W), dtype=bool)
    static[5:15, 5:90] = True  # background far from the square
    assert ok[static].mean() > 0.9


def test_occlusion_with_exact_flow() -> None:
    """The mask logic alone, on exact flows: a 20 px square at x 30..49 moves +6 over a static background."""
    fwd, bwd = _uniform(0.0, 0.0), _uniform(0.0, 0.0)
    fwd[20:40, 30:50, 0] = 6.0  # the square in a
    bwd[20:40, 36:56, 0] = -6.0  # the square in b
    ok = consistency_mask(fwd, bwd, 1.0)
    assert not ok[20:40, 50:56].any()  # background that the square covers in b
    assert ok[20:40, 30:50].all() and ok[:20].all() and ok[40:].all() and ok[:, 56:].all()
    back_ok = consistency_mask(bwd, fwd, 1.0)
    assert not back_ok[20:40, 30:36].any()  # background that the square uncovers has no match in a
    assert back_ok[20:40, 36:56].all()


def test_flow_of_synthetic_scene() -> None:
    """End to end on a synthetic plate: consistent flow matches the ground truth."""
    scene = make_scene(SceneSpec(width=128, height=80, frames=2, fg_start=(30.0, 20.0), fg_size=(36, 28)))
    field = compute_flow(scene.frames, DISFlow("medium"))
    err = np.hypot(*(field.forward[0] - scene.true_flow(0)).transpose(2, 0, 1))
    ok = field.forward_ok[0]
    assert ok.mean() > 0.8
    assert np.median(err[ok & ~scene.masks[0]]) < 0.2
    assert np.median(err[ok & scene.masks[0]]) < 0.5


# --- resize -----------------------------------------------------------------------------------------------


def test_resize_flow_scales_each_axis() -> None:
    flow = _uniform(3.0, -2.0)
    out = resize_flow(flow, (2 * W, H // 2))  # W x2, H x0.5
    assert out.shape == (H // 2, 2 * W, 2) and out.dtype == np.float32
    np.testing.assert_allclose(out[..., 0], 6.0, atol=1e-5)
    np.testing.assert_allclose(out[..., 1], -1.0, atol=1e-5)
    down = resize_flow(np.stack([flow, flow]), (W // 2, H // 4))  # batch, shrink both
    assert down.shape == (2, H // 4, W // 2, 2)
    np.testing.assert_allclose(down[..., 0], 1.5, atol=1e-5)
    np.testing.assert_allclose(down[..., 1], -0.5, atol=1e-5)


def test_resize_flow_matches_flow_of_resized_frames() -> None:
    """Flow on the resized pair, and the resized flow of the original pair, agree (non-uniform aspect)."""
    a, b = _shifted_pair(4, -2)
    size = (W // 2, H)  # W x0.5, H x1 -> (2, -2)
    ra, rb = (cv2.resize(im, size, interpolation=cv2.INTER_AREA) for im in (a, b))
    direct = DISFlow("medium")(ra, rb)[8:-8, 8:-8]
    resized = resize_flow(DISFlow("medium")(a, b), size)[8:-8, 8:-8]
    assert np.median(np.abs(direct - resized)) < 0.3
    assert np.median(np.abs(resized[..., 0] - 2.0)) < 0.3 and np.median(np.abs(resized[..., 1] + 2.0)) < 0.3


# --- compute_flow and its cache -----------------------------------------------------------------------------


def test_compute_flow_shapes_and_progress() -> None:
    a, b = _shifted_pair(3, -2)
    frames = np.stack([a, b, a])
    calls: list[tuple[int, int]] = []
    field = compute_flow(frames, DISFlow("ultrafast"), progress=lambda d, n: calls.append((d, n)))
    assert isinstance(field, FlowField)
    assert field.forward.shape == field.backward.shape == (2, H, W, 2)
    assert field.forward_ok.shape == field.backward_ok.shape == (2, H, W)
    assert field.forward.dtype == np.float32 and field.forward_ok.dtype == bool
    assert field.backend == "dis-ultrafast" and field.threshold_px == 1.0
    assert calls == [(1, 2), (2, 2)]
    interior = (slice(10, -10), slice(10, -10))
    assert np.median(np.abs(field.forward[0][interior] - (3.0, -2.0))) < 0.3
    assert np.median(np.abs(field.backward[0][interior] - (-3.0, 2.0))) < 0.3
    assert np.median(np.abs(field.forward[1][interior] - (-3.0, 2.0))) < 0.3  # b -> a
    assert field.forward_ok[0][interior].mean() > 0.9
    assert not field.forward_ok[0][:, -2:].any()  # leaves the frame


def test_cache_hit_skips_backend(tmp_path: Path) -> None:
    frames = _clip()
    backend = CountingBackend()
    first = compute_flow(frames, backend, cache_dir=tmp_path)
    assert backend.calls == 4  # 2 pairs x (forward, backward)
    files = list(tmp_path.glob("*.npz"))
    assert [f.name for f in files] == [f"{content_key(frames, backend, 1.0)}.npz"]
    assert not [p for p in tmp_path.iterdir() if p.suffix == ".tmp"]
    progress: list[tuple[int, int]] = []
    second = compute_flow(frames, backend, cache_dir=tmp_path, progress=lambda d, n: progress.append((d, n)))
    assert backend.calls == 4
    assert progress == [(2, 2)]
    for name in ("forward", "backward", "forward_ok", "backward_ok"):
        np.testing.assert_array_equal(getattr(first, name), getattr(second, name))
        assert getattr(first, name).dtype == getattr(second, name).dtype
    assert second.backend == "fake" and second.threshold_px == 1.0


def test_the_flow_is_found_by_its_key_never_by_age(tmp_path: Path) -> None:
    """``cached_flow`` opens the file its key names (the key ``compute_flow`` gives, which the fit records): another
    plate's flow of the same shape written later is never taken; a key that is not a content key (a hand-edited
    clip.json: a path, an empty string) or names no file is a miss."""
    backend = CountingBackend()
    own = compute_flow(_clip(seed=0), backend, cache_dir=tmp_path)
    assert own.key == content_key(_clip(seed=0), backend, 1.0)
    other = compute_flow(_clip(seed=5), backend, cache_dir=tmp_path)  # newer, same shape
    assert other.key != own.key and compute_flow(_clip(seed=0), backend, cache_dir=tmp_path).key == own.key
    found = cached_flow(tmp_path, own.key, 3, 32, 48, "fake", 1.0)
    assert found is not None and found.key == own.key
    np.testing.assert_array_equal(found.forward, own.forward)
    assert cached_flow(tmp_path, own.key, 3, 32, 48, "fake", 0.5) is None  # another threshold
    assert cached_flow(tmp_path, own.key, 4, 32, 48, "fake", 1.0) is None  # another length
    for key in ("", "../" + own.key, own.key.upper(), own.key[:-1], "0" * 64):
        assert cached_flow(tmp_path, key, 3, 32, 48, "fake", 1.0) is None
    assert compute_flow(_clip(seed=0), backend).key is None  # not cached: no key


def test_cache_roundtrip_is_exact(tmp_path: Path) -> None:
    a, b = _shifted_pair(2, 1)
    frames = np.stack([a, b])
    first = compute_flow(frames, DISFlow("ultrafast"), cache_dir=tmp_path)
    second = compute_flow(frames, DISFlow("ultrafast"), cache_dir=tmp_path)
    assert first.forward.tobytes() == second.forward.tobytes()


def test_content_key_changes_with_inputs() -> None:
    frames = _clip()
    fake = CountingBackend()
    key = content_key(frames, fake, 1.0)
    assert len(key) == 64 and key == content_key(frames.copy(), fake, 1.0)
    changed = frames.copy()
    changed[1, 3, 4, 0] += 1e-3
    assert content_key(changed, fake, 1.0) != key
    assert content_key(frames, CountingBackend("other"), 1.0) != key
    assert content_key(frames, fake, 0.5) != key
    assert content_key(frames[:2], fake, 1.0) != key
    assert content_key(frames.reshape(3, 48, 32, 3), fake, 1.0) != key  # same bytes, other shape


def test_different_frames_miss_the_cache(tmp_path: Path) -> None:
    backend = CountingBackend()
    compute_flow(_clip(seed=0), backend, cache_dir=tmp_path)
    compute_flow(_clip(seed=5), backend, cache_dir=tmp_path)
    assert backend.calls == 8
    assert len(list(tmp_path.glob("*.npz"))) == 2


@pytest.mark.parametrize("garbage", [b"", b"not a zip file", b"PK\x03\x04truncated"])
def test_corrupt_cache_is_recomputed(tmp_path: Path, garbage: bytes) -> None:
    frames = _clip()
    backend = CountingBackend()
    path = tmp_path / f"{content_key(frames, backend, 1.0)}.npz"
    path.write_bytes(garbage)
    field = compute_flow(frames, backend, cache_dir=tmp_path)
    assert backend.calls == 4 and field.forward.shape == (2, 32, 48, 2)
    compute_flow(frames, backend, cache_dir=tmp_path)  # overwritten with a good file
    assert backend.calls == 4


def test_cache_with_wrong_content_is_recomputed(tmp_path: Path) -> None:
    frames = _clip()
    backend = CountingBackend()
    path = tmp_path / f"{content_key(frames, backend, 1.0)}.npz"
    np.savez(path, forward=np.zeros((1, 2, 2, 2), np.float32))  # loadable, but not this clip's flow
    compute_flow(frames, backend, cache_dir=tmp_path)
    assert backend.calls == 4


def test_single_frame_gives_empty_arrays(tmp_path: Path) -> None:
    backend = CountingBackend()
    field = compute_flow(_clip(t=1), backend, cache_dir=tmp_path)
    assert backend.calls == 0
    assert field.forward.shape == field.backward.shape == (0, 32, 48, 2)
    assert field.forward_ok.shape == field.backward_ok.shape == (0, 32, 48)
    assert compute_flow(_clip(t=1), backend, cache_dir=tmp_path).forward.shape == (0, 32, 48, 2)


def test_nan_frames_give_finite_flow() -> None:
    frames = _clip()
    frames[0, 5:15, 5:20] = np.nan
    frames[1, :, :10] = np.inf
    frames[2] = np.nan
    field = compute_flow(frames, DISFlow("ultrafast"))
    for arr in (field.forward, field.backward):
        assert np.isfinite(arr).all()


def test_backend_nan_output_is_zeroed_and_masked() -> None:
    class NanBackend:
        name = "nan"

        def __call__(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
            f = np.zeros((*a.shape[:2], 2), dtype=np.float32)
            f[3, 4] = np.nan
            return f

    field = compute_flow(_clip(t=2), NanBackend())
    assert np.isfinite(field.forward).all() and np.isfinite(field.backward).all()
    assert not field.forward_ok[0, 3, 4] and field.forward_ok[0, 10, 10]


def test_bad_inputs() -> None:
    with pytest.raises(ValueError):
        compute_flow(np.zeros((3, 8, 8), np.float32), CountingBackend())
    with pytest.raises(ValueError):
        compute_flow(np.zeros((0, 8, 8, 3), np.float32), CountingBackend())

    class WrongShape(CountingBackend):
        def __call__(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
            return np.zeros((2, 2, 2), np.float32)

    with pytest.raises(ValueError, match="shape"):
        compute_flow(_clip(t=2), WrongShape())


@pytest.mark.parametrize("count", [0, 1, 4095, 4097, 32767, 100_000])
def test_sample_points_takes_any_number_of_points_each_sampled_alone(count: int) -> None:
    """``cv2.remap`` refuses 32767 samples in a row; ``sample_points`` lays them out in rows, and every point's
    value is the bilinear one of its own position, bit for bit what one row of fewer points gives."""
    rng = np.random.default_rng(count)
    field = rng.normal(size=(48, 64, 2)).astype(np.float32)
    pts = rng.uniform(-3.0, 66.0, size=(count, 2))
    got = sample_points(field, pts)
    assert got.shape == (count, 2) and got.dtype == np.float32
    for lo in range(0, count, 30_000):  # the one-row call, where OpenCV takes it
        part = pts[lo : lo + 30_000].astype(np.float32).reshape(-1, 1, 2)
        one_row = cv2.remap(field, part[..., 0], part[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        assert np.array_equal(got[lo : lo + 30_000], one_row.reshape(-1, 2))


def test_sample_points_of_a_one_channel_field_and_at_pixel_centres() -> None:
    field = np.arange(12, dtype=np.float32).reshape(3, 4, 1)
    pts = np.array([[0.0, 0.0], [3.0, 2.0], [1.5, 1.0], [9.0, -4.0]])  # the last beyond the corner: edge value
    assert sample_points(field, pts)[:, 0].tolist() == [0.0, 11.0, 5.5, 3.0]
