"""Optical flow preprocessing: forward/backward flow of every adjacent frame pair and where to trust it.

The flow losses (Eq. 11, 12) only use flow that survives a forward-backward round trip, so occluded and
out-of-frame pixels never pull the mappings. Computing flow is the slowest preprocessing step, so results
are cached on disk under a key of the exact frames, backend and threshold: a re-fit or a resumed run of the
same clip reuses them.

Conventions: pixel centres are at integer coordinates (pixel ``[y, x]`` is the point ``(x, y)``, as in
``cv2.remap``); a flow vector ``(dx, dy)`` at ``(x, y)`` of frame ``a`` points to ``(x + dx, y + dy)``
in ``b``.
"""

from __future__ import annotations

import dataclasses
import errno
import hashlib
import logging
import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, Protocol, TypeVar, runtime_checkable

import cv2
import numpy as np

from ..config import FLOW_PRESETS
from ..errors import DiskFullError, InputError
from ..io.atomic import atomic_write
from ..terms.run_folder import FLOW_KEY_PATTERN

log = logging.getLogger(__name__)
#: What a cache reader makes of a file's arrays (``read_cache``).
_Read = TypeVar("_Read")

#: Bump when the flow computation or the cache layout changes: old cache files then miss instead of lying.
FLOW_CACHE_VERSION = 1

#: The config's preset names (``FLOW_PRESETS``, fastest first) to OpenCV's preset and the finest scale DIS refines
#: to (None: the preset's own; 0: full resolution). OpenCV's ``medium`` stops at half resolution (finest scale 1);
#: ``fine`` goes on to full resolution, about five times the time: chained over a clip's frames it follows points
#: better on every clip measured (object points, 32 frames: camel 0.81 -> 0.91, cows 0.82 -> 0.85, blackswan
#: 0.71 -> 0.85 at 768 px; docs/bench/experiments.md).
_DIS_PRESETS: dict[str, tuple[int, int | None]] = dict(
    zip(
        FLOW_PRESETS,
        (
            (cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, None),
            (cv2.DISOPTICAL_FLOW_PRESET_FAST, None),
            (cv2.DISOPTICAL_FLOW_PRESET_MEDIUM, None),
            (cv2.DISOPTICAL_FLOW_PRESET_MEDIUM, 0),
        ),
        strict=True,
    )
)
DIS_PRESETS: tuple[str, ...] = tuple(_DIS_PRESETS)


@runtime_checkable
class FlowBackend(Protocol):
    """Anything that estimates dense flow between two RGB frames (DIS now, RAFT later).

    ``name`` is a stable id that goes into the cache key, so two backends (or settings) that can give
    different flow must have different names.
    """

    @property
    def name(self) -> str: ...

    def __call__(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``a``, ``b``: float32 [H, W, 3] RGB in [0, 1] -> float32 [H, W, 2] flow (dx, dy) from a to b."""
        ...


def _to_grey_u8(img: np.ndarray) -> np.ndarray:
    """DIS works on 8-bit grey; NaN/Inf become 0 so they cannot poison the flow."""
    rgb = np.nan_to_num(np.asarray(img, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    u8 = np.clip(rgb * 255.0 + 0.5, 0.0, 255.0).astype(np.uint8)
    return cv2.cvtColor(np.ascontiguousarray(u8), cv2.COLOR_RGB2GRAY)


#: DIS rejects images under 12 px and segfaults (OpenCV 4.11) on thin ones such as 20x300: pad to this.
_DIS_MIN_SIDE = 32


def _pad_min(grey: np.ndarray) -> np.ndarray:
    h, w = grey.shape
    if h >= _DIS_MIN_SIDE and w >= _DIS_MIN_SIDE:
        return grey
    return cv2.copyMakeBorder(grey, 0, max(0, _DIS_MIN_SIDE - h), 0, max(0, _DIS_MIN_SIDE - w), cv2.BORDER_REPLICATE)


@dataclass(frozen=True)
class DISFlow:
    """OpenCV's Dense Inverse Search flow: CPU-only, no weights to download, good enough for the losses.

    The preset's own settings are used (``fast``, ``medium`` and ``fine`` include variational refinement).
    """

    preset: str = "medium"

    def __post_init__(self) -> None:
        if self.preset not in _DIS_PRESETS:
            raise ValueError(f"unknown DIS preset {self.preset!r}; expected one of {DIS_PRESETS}")

    @property
    def name(self) -> str:
        return f"dis-{self.preset}"

    def __call__(self, a: np.ndarray, b: np.ndarray, init: np.ndarray | None = None) -> np.ndarray:
        """``init``: float32 [H, W, 2], a flow to start from: OpenCV's DIS takes a float32 two-channel flow of the
        frames' size passed as ``calc``'s output as its initial flow (taken down to its coarsest scale and refined
        from there), so a displacement far beyond DIS's own search is followed when ``init`` is close to it (the
        chained flow of ``engine.data.long_flow``)."""
        if a.shape != b.shape or a.ndim != 3 or a.shape[2] != 3:
            raise ValueError(f"DISFlow needs two [H, W, 3] frames of equal size, got {a.shape} and {b.shape}")
        # A fresh instance per call: DIS objects are stateful and not thread-safe; creation is cheap.
        preset, finest = _DIS_PRESETS[self.preset]
        dis = cv2.DISOpticalFlow.create(preset)
        if finest is not None:
            dis.setFinestScale(finest)
        h, w = a.shape[:2]
        ga, gb = _pad_min(_to_grey_u8(a)), _pad_min(_to_grey_u8(b))
        if init is None:
            # None: OpenCV allocates the output (its stubs list only an array there)
            flow = dis.calc(ga, gb, None)  # type: ignore[call-overload]
        else:
            if init.shape != (h, w, 2):
                raise ValueError(f"initial flow must be {(h, w, 2)}, got {init.shape}")
            start = np.nan_to_num(np.asarray(init, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
            ph, pw = ga.shape
            if (ph, pw) != (h, w):
                start = np.asarray(cv2.copyMakeBorder(start, 0, ph - h, 0, pw - w, cv2.BORDER_REPLICATE))
            flow = dis.calc(ga, gb, np.ascontiguousarray(start))  # a copy of init: DIS writes its result into it
        flow = flow[:h, :w]
        return np.nan_to_num(np.asarray(flow, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)


@dataclass
class FlowField:
    """Flow of a clip. ``backward[t]`` is the flow of frame t+1 back to frame t (same index as forward)."""

    forward: np.ndarray  # float32 [T-1, H, W, 2]: frame t -> t+1
    backward: np.ndarray  # float32 [T-1, H, W, 2]: frame t+1 -> t
    forward_ok: np.ndarray  # bool [T-1, H, W]: consistent round trip and target inside the frame
    backward_ok: np.ndarray  # bool [T-1, H, W]
    backend: str
    threshold_px: float
    key: str | None = None
    """The content key it is cached under (``content_key``: ``RUN_DIR/flow_cache/KEY.npz``), which the fit records
    (``clip.json``'s ``flow_key``) so an export finds this flow and no other; None where it was not cached."""

    @property
    def pairs(self) -> int:
        return int(self.forward.shape[0])


def consistency_mask(fwd: np.ndarray, bwd: np.ndarray, threshold_px: float = 1.0) -> np.ndarray:
    """Where ``fwd`` (a -> b) is trustworthy: the round trip through ``bwd`` (b -> a) returns within
    ``threshold_px`` and the target lies inside ``b`` (within the pixel centres, so sampling ``b`` there
    needs no extrapolation). Occluded pixels fail the round trip because ``bwd`` there follows the occluder.

    ``fwd``, ``bwd``: [H, W, 2] or [N, H, W, 2]. Returns bool [H, W] or [N, H, W]. Non-finite flow is not ok.
    """
    fwd = np.asarray(fwd, dtype=np.float32)
    bwd = np.asarray(bwd, dtype=np.float32)
    if fwd.shape != bwd.shape or fwd.ndim not in (3, 4) or fwd.shape[-1] != 2:
        raise ValueError(f"flows must both be [(N,) H, W, 2], got {fwd.shape} and {bwd.shape}")
    if fwd.ndim == 4:
        out = np.empty(fwd.shape[:3], dtype=bool)
        for i in range(fwd.shape[0]):
            out[i] = consistency_mask(fwd[i], bwd[i], threshold_px)
        return out
    h, w = fwd.shape[:2]
    finite = np.isfinite(fwd[..., 0]) & np.isfinite(fwd[..., 1])
    all_finite = bool(finite.all())
    if not all_finite:
        fwd = np.where(finite[..., None], fwd, 0.0).astype(np.float32)
    if not np.isfinite(bwd).all():
        bwd = np.nan_to_num(bwd, nan=np.inf, posinf=np.inf, neginf=np.inf)  # non-finite target -> error inf
    xs, ys = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    qx = xs + fwd[..., 0]
    qy = ys + fwd[..., 1]
    back = cv2.remap(np.ascontiguousarray(bwd), qx, qy, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    ex = fwd[..., 0] + back[..., 0]
    ey = fwd[..., 1] + back[..., 1]
    ok = ex * ex + ey * ey < np.float32(threshold_px) ** 2  # NaN (inf * 0 in the interpolation) -> False
    ok &= (qx >= 0.0) & (qx <= w - 1) & (qy >= 0.0) & (qy <= h - 1)
    if not all_finite:
        ok &= finite
    return ok


#: ``cv2.remap`` refuses a map or an image of ``SHRT_MAX`` (32767) pixels or more a side. Points sampled at once are
#: laid out in rows of this many, so any number of them fits (a close-up's mask holds 100k points and more).
POINTS_PER_ROW = 4096


def sample_points(field: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear samples [N, C] of ``field`` [H, W, C] (float32) at the points ``pts`` [N, 2] (x, y), edge values
    beyond it; each point is sampled alone, so the rows the points are laid out in change no value."""
    n = len(pts)
    rows = max(1, -(-n // POINTS_PER_ROW))
    width = min(max(n, 1), POINTS_PER_ROW)
    xy = np.zeros((rows * width, 2), np.float32)
    xy[:n] = pts
    xy = xy.reshape(rows, width, 2)
    out = cv2.remap(field, xy[..., 0], xy[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(rows * width, -1)[:n]


def resize_flow(flow: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resample a flow field ([H, W, 2] or [N, H, W, 2]) to ``size = (W, H)``, rescaling the vectors.

    dx scales with the width ratio and dy with the height ratio (the paper's reference code swaps them,
    which only goes unnoticed for uniform scaling). With cv2's pixel-centre-aligned resize a displacement
    ``d`` maps to exactly ``d * ratio``.
    """
    flow = np.asarray(flow, dtype=np.float32)
    if flow.ndim == 4:
        return np.stack([resize_flow(f, size) for f in flow]) if len(flow) else flow.reshape(0, size[1], size[0], 2)
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise ValueError(f"flow must be [(N,) H, W, 2], got {flow.shape}")
    new_w, new_h = int(size[0]), int(size[1])
    if new_w < 1 or new_h < 1:
        raise ValueError(f"target size must be positive, got {size}")
    old_h, old_w = flow.shape[:2]
    shrink = new_w <= old_w and new_h <= old_h
    interp = cv2.INTER_AREA if shrink else cv2.INTER_LINEAR  # area averaging avoids aliasing when shrinking
    out = cv2.resize(np.ascontiguousarray(flow), (new_w, new_h), interpolation=interp).astype(np.float32)
    out[..., 0] *= new_w / old_w
    out[..., 1] *= new_h / old_h
    return out


def _sanitize(frames: np.ndarray) -> np.ndarray:
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3:
        raise ValueError(f"frames must be [T, H, W, 3], got {frames.shape}")
    if frames.shape[0] < 1:
        raise ValueError("frames must hold at least one frame")
    out = np.ascontiguousarray(frames, dtype=np.float32)
    if np.isfinite(out).all():
        return out  # the usual case: no copy of the whole clip
    return np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0)


def content_key(frames: np.ndarray, backend: FlowBackend, threshold_px: float) -> str:
    """Cache key: whatever changes the flow (pixels, size, backend, threshold, code version) changes it."""
    arr = np.ascontiguousarray(frames)
    h = hashlib.sha256()
    h.update(f"neural-atlas-flow:v{FLOW_CACHE_VERSION}\n".encode())
    h.update(f"shape={tuple(arr.shape)};dtype={arr.dtype.str}\n".encode())
    h.update(f"backend={backend.name};threshold={float(threshold_px)!r}\n".encode())
    h.update(arr.data.cast("B"))  # the pixels themselves, without copying the clip
    return h.hexdigest()


FLOW_KEY = re.compile(FLOW_KEY_PATTERN)


def cached_flow(
    cache_dir: Path, key: str, t: int, h: int, w: int, backend: str, threshold_px: float
) -> FlowField | None:
    """The adjacent-pair flow cached in ``cache_dir`` under ``key`` (the one the fit recorded, ``FlowField.key``) for
    ``t`` frames at ``h`` x ``w`` with this backend and threshold; None when that file is not there, not whole or not
    of this shape. Found by its key alone, never by looking for a likely file: the cache may hold another plate's flow
    (a run folder refitted on other frames, a ``flow_cache`` shared between shots), and only the key says which is
    this fit's. A ``key`` that is not a content key is a miss (``clip.json`` is a file a user can edit)."""
    if not FLOW_KEY.fullmatch(key):
        return None
    field = _load_cache(Path(cache_dir) / f"{key}.npz", t, h, w, backend, threshold_px, quiet=True)
    return None if field is None else dataclasses.replace(field, key=key)


def _load_cache(
    path: Path, t: int, h: int, w: int, backend: str, threshold_px: float, quiet: bool = False
) -> FlowField | None:
    """A cache file that is missing, truncated or from something else is a miss, never an error (``quiet``: a
    lookup where a miss is no news)."""

    def read(z: Any) -> tuple[FlowField, int]:
        field = FlowField(
            forward=np.asarray(z["forward"]),
            backward=np.asarray(z["backward"]),
            forward_ok=np.asarray(z["forward_ok"]),
            backward_ok=np.asarray(z["backward_ok"]),
            backend=str(z["backend"]),
            threshold_px=float(z["threshold_px"]),
        )
        return field, int(z["version"])

    found = read_cache(path, "flow cache", read, quiet)
    if found is None:
        return None
    field, version = found
    n = t - 1
    good = (
        version == FLOW_CACHE_VERSION
        and field.backend == backend
        and field.threshold_px == float(threshold_px)
        and field.forward.shape == field.backward.shape == (n, h, w, 2)
        and field.forward_ok.shape == field.backward_ok.shape == (n, h, w)
        and field.forward.dtype == field.backward.dtype == np.float32
        and field.forward_ok.dtype == field.backward_ok.dtype == np.bool_
        and bool(np.isfinite(field.forward).all() and np.isfinite(field.backward).all())
    )
    if not good:
        foreign_cache(path, "flow cache", quiet)
        return None
    return field


def read_cache(path: Path, what: str, read: Callable[[Any], _Read], quiet: bool = False) -> _Read | None:
    """``read`` of the npz file at ``path`` (its arrays by name); None where the file is missing or cannot be read
    (a warning naming ``what``, unless ``quiet``): a cache is an optimisation, and a bad file is computed again."""
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            return read(z)
    except Exception as exc:  # zipfile.BadZipFile, EOFError, KeyError, ValueError, OSError, ...
        if not quiet:
            log.warning("ignoring unreadable %s %s (%s); recomputing", what, path, exc)
        return None


def foreign_cache(path: Path, what: str, quiet: bool = False) -> None:
    """Warn (unless ``quiet``) that the cache file read is not of this clip: a miss, computed again."""
    if not quiet:
        log.warning("ignoring %s %s: it does not match this clip; recomputing", what, path)


#: Bytes of an npz file beyond its arrays' data, per array (zip headers, zip64 extras, the .npy header): the cache
#: file's space is reserved with this margin before it is written.
NPZ_OVERHEAD_PER_ARRAY = 4096
#: fallocate errors that mean "this file system cannot reserve space", not "the disk is full".
_NO_FALLOCATE = frozenset({errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS})


def _reserve(f: BinaryIO, size: int) -> None:
    """Reserve ``size`` bytes for ``f`` where the OS can (``posix_fallocate``), so a disk without room fails here
    with ENOSPC, before a zip file is half-written (a zip writer that fails half-way cannot close cleanly)."""
    fallocate = getattr(os, "posix_fallocate", None)
    if fallocate is None:
        return
    try:
        fallocate(f.fileno(), 0, size)
    except OSError as exc:
        if exc.errno not in _NO_FALLOCATE:
            raise


def _save_cache(path: Path, field: FlowField) -> None:
    """The flow of ``compute_flow`` written to ``path`` (``_save_arrays``)."""
    arrays = {
        "forward": field.forward,
        "backward": field.backward,
        "forward_ok": field.forward_ok,
        "backward_ok": field.backward_ok,
        "backend": np.array(field.backend),
        "threshold_px": np.array(field.threshold_px, dtype=np.float64),
        "version": np.array(FLOW_CACHE_VERSION),
    }
    _save_arrays(path, arrays, "flow cache")


def _save_arrays(path: Path, arrays: dict[str, np.ndarray], what: str) -> None:
    """Atomic write (``io.atomic``: a temp file in the same folder, then a rename): a kill, a cancel or a full disk
    never leaves a half file under the cache's name, and the temp file is removed whatever stopped the write.
    The cache is only an optimisation: a disk without room for it skips it (logged at INFO: the fit goes on, and
    a disk too full for the fit's own files says so in one line then), any other failure is logged as a warning;
    a cancel (KeyboardInterrupt) still stops the command. ``what`` names the file in the log."""
    need = sum(a.nbytes for a in arrays.values()) + NPZ_OVERHEAD_PER_ARRAY * len(arrays)

    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            _reserve(f, need)
            np.savez(f, **arrays)
            f.truncate()  # to what was written: the reservation's margin is not part of the file

    try:
        atomic_write(path, write, need=need)
    except DiskFullError as exc:
        log.info("no room for the %s %s (%s); continuing without it", what, path, exc)
    except (OSError, InputError) as exc:
        log.warning("could not write %s %s (%s); continuing without it", what, path, exc)


def _checked_flow(flow: np.ndarray, h: int, w: int, backend: FlowBackend) -> np.ndarray:
    flow = np.asarray(flow)
    if flow.shape != (h, w, 2):
        raise ValueError(f"flow backend {backend.name} returned shape {flow.shape}, expected {(h, w, 2)}")
    return flow.astype(np.float32, copy=False)


def compute_flow(
    frames: np.ndarray,
    backend: FlowBackend | None = None,
    cache_dir: Path | None = None,
    threshold_px: float = 1.0,
    progress: Callable[[int, int], None] | None = None,
) -> FlowField:
    """Forward and backward flow of every adjacent pair of ``frames`` (float32 [T, H, W, 3] in [0, 1], at
    working resolution) with their consistency masks, cached in ``cache_dir`` when given.

    ``progress(done_pairs, total_pairs)`` is called after each pair (once with ``(total, total)`` on a cache
    hit, so a progress bar still completes). A single frame gives arrays with a leading dimension of 0.
    """
    backend = DISFlow() if backend is None else backend
    frames = _sanitize(frames)
    t, h, w = frames.shape[:3]
    n = t - 1
    cache_path = None
    if cache_dir is not None:
        cache_path = Path(cache_dir) / f"{content_key(frames, backend, threshold_px)}.npz"
        cached = _load_cache(cache_path, t, h, w, backend.name, threshold_px)
        if cached is not None:
            if progress is not None and n > 0:
                progress(n, n)
            return dataclasses.replace(cached, key=cache_path.stem)

    forward = np.zeros((n, h, w, 2), dtype=np.float32)
    backward = np.zeros((n, h, w, 2), dtype=np.float32)
    forward_ok = np.zeros((n, h, w), dtype=bool)
    backward_ok = np.zeros((n, h, w), dtype=bool)
    for i in range(n):
        fwd = _checked_flow(backend(frames[i], frames[i + 1]), h, w, backend)
        bwd = _checked_flow(backend(frames[i + 1], frames[i]), h, w, backend)
        # Masks first (they reject non-finite vectors), then zero those vectors: stored flow is never NaN.
        forward_ok[i] = consistency_mask(fwd, bwd, threshold_px)
        backward_ok[i] = consistency_mask(bwd, fwd, threshold_px)
        forward[i] = np.nan_to_num(fwd, nan=0.0, posinf=0.0, neginf=0.0)
        backward[i] = np.nan_to_num(bwd, nan=0.0, posinf=0.0, neginf=0.0)
        if progress is not None:
            progress(i + 1, n)

    key = None if cache_path is None else cache_path.stem
    field = FlowField(forward, backward, forward_ok, backward_ok, backend.name, float(threshold_px), key)
    if cache_path is not None:
        _save_cache(cache_path, field)
    return field
