"""Per-frame global motion of each layer from optical flow: the fast model's starting point.

A robust similarity (rotation, uniform scale, translation) per adjacent frame pair, fitted with RANSAC
to reliable flow inside the layer's region, then chained to frame 0. The background mapping starts as
the camera's stabilisation and the foreground mapping as the object's, so the atlases are coherent from
the first step and the networks only learn the residual deformation.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from engine.data.flow import FlowField

#: Fewer reliable flow vectors than this in a layer's region: that pair's motion is taken as identity.
MIN_POINTS = 12
#: Largest sampling stride (pixels) of the flow vectors fed to RANSAC; small regions use every pixel.
STRIDE = 4
#: The stride is chosen so a region yields about this many flow vectors.
TARGET_POINTS = 2000
#: RANSAC inlier threshold in pixels, iterations and confidence of the similarity fit.
RANSAC_PX = 1.5
RANSAC_ITERATIONS = 500
RANSAC_CONFIDENCE = 0.99
#: Similarity scales outside [1/MAX_SCALE_STEP, MAX_SCALE_STEP] per frame are rejected as outliers.
MAX_SCALE_STEP = 1.25
#: Reference pixels added on every side of a layer's content box beyond its relative margin, so that even a
#: one-pixel object gets a box with room around it.
EXTENT_PAD_PX = 2.0


@dataclass
class LayerMotion:
    """``to_ref[t]`` (2x3) maps frame-t pixels to reference (frame-0) pixels; ``center``/``half_extent``
    place the layer's content in the atlas square [-1, 1]^2."""

    to_ref: np.ndarray  # float64 [T, 2, 3]
    center: np.ndarray  # float64 [2]
    half_extent: float  # reference pixels per atlas unit (isotropic, so rigidity is measured in pixels)
    aspect: tuple[float, float] = (1.0, 1.0)  # the content spans [-ax, ax] x [-ay, ay]; max(ax, ay) == 1


def _pair_similarity(flow: np.ndarray, ok: np.ndarray, region: np.ndarray | None) -> np.ndarray:
    h, w = ok.shape
    area = float(region.sum()) if region is not None else float(h * w)
    stride = int(np.clip(np.floor(np.sqrt(area / TARGET_POINTS)), 1, STRIDE))
    ys, xs = np.mgrid[stride // 2 : h : stride, stride // 2 : w : stride]
    sel = ok[ys, xs]
    if region is not None:
        sel &= region[ys, xs]
    if sel.sum() < MIN_POINTS:
        return np.eye(2, 3)
    src = np.stack((xs[sel] + 0.5, ys[sel] + 0.5), -1).astype(np.float32)
    dst = src + flow[ys[sel], xs[sel]].astype(np.float32)
    m, inliers = cv2.estimateAffinePartial2D(
        src,
        dst,
        method=cv2.RANSAC,
        ransacReprojThreshold=RANSAC_PX,
        maxIters=RANSAC_ITERATIONS,
        confidence=RANSAC_CONFIDENCE,
    )
    if m is None or inliers is None or int(inliers.sum()) < MIN_POINTS:
        return np.eye(2, 3)
    scale = float(np.sqrt(abs(np.linalg.det(m[:, :2]))))
    if not (1.0 / MAX_SCALE_STEP <= scale <= MAX_SCALE_STEP):
        return np.eye(2, 3)
    return m.astype(np.float64)


def _h(m: np.ndarray) -> np.ndarray:
    return np.vstack((m, [0.0, 0.0, 1.0]))


def chain_motion(pair_motions: list[np.ndarray]) -> np.ndarray:
    """Pair motions S_t (frame t -> t+1 pixels) to per-frame maps to frame 0: M_{t+1} = M_t S_t^-1."""
    out = [np.eye(3)]
    for s in pair_motions:
        out.append(out[-1] @ np.linalg.inv(_h(s)))
    return np.stack([m[:2] for m in out])


def _extent(points: np.ndarray, margin: float) -> tuple[np.ndarray, float, tuple[float, float]]:
    lo, hi = points.min(0), points.max(0)
    center = (lo + hi) / 2.0
    halves = (hi - lo) / 2.0 * (1.0 + margin) + EXTENT_PAD_PX
    half = float(halves.max())
    return center, half, (float(halves[0] / half), float(halves[1] / half))


def _first_regions(region_masks: np.ndarray) -> list[np.ndarray | None]:
    """Each frame's region, None where a frame has none; the frames before the first region take the first one
    (nothing earlier to carry it from)."""
    regions: list[np.ndarray | None] = [m if m.any() else None for m in region_masks]
    first = next((r for r in regions if r is not None), None)
    for t, r in enumerate(regions):
        if r is not None:
            break
        regions[t] = first
    return regions


def _carried(region: np.ndarray, pair: np.ndarray, size: tuple[int, int]) -> np.ndarray | None:
    """``region`` moved by the pair motion ``pair`` (2x3, frame t -> t+1 pixels); None once it has left the
    frame."""
    w, h = size
    moved = cv2.warpAffine(region.astype(np.uint8), pair, (w, h), flags=cv2.INTER_NEAREST).astype(bool)
    return moved if moved.any() else None


def estimate_layer_motion(
    flow: FlowField | None,
    region_masks: np.ndarray | None,
    size: tuple[int, int],
    fit_motion: bool = True,
    margin: float = 0.06,
    extent_masks: np.ndarray | None = None,
) -> LayerMotion:
    """Per-frame similarity to the reference frame for one layer.

    ``region_masks`` (bool [T, H, W]) selects the layer's pixels (None = whole frame); the atlas extent
    covers where those pixels land (the whole frame when a mask frame is empty), or where ``extent_masks``
    land when given (a scribbled part: its motion from its scribbles, its extent from the whole object's).
    A frame without a region (a mask left out) fits its pair inside the previous region carried by the layer's
    own motion; frames before the first region use the first one.
    """
    w, h = size
    t_count = 1 if flow is None else flow.forward.shape[0] + 1
    if region_masks is not None:
        t_count = region_masks.shape[0]
    pairs = []
    regions: list[np.ndarray | None] = [None] * t_count if region_masks is None else _first_regions(region_masks)
    for t in range(t_count - 1):
        if not fit_motion or flow is None:
            pairs.append(np.eye(2, 3))
            continue
        region, last = regions[t], regions[t - 1] if t else None
        if region is None and last is not None:
            # a frame without a mask (skipped in the roto, dropped by a detector): the object is where its own
            # motion carried the last region. Without it that pair fitted the whole frame, which is the camera's
            # motion, and every later frame of the object's atlas was displaced by it.
            region = _carried(last, pairs[-1], (w, h))
            regions[t] = region
        pairs.append(_pair_similarity(flow.forward[t], flow.forward_ok[t], region))
    to_ref = chain_motion(pairs)
    pts = []
    corners = np.array([[0, 0], [w, 0], [0, h], [w, h]], dtype=np.float64)
    extent = region_masks if extent_masks is None else extent_masks
    for t in range(t_count):
        if extent is not None and extent[t].any():
            ys, xs = np.nonzero(extent[t])
            p = np.array(
                [
                    [xs.min(), ys.min()],
                    [xs.max() + 1, ys.min()],
                    [xs.min(), ys.max() + 1],
                    [xs.max() + 1, ys.max() + 1],
                ],
                dtype=np.float64,
            )
        elif extent is not None:
            continue
        else:
            p = corners
        pts.append(p @ to_ref[t][:, :2].T + to_ref[t][:, 2])
    if not pts:
        pts = [corners]
    center, half, aspect = _extent(np.concatenate(pts), margin)
    return LayerMotion(to_ref=to_ref, center=center, half_extent=half, aspect=aspect)
