"""Paint that follows the flow (``export --follow-flow``, the default): each layer's UV averaged along the fit's own
optical flow before the passes are written.

Why: in an ideal atlas a point of the object keeps its UV in every frame. A fitted mapping is smooth in time and
cannot follow a dog's legs or a rider's knees from one frame to the next (nor, in the background's one mapping, the
cars that drive through it), so the UV of such a point wobbles by a few pixels a frame and the paint slips. Chained
optical flow follows those frames closely but drifts over long gaps; the atlas does not drift. Averaging a layer's
UV along flow trajectories with a two-sided exponential filter takes what each does well: over a few frames the UV
moves with the flow, over many it stays the atlas's. The filter, at working resolution, with ``u`` the layer's UV
and ``w`` the weight of one frame step::

    F_0 = u_0,       F_t(x) = (1 - w) u_t(x) + w F_{t-1}(x + back_t(x))      (back_t: flow t -> t-1)
    B_T = u_T,       B_t(x) = (1 - w) u_t(x) + w B_{t+1}(x + fwd_t(x))       (fwd_t: flow t -> t+1)
    result = (F + B - (1 - w) u) / (1 + w)                                   (weights proportional to w^|k|)

A step is taken only where the pixel belongs to the layer, the flow passed the fit's forward-backward check and
the point it lands on belongs to the layer in the neighbour frame; elsewhere the pass restarts from ``u`` (where
neither pass could step, the result is ``u`` exactly). The export adds the correction (result - u), upsampled, to
the UV it evaluates at every native pixel.

A layer whose UV already follows the flow within the flow's own error (``MIN_SLIP_PX``, the median frame-to-frame
disagreement, ``layer_slip_px``) is left as it is: there the atlas is better than the flow at every gap, and the
filter could only bring the flow's drift in (measured: docs/bench/experiments.md, the follow-flow rows).

numpy and OpenCV only (no torch): the arrays come from the exporter.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..data.flow import FlowField

#: Weight of the neighbour frame in each step (0: the fitted UV, unchanged).
FOLLOW_WEIGHT = 0.7
#: A layer is filtered only when its UV disagrees with the flow by more than this, in working pixels (median over
#: its pixels and frames): DIS's own error on a plate the UV follows exactly is 0.15-0.3 px.
MIN_SLIP_PX = 0.3
#: A carried value is used only where at least this share of its bilinear footprint belongs to the layer, so UV of
#: another layer (or of nothing) is never mixed in at an outline.
MIN_SHARE = 0.99
#: Floor of a frame's UV scale (UV units per pixel) when converting UV distances to pixels: a collapsed mapping.
MIN_UV_PER_PX = 1e-9
#: What following the flow holds in memory per working pixel and frame: each layer's UV (8 B), whether the layer
#: owns the pixel (1 B) and its correction (8 B); once, the fit's flow both ways (16 B) and their checks (2 B).
BYTES_PER_LAYER, FLOW_BYTES = 17, 18
#: Follow the flow only while that fits in this share of the memory the system says is available, so an export that
#: would once have fitted is not pushed into swap or the OOM killer by a long clip.
MEMORY_SHARE = 0.8
#: Where Linux says how much memory a new allocation can take without swapping (``MemAvailable``, in kB).
MEMINFO = "/proc/meminfo"


def memory_needed(frames: int, size: tuple[int, int], layers: int) -> int:
    """Bytes that following the flow holds for ``frames`` frames of ``size`` (W, H) working pixels and ``layers``
    layers, beyond what an export as fitted holds."""
    w, h = size
    return frames * w * h * (FLOW_BYTES + BYTES_PER_LAYER * layers)


def available_memory(meminfo: str = MEMINFO) -> int | None:
    """Bytes of memory available to a new allocation (Linux's ``MemAvailable``); None where the system does not
    say (then nothing is refused on its account)."""
    try:
        with open(meminfo, encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _grid(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return gx, gy


def _carried(
    uv: np.ndarray, owned: np.ndarray, flow: np.ndarray, grid: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """(``uv`` [H, W, 2] read where ``flow`` [H, W, 2] carries each pixel, the share [H, W] of that bilinear read
    that ``owned`` covers); the read is normalised by the share, so it averages owned pixels only."""
    gx, gy = grid
    m = owned.astype(np.float32)
    look = cv2.remap(
        np.dstack((uv * m[..., None], m)),
        gx + flow[..., 0],
        gy + flow[..., 1],
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=(0.0, 0.0, 0.0, 0.0),
    )
    share = look[..., 2]
    return look[..., :2] / np.maximum(share, MIN_SHARE)[..., None], share


def _step(
    u: np.ndarray,
    owned: np.ndarray,
    neighbour: np.ndarray,
    neighbour_owned: np.ndarray,
    flow: np.ndarray,
    flow_ok: np.ndarray,
    weight: float,
    grid: tuple[np.ndarray, np.ndarray],
) -> np.ndarray:
    """One recursion step of either pass: ``u`` pulled toward the filtered neighbour where the flow allows."""
    looked, share = _carried(neighbour, neighbour_owned, flow, grid)
    use = owned & flow_ok & (share >= MIN_SHARE)
    out = u.copy()
    out[use] = (1.0 - weight) * u[use] + weight * looked[use]
    return out


def follow_flow(uv: np.ndarray, owned: np.ndarray, flow: FlowField, weight: float = FOLLOW_WEIGHT) -> np.ndarray:
    """The correction [T, H, W, 2] (filtered minus ``uv``; zero where the layer does not own the pixel) of one
    layer's UV ``uv`` [T, H, W, 2] (any linear unit), ``owned`` [T, H, W] bool, along ``flow`` (the fit's, at the
    same H x W). Memory: ``uv`` and one more array of its size."""
    if not 0.0 <= weight < 1.0:
        raise ValueError(f"the follow-flow weight must be in [0, 1), not {weight}")
    frames, h, w = owned.shape
    if frames < 2 or weight == 0.0:
        return np.zeros_like(uv, dtype=np.float32)
    grid = _grid(h, w)
    fwd = np.empty(uv.shape, np.float32)  # the forward pass, then the correction in place
    fwd[0] = uv[0]
    for t in range(1, frames):
        k = t - 1  # pair (t-1, t): backward[k] carries frame t to t-1
        fwd[t] = _step(uv[t], owned[t], fwd[t - 1], owned[t - 1], flow.backward[k], flow.backward_ok[k], weight, grid)
    bwd = uv[-1].astype(np.float32)
    for t in range(frames - 1, -1, -1):
        if t < frames - 1:
            bwd = _step(uv[t], owned[t], bwd, owned[t + 1], flow.forward[t], flow.forward_ok[t], weight, grid)
        # (F + B - (1 - w) u) / (1 + w) - u, written so that it is exactly 0 where neither pass took a step
        both = ((fwd[t] - uv[t]) + (bwd - uv[t])) / (1.0 + weight)
        fwd[t] = np.where(owned[t][..., None], both, 0.0)
    return fwd


def uv_per_px(uv: np.ndarray, owned: np.ndarray) -> float | None:
    """One frame's scale of its UV map (UV units per pixel: the median of sqrt |det J| over owned pixels whose four
    neighbours are owned; None where there are none): converts a UV distance into pixels of the frame."""
    inner = np.zeros_like(owned)
    inner[1:-1, 1:-1] = owned[1:-1, 1:-1] & owned[:-2, 1:-1] & owned[2:, 1:-1] & owned[1:-1, :-2] & owned[1:-1, 2:]
    if not inner.any():
        return None
    iy, ix = np.nonzero(inner)
    dx = (uv[iy, ix + 1] - uv[iy, ix - 1]) / 2.0
    dy = (uv[iy + 1, ix] - uv[iy - 1, ix]) / 2.0
    det = np.abs(dx[:, 0] * dy[:, 1] - dx[:, 1] * dy[:, 0])
    return max(float(np.sqrt(np.median(det))), MIN_UV_PER_PX)


def layer_slip_px(uv: np.ndarray, owned: np.ndarray, flow: FlowField) -> float | None:
    """How far, in pixels, a layer's UV disagrees with the flow from one frame to the next: for each owned pixel
    whose flow passed the check and lands on the layer, the distance between its UV and the UV where it lands,
    over the frame's UV scale; the median of all (None: no such pixel, nothing to judge)."""
    frames, h, w = owned.shape
    grid = _grid(h, w)
    slips = []
    for t in range(frames - 1):
        scale = uv_per_px(uv[t], owned[t])
        if scale is None:
            continue
        looked, share = _carried(uv[t + 1], owned[t + 1], flow.forward[t], grid)
        use = owned[t] & flow.forward_ok[t] & (share >= MIN_SHARE)
        if use.any():
            slips.append(np.linalg.norm(looked[use] - uv[t][use], axis=-1) / scale)
    return float(np.median(np.concatenate(slips))) if slips else None


__all__ = [
    "BYTES_PER_LAYER",
    "FLOW_BYTES",
    "FOLLOW_WEIGHT",
    "MEMORY_SHARE",
    "MIN_SHARE",
    "MIN_SLIP_PX",
    "available_memory",
    "follow_flow",
    "layer_slip_px",
    "memory_needed",
    "uv_per_px",
]
