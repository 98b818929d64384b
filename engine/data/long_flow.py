"""Long-range correspondences: flow between frames t and t+k (k = 2, 4, 8, ...) where it survives a round trip.

The flow-consistency term of the fit ties each frame's mapping to the next one's only. A small error per pair
then adds up over the clip, and paint applied through the atlas drifts. Correspondences across k frames tie
mappings that are k frames apart directly, so such an error cannot accumulate past k frames.

DIS alone finds displacements up to a few tens of pixels; over k frames an object moves k times as far. Each
gap's flow therefore starts from the half gap's flow chained twice (the adjacent flow for k = 2): DIS refines
that start (``DISFlow``'s ``init``) rather than searching from zero. Only correspondences that pass the
forward-backward check (``consistency_mask``, the fit's threshold) are kept, and of those only the pixels on a
grid of ``stride`` (memory: a 768x432 clip of 50 frames keeps 1.5e7, 200 MiB, at stride 2 with gaps 2..8),
stored as flat source indices and float target positions. Results are cached on disk like the adjacent flow.
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np

from .flow import DISFlow, FlowField, _sanitize, _save_arrays, consistency_mask, foreign_cache, read_cache

log = logging.getLogger(__name__)

#: Bump when the computation or the cache layout changes: old cache files then miss instead of lying.
LONG_FLOW_CACHE_VERSION = 1


class InitFlowBackend(Protocol):
    """A flow backend that can start from a given flow (``DISFlow``); ``name`` goes into the cache key."""

    @property
    def name(self) -> str: ...

    def __call__(self, a: np.ndarray, b: np.ndarray, init: np.ndarray | None = None) -> np.ndarray: ...


@dataclass
class LongFlow:
    """Consistent correspondences between frames ``gaps`` apart, both directions, on a pixel grid of ``stride``.

    Correspondence i maps pixel centre ``src`` (flat index t*H*W + y*W + x, integer coordinates as in
    engine.data.flow) of frame t to the point ``dst_xy[i]`` of frame ``dst_t[i]`` (t + k or t - k).
    """

    src: np.ndarray  # int32 (int64 for clips of 2**31 pixels) [N]
    dst_xy: np.ndarray  # float32 [N, 2]
    dst_t: np.ndarray  # int16 (int32 for clips of 2**15 frames) [N]
    gaps: tuple[int, ...]
    stride: int
    backend: str
    threshold_px: float

    @property
    def count(self) -> int:
        return int(self.src.shape[0])


def long_flow_gaps(max_gap: int, frames: int) -> tuple[int, ...]:
    """The gaps 2, 4, 8, ... up to ``max_gap`` that a clip of ``frames`` frames has a pair for (empty: off)."""
    gaps = []
    k = 2
    while k <= max_gap and k < frames:
        gaps.append(k)
        k *= 2
    return tuple(gaps)


def long_flow_pairs(gaps: tuple[int, ...], frames: int) -> int:
    """Frame pairs (each both ways) ``compute_long_flow`` computes for ``gaps``: the progress total."""
    return sum(max(0, frames - k) for k in gaps)


def chain(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """Flow a -> c from ``first`` (a -> b) and ``second`` (b -> c): ``first(p) + second(p + first(p))``,
    ``second`` sampled bilinearly (edge values beyond the frame)."""
    h, w = first.shape[:2]
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    qx = xs + first[..., 0]
    qy = ys + first[..., 1]
    along = cv2.remap(np.ascontiguousarray(second), qx, qy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return (first + along).astype(np.float32)


def long_content_key(
    frames: np.ndarray, adjacent: FlowField, gaps: tuple[int, ...], backend: InitFlowBackend, stride: int
) -> str:
    """Cache key: the pixels, the adjacent flow's backend and threshold (its start), this backend, the gaps,
    the stride and the code version."""
    arr = np.ascontiguousarray(frames)
    h = hashlib.sha256()
    h.update(f"neural-atlas-long-flow:v{LONG_FLOW_CACHE_VERSION}\n".encode())
    h.update(f"shape={tuple(arr.shape)};dtype={arr.dtype.str}\n".encode())
    h.update(f"adjacent={adjacent.backend};threshold={float(adjacent.threshold_px)!r}\n".encode())
    h.update(f"backend={backend.name};gaps={list(gaps)};stride={int(stride)}\n".encode())
    h.update(arr.data.cast("B"))
    return h.hexdigest()


def _checked(flow: np.ndarray, h: int, w: int, name: str) -> np.ndarray:
    flow = np.asarray(flow)
    if flow.shape != (h, w, 2):
        raise ValueError(f"flow backend {name} returned shape {flow.shape}, expected {(h, w, 2)}")
    return flow.astype(np.float32, copy=False)


def _index_types(t: int, h: int, w: int) -> tuple[type[np.integer], type[np.integer]]:
    src = np.int32 if t * h * w <= np.iinfo(np.int32).max else np.int64
    dst_t = np.int16 if t <= np.iinfo(np.int16).max else np.int32
    return src, dst_t


def _load_long_cache(
    path: Path, t: int, h: int, w: int, gaps: tuple[int, ...], stride: int, backend: str, threshold_px: float
) -> LongFlow | None:
    """A missing, truncated, foreign or out-of-range cache file is a miss, never an error."""

    def read(z: Any) -> tuple[LongFlow, int]:
        lf = LongFlow(
            src=np.asarray(z["src"]),
            dst_xy=np.asarray(z["dst_xy"]),
            dst_t=np.asarray(z["dst_t"]),
            gaps=tuple(int(k) for k in np.asarray(z["gaps"]).reshape(-1)),
            stride=int(z["stride"]),
            backend=str(z["backend"]),
            threshold_px=float(z["threshold_px"]),
        )
        return lf, int(z["version"])

    found = read_cache(path, "long-range flow cache", read)
    if found is None:
        return None
    lf, version = found
    src_type, t_type = _index_types(t, h, w)
    n = lf.src.shape[0] if lf.src.ndim == 1 else -1
    good = (
        version == LONG_FLOW_CACHE_VERSION
        and (lf.gaps, lf.stride, lf.backend, lf.threshold_px) == (gaps, stride, backend, float(threshold_px))
        and n >= 0
        and lf.src.dtype == src_type
        and lf.dst_t.dtype == t_type
        and lf.dst_xy.dtype == np.float32
        and lf.dst_xy.shape == (n, 2)
        and lf.dst_t.shape == (n,)
        and (n == 0 or (int(lf.src.min()) >= 0 and int(lf.src.max()) < t * h * w))
        and (n == 0 or (int(lf.dst_t.min()) >= 0 and int(lf.dst_t.max()) < t))
        and bool(np.isfinite(lf.dst_xy).all())
    )
    if not good:
        foreign_cache(path, "long-range flow cache")
        return None
    return lf


def _save_long_cache(path: Path, lf: LongFlow) -> None:
    arrays = {
        "src": lf.src,
        "dst_xy": lf.dst_xy,
        "dst_t": lf.dst_t,
        "gaps": np.array(lf.gaps, dtype=np.int64),
        "stride": np.array(lf.stride),
        "backend": np.array(lf.backend),
        "threshold_px": np.array(lf.threshold_px, dtype=np.float64),
        "version": np.array(LONG_FLOW_CACHE_VERSION),
    }
    _save_arrays(path, arrays, "long-range flow cache")


def compute_long_flow(
    frames: np.ndarray,
    adjacent: FlowField,
    gaps: tuple[int, ...],
    backend: InitFlowBackend | None = None,
    cache_dir: Path | None = None,
    threshold_px: float | None = None,
    stride: int = 2,
    progress: Callable[[int, int], None] | None = None,
) -> LongFlow:
    """Consistent correspondences of ``frames`` (float32 [T, H, W, 3] in [0, 1], the frames ``adjacent`` was
    computed on) between frames ``gaps`` apart (``long_flow_gaps``: each gap's half is computed before it), on
    the pixel grid of ``stride``, cached in ``cache_dir`` when given.

    ``threshold_px``: the forward-backward threshold (None: the adjacent flow's). ``progress(done, total)``
    after each pair (``long_flow_pairs``; once with ``(total, total)`` on a cache hit).
    """
    backend = DISFlow() if backend is None else backend
    threshold = float(adjacent.threshold_px if threshold_px is None else threshold_px)
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    frames = _sanitize(frames)
    t, h, w = frames.shape[:3]
    gaps = tuple(int(k) for k in gaps)
    if any(k < 2 or k & (k - 1) for k in gaps) or list(gaps) != sorted(set(gaps)) or (gaps and gaps[0] != 2):
        raise ValueError(f"gaps must be the powers of two 2, 4, 8, ... in order, got {gaps}")
    if adjacent.forward.shape != (max(t - 1, 0), h, w, 2):
        raise ValueError(f"adjacent flow {adjacent.forward.shape} is not of these {t} frames of {w}x{h}")
    total = long_flow_pairs(gaps, t)
    cache_path = None
    if cache_dir is not None:
        cache_path = Path(cache_dir) / f"long-{long_content_key(frames, adjacent, gaps, backend, stride)}.npz"
        cached = _load_long_cache(cache_path, t, h, w, gaps, stride, backend.name, threshold)
        if cached is not None:
            if progress is not None and total > 0:
                progress(total, total)
            return cached

    lf = _correspondences(frames, adjacent, gaps, backend, threshold, stride, total, progress)
    if cache_path is not None:
        _save_long_cache(cache_path, lf)
    return lf


def _correspondences(
    frames: np.ndarray,
    adjacent: FlowField,
    gaps: tuple[int, ...],
    backend: InitFlowBackend,
    threshold: float,
    stride: int,
    total: int,
    progress: Callable[[int, int], None] | None,
) -> LongFlow:
    """The consistent correspondences of every pair ``gaps`` apart (checked arguments, see ``compute_long_flow``):
    each gap's flow starts from the previous gap's chained twice, so a long gap is found from what a short one
    already knows instead of searched from scratch."""
    t, h, w = frames.shape[:3]
    src_type, t_type = _index_types(t, h, w)
    grid = np.zeros((h, w), dtype=bool)
    grid[::stride, ::stride] = True
    src_parts: list[np.ndarray] = []
    dst_parts: list[np.ndarray] = []
    t_parts: list[np.ndarray] = []

    def keep(flow: np.ndarray, ok: np.ndarray, a: int, b: int) -> None:
        ys, xs = np.nonzero(ok & grid)
        src_parts.append((a * h * w + ys.astype(np.int64) * w + xs).astype(src_type))
        dst_parts.append(np.stack((xs + flow[ys, xs, 0], ys + flow[ys, xs, 1]), -1).astype(np.float32))
        t_parts.append(np.full(len(ys), b, dtype=t_type))

    # the previous gap's dense flow, both ways: fwd[i] frame i -> i + half, bwd[i] frame i + half -> i
    fwd_prev, bwd_prev = list(adjacent.forward), list(adjacent.backward)
    done = 0
    for k in gaps:
        half = k // 2
        fwd_k, bwd_k = [], []
        for a in range(t - k):
            b = a + k
            start_f = chain(fwd_prev[a], fwd_prev[a + half])
            start_b = chain(bwd_prev[a + half], bwd_prev[a])
            fwd = _checked(backend(frames[a], frames[b], start_f), h, w, backend.name)
            bwd = _checked(backend(frames[b], frames[a], start_b), h, w, backend.name)
            ok_f = consistency_mask(fwd, bwd, threshold)
            ok_b = consistency_mask(bwd, fwd, threshold)
            fwd = np.nan_to_num(fwd, nan=0.0, posinf=0.0, neginf=0.0)
            bwd = np.nan_to_num(bwd, nan=0.0, posinf=0.0, neginf=0.0)
            keep(fwd, ok_f, a, b)
            keep(bwd, ok_b, b, a)
            fwd_k.append(fwd)
            bwd_k.append(bwd)
            done += 1
            if progress is not None:
                progress(done, total)
        fwd_prev, bwd_prev = fwd_k, bwd_k

    def joined(parts: list[np.ndarray], shape: tuple[int, ...], dtype: type[np.generic]) -> np.ndarray:
        return np.concatenate(parts) if parts else np.zeros(shape, dtype=dtype)

    lf = LongFlow(
        src=joined(src_parts, (0,), src_type),
        dst_xy=joined(dst_parts, (0, 2), np.float32),
        dst_t=joined(t_parts, (0,), t_type),
        gaps=gaps,
        stride=int(stride),
        backend=backend.name,
        threshold_px=threshold,
    )
    return lf


__all__ = [
    "LONG_FLOW_CACHE_VERSION",
    "InitFlowBackend",
    "LongFlow",
    "chain",
    "compute_long_flow",
    "long_flow_gaps",
    "long_flow_pairs",
]
