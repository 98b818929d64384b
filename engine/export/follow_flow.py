"""Paint that follows the flow (``export --follow-flow``, the default): each layer's UV averaged along optical flow
(the export's own, ``FOLLOW_FLOW_PRESET``) before the passes are written.

Why: in an ideal atlas a point of the object keeps its UV in every frame. A fitted mapping is smooth in time and
cannot follow a dog's legs, a camel turning or a dancer's arms from one frame to the next (nor, in the background's
one mapping, the cars that drive through it), so the UV of such a point drifts by pixels over a few frames and the
paint slips. Chained optical flow follows those frames closely; the atlas is one canvas for the whole clip. Averaging
a layer's UV along flow trajectories with a two-sided exponential mean takes what each does well: over a few frames
the paint moves with the flow, over many it stays the atlas's; with a long reach a point keeps nearly one UV along
its whole trajectory, the mean of what the atlas says over its frames. The mean, at working resolution, with ``u``
the layer's UV, ``w`` the weight of one frame step and ``D`` the weight a trajectory has gathered so far::

    D_0 = 1,  F_0 = u_0,  D_t = 1 + w D_{t-1}(x'),  F_t = (u_t + w D_{t-1}(x') F_{t-1}(x')) / D_t,  x' = x + back_t(x)
    the same backward (B, E) along fwd_t from the last frame; result = (D F + E B - u) / (D + E - 1)

so each frame of a trajectory weighs w^|k| and the weights are normalised over the frames the trajectory holds: its
first and last frame weigh no more than the others (a plain recursive filter ``F_t = (1 - w) u_t + w F_{t-1}``
leaves the rest of the weight, w^t, on the first frame, so along a long reach the result leans on the trajectory's
two ends and changes along it by several times as much).

A step is taken only where the pixel belongs to the layer, the flow passed its forward-backward check and
the point it lands on belongs to the layer in the neighbour frame. Where it cannot be taken (an occlusion, a
disocclusion, the outline), the pass starts again from ``u`` over a few frames (``SHORT_WEIGHT``); along whole
trajectories (``LONG_WEIGHT``, ``fill``) the pixel instead takes the correction (``F - u``) and the gathered weight
of the pixels around it that were carried (a Gaussian of ``FILL_SIGMA_PX``, normalised over them), times ``w``: the
atlas's error is smooth over the object, and starting again from the fitted UV there would bring back, downstream,
the error the filter had removed. A pixel with no carried pixel near it keeps ``u``; where neither pass could step
or fill, the result is ``u`` exactly. The export carries the correction (result - u) past the layer's outline
(``extended``), upsamples it and adds it to the UV it evaluates at every native pixel; which reach each layer
follows is ``flow_reach``'s choice.

A layer whose UV already follows the flow within the flow's own error (``MIN_SLIP_PX``, the median frame-to-frame
disagreement, ``layer_slip_px``) is left as it is: there the atlas is better than the flow at every gap, and the
filter could only bring the flow's drift in (measured: docs/bench/experiments.md, the follow-flow rows).

numpy and OpenCV only (no torch): the arrays come from the exporter.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from ..data.flow import FlowField

#: The flow the export follows (``engine.data.flow.DISFlow``'s preset), computed on the plate at working size by
#: the export itself whatever flow the fit learnt from: the finest DIS preset. Chained over a clip it tracks points
#: best (measured against ``medium``, the fit's default: docs/bench/experiments.md), and the paint follows it point
#: by point, where the fit's losses only need it on average.
FOLLOW_FLOW_PRESET = "fine"
#: Weight of the neighbour frame in each step (0: the fitted UV, unchanged), over a few frames: the filter reaches
#: about 1 / (1 - w) frames along the flow, and where the flow cannot carry a pixel it starts again from its fitted UV.
SHORT_WEIGHT = 0.7
#: ... along whole trajectories: at 0.999 a point keeps nearly one UV along all of its trajectory in a clip of a few
#: hundred frames (frames 300 apart weigh 0.74 of each other), and where the flow cannot carry a pixel it takes its
#: carried neighbours' correction (the fill). Which reach a layer gets: ``flow_reach`` (measured from 0.7 to 0.999,
#: and 0.995 against 0.999 on every clip: docs/bench/experiments.md).
LONG_WEIGHT = 0.999
#: The fill: where the flow cannot carry a pixel, it takes the correction of the carried pixels around it, a Gaussian
#: of this many working pixels (about a limb's half-width at the working size) normalised over the carried pixels.
FILL_SIGMA_PX = 6.0
#: ... only where the carried pixels make up at least this share of the Gaussian's weight: farther away, nothing
#: nearby says what the atlas's error is, and the pixel keeps its fitted UV.
FILL_MIN_SHARE = 0.01
#: A layer is filtered only when its UV disagrees with the flow by more than this, in working pixels (median over
#: its pixels and frames): DIS's own error on a plate the UV follows exactly is 0.15-0.3 px.
MIN_SLIP_PX = 0.3
#: A carried value is used only where at least this share of its bilinear footprint belongs to the layer, so UV of
#: another layer (or of nothing) is never mixed in at an outline.
MIN_SHARE = 0.99
#: Floor of a frame's UV scale (UV units per pixel) when converting UV distances to pixels: a collapsed mapping.
MIN_UV_PER_PX = 1e-9
#: What following the flow holds in memory per working pixel and frame: each layer's UV (8 B), whether the layer
#: owns the pixel and whether it is solid there (2 x 1 B), its correction over each reach (2 x 8 B) and the weight
#: the forward pass gathered (4 B, while one reach is computed); once, the
#: flow both ways (16 B), their checks (2 B) and the plate at working size (12 B: the reach test and the
#: atlas texture).
BYTES_PER_LAYER, FLOW_BYTES = 30, 30
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
    uv: np.ndarray,
    owned: np.ndarray,
    flow: np.ndarray,
    grid: tuple[np.ndarray, np.ndarray],
    gathered: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(``uv`` [H, W, 2] read where ``flow`` [H, W, 2] carries each pixel, ``gathered`` [H, W] read there (ones when
    None), the share [H, W] of that bilinear read that ``owned`` covers); the reads are normalised by the share, so
    they average owned pixels only."""
    gx, gy = grid
    m = owned.astype(np.float32)
    d = m if gathered is None else gathered * m
    look = cv2.remap(
        np.dstack((uv * m[..., None], d, m)),
        gx + flow[..., 0],
        gy + flow[..., 1],
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=(0.0, 0.0, 0.0, 0.0),
    )
    share = look[..., 3]
    norm = np.maximum(share, MIN_SHARE)
    return look[..., :2] / norm[..., None], look[..., 2] / norm, share


def _filled(values: np.ndarray, carried: np.ndarray, owned: np.ndarray) -> np.ndarray:
    """``values`` [H, W, C] where ``carried``, and at the other ``owned`` pixels the carried pixels' values around
    them (a Gaussian of ``FILL_SIGMA_PX`` normalised over the carried pixels, where they hold at least
    ``FILL_MIN_SHARE`` of its weight; else 0); 0 off ``owned``."""
    m = carried.astype(np.float32)
    num = cv2.GaussianBlur(values * m[..., None], (0, 0), FILL_SIGMA_PX).reshape(values.shape)
    den = cv2.GaussianBlur(m, (0, 0), FILL_SIGMA_PX)
    near = den >= FILL_MIN_SHARE
    around = num / np.maximum(den, FILL_MIN_SHARE)[..., None]
    out = np.where(carried[..., None], values, np.where(near[..., None], around, 0.0))
    return np.where(owned[..., None], out, 0.0).astype(np.float32)


def _step(
    u: np.ndarray,
    owned: np.ndarray,
    neighbour: tuple[np.ndarray, np.ndarray, np.ndarray],
    carry: tuple[np.ndarray, np.ndarray],
    weight: float,
    grid: tuple[np.ndarray, np.ndarray],
    fill: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """One recursion step of either pass: (the correction [H, W, 2] that moves ``u`` to the trajectory's mean so
    far, the weight [H, W] the trajectory has gathered here). ``neighbour``: the neighbour frame's filtered UV, its
    gathered weight and where the layer owns it; ``carry``: the flow to the neighbour [H, W, 2] and where it passed
    its forward-backward check [H, W]. Where the flow cannot carry a pixel it starts a trajectory (weight 1,
    no correction) or, with ``fill``, takes what the carried pixels around it were given, one step further (times
    ``weight``)."""
    flow, flow_ok = carry
    filtered, gathered, neighbour_owned = neighbour
    looked, d_looked, share = _carried(filtered, neighbour_owned, flow, grid, gathered)
    use = owned & flow_ok & (share >= MIN_SHARE)
    pulled = np.zeros_like(u)
    d = np.ones(u.shape[:2], np.float32)
    wd = weight * d_looked[use]
    d[use] = 1.0 + wd
    pulled[use] = (wd / (1.0 + wd))[:, None] * (looked[use] - u[use])
    if not fill:
        return pulled, d
    out = _filled(np.dstack((pulled, d)), use, owned)
    out[~use] *= weight  # a filled pixel is one step further from the pixels it was filled from
    return out[..., :2], np.where(owned & ~use, np.maximum(out[..., 2], 1.0), d)


def follow_flow(
    uv: np.ndarray, owned: np.ndarray, flow: FlowField, weight: float = SHORT_WEIGHT, fill: bool = False
) -> np.ndarray:
    """The correction [T, H, W, 2] (filtered minus ``uv``; zero where the layer does not own the pixel) of one
    layer's UV ``uv`` [T, H, W, 2] (any linear unit), ``owned`` [T, H, W] bool, along ``flow`` (the export's, at the
    same H x W); ``fill``: a pixel the flow cannot carry takes its carried neighbours' correction (the long reach).
    Memory: ``uv``, one more array of its size and the forward pass's weights ([T, H, W] float32)."""
    if not 0.0 <= weight < 1.0:
        raise ValueError(f"the follow-flow weight must be in [0, 1), not {weight}")
    frames, h, w = owned.shape
    if frames < 2 or weight == 0.0:
        return np.zeros_like(uv, dtype=np.float32)
    grid = _grid(h, w)
    out = np.empty(uv.shape, np.float32)  # the forward pass's corrections, then the result in place
    gathered = np.empty(owned.shape, np.float32)  # the forward pass's weights D
    out[0], gathered[0] = 0.0, 1.0
    for t in range(1, frames):
        k = t - 1  # pair (t-1, t): backward[k] carries frame t to t-1
        prev = (uv[t - 1] + out[t - 1], gathered[t - 1], owned[t - 1])
        back = (flow.backward[k], flow.backward_ok[k])
        out[t], gathered[t] = _step(uv[t], owned[t], prev, back, weight, grid, fill)
    after = np.zeros(uv.shape[1:], np.float32)  # the backward pass's correction of frame t + 1 ...
    after_d = np.ones(owned.shape[1:], np.float32)  # ... and its weight E
    for t in range(frames - 1, -1, -1):
        here, here_d = np.zeros_like(after), np.ones_like(after_d)
        if t < frames - 1:
            nxt = (uv[t + 1] + after, after_d, owned[t + 1])
            fwd = (flow.forward[t], flow.forward_ok[t])
            here, here_d = _step(uv[t], owned[t], nxt, fwd, weight, grid, fill)
        # (D F + E B - u) / (D + E - 1) - u = (D (F - u) + E (B - u)) / (D + E - 1): exactly 0 where neither pass
        # took a step or filled one (D = E = 1, no correction)
        d = gathered[t][..., None]
        e = here_d[..., None]
        mean = (d * out[t] + e * here) / (d + e - 1.0)
        out[t] = np.where(owned[t][..., None], mean, 0.0)
        after, after_d = here, here_d
    return out


def extended(correction: np.ndarray, owned: np.ndarray) -> np.ndarray:
    """``correction`` [T, H, W, 2] (``follow_flow``'s) with each pixel the layer does not own given the correction of
    its nearest owned pixel in the same frame (a frame the layer owns nothing of keeps zeros); in place (the
    correction is as large as the layer's UV).

    Why: the export upsamples the correction to the native size bilinearly and adds it to the UV there. At the outline
    a native pixel the layer still covers reads half of its correction from the working pixels outside, and zero
    there would leave it between the fitted and the followed UV: a thin rim whose UV repeats the UV of a point well
    inside (measured: a camel's neck, 11 px away), so paint at that point shows twice. Off the layer its opacity is
    zero and the UV shows nowhere."""
    for t in range(len(correction)):
        if owned[t].any() and not owned[t].all():
            iy, ix = ndimage.distance_transform_edt(~owned[t], return_distances=False, return_indices=True)
            correction[t] = correction[t][iy, ix]
    return correction


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
        looked, _, share = _carried(uv[t + 1], owned[t + 1], flow.forward[t], grid)
        use = owned[t] & flow.forward_ok[t] & (share >= MIN_SHARE)
        if use.any():
            slips.append(np.linalg.norm(looked[use] - uv[t][use], axis=-1) / scale)
    return float(np.median(np.concatenate(slips))) if slips else None


__all__ = [
    "BYTES_PER_LAYER",
    "FILL_MIN_SHARE",
    "FILL_SIGMA_PX",
    "FLOW_BYTES",
    "FOLLOW_FLOW_PRESET",
    "LONG_WEIGHT",
    "MEMORY_SHARE",
    "MIN_SHARE",
    "MIN_SLIP_PX",
    "SHORT_WEIGHT",
    "available_memory",
    "follow_flow",
    "layer_slip_px",
    "memory_needed",
    "uv_per_px",
]
