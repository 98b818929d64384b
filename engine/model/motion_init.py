"""Per-frame global motion of each layer from optical flow: the fast model's starting point.

A robust similarity (rotation, uniform scale, translation) per adjacent frame pair, fitted with RANSAC
to reliable flow inside the layer's region, then chained to frame 0. The background mapping starts as
the camera's stabilisation and the foreground mapping as the object's, so the atlases are coherent from
the first step and the networks only learn the residual deformation. A foreground that moves apart from the
background gets the motion of the object as a whole (refined apart from the background's), and an occluder's
flow inside its mask (a tree it passes behind) is set aside.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import cv2
import numpy as np

from ..data.flow import FlowField

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
#: An object's RANSAC similarity is refitted (``_refined``) to the flow vectors within this distance of it (pixels;
#: up to ``REFINE_ROUNDS`` times) and nearer it than the background's motion: a deforming object (a running dog) has
#: no rigid part larger than a leg, and the largest consensus at ``RANSAC_PX`` is that one part's motion, not the
#: body's; the background's vectors inside the mask and an occluder's stay out.
#: The refit's scale is the consensus's unless the least-squares scale keeps the object nearer the size its masks
#: show over the clip (``_size_error``): over a deforming body the least-squares scale may take pedalling legs and
#: turning wheels for a zoom, and a scale error compounds along the chain of pairs (bmx-trees with its precise masks
#: shrank to 0.82 of its size by frame 10, its masks keeping 1.0, the consensus's scale 0.88), where a running dog's
#: consensus is one leg's, whose scale is no better than its rotation.
REFINE_PX = 5.0
REFINE_ROUNDS = 3
#: ... but only in a layer whose larger consensus holds less than this share of the region's flow vectors (the
#: median over pairs): where one similarity holds most of them the object is rigid (a car: 79%, a swan gliding: all),
#: and the vectors near it that it leaves out are reflections in its glass or its wheels, which the refit would follow
#: (car-roundabout's tracking fell 0.397 -> 0.318 with it; a running dog's and a rider's 59-60% gained).
RIGID_SHARE = 0.7
#: Similarity scales outside [1/MAX_SCALE_STEP, MAX_SCALE_STEP] per frame are rejected as outliers.
MAX_SCALE_STEP = 1.25
#: A second and third consensus motion are fitted to the flow vectors the ones before leave out while those are at
#: least this share of a region's vectors; a motion holding less never replaces the larger consensus.
OTHER_MOTION_SHARE = 0.15
#: Consensus motions fitted per frame pair where the larger one may be an occluder's.
MAX_MOTIONS = 3
#: Occluders are looked for only in a layer whose pairs move its region at least this far (pixels, the median over
#: pairs) from the background's motion: an object that moves with the background (a parked car, a static shot's
#: still object) has nothing that tells it from a tree in front of it.
MIN_SEPARATION_PX = 2.0
#: A pair whose larger consensus moves the region less than this fraction of the layer's median separation from
#: the background's motion has the background's (or an occluder's) flow, not the object's ...
BACKGROUND_LIKE = 0.25
#: ... and is replaced by the next consensus that is at least this fraction of the separation away from the
#: background's (or, with none, by the object's previous motion relative to the background), when the whole
#: masks' boxes agree.
OBJECT_LIKE = 0.5
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


def _flow_vectors(flow: np.ndarray, ok: np.ndarray, region: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Reliable flow vectors (pixel centres and where they land, float32 [N, 2] each) inside ``region``, on a
    stride that gives about ``TARGET_POINTS`` of them."""
    h, w = ok.shape
    area = float(region.sum()) if region is not None else float(h * w)
    stride = int(np.clip(np.floor(np.sqrt(area / TARGET_POINTS)), 1, STRIDE))
    ys, xs = np.mgrid[stride // 2 : h : stride, stride // 2 : w : stride]
    sel = ok[ys, xs]
    if region is not None:
        sel &= region[ys, xs]
    src = np.stack((xs[sel] + 0.5, ys[sel] + 0.5), -1).astype(np.float32)
    return src, src + flow[ys[sel], xs[sel]].astype(np.float32)


def _least_squares_similarity(src: np.ndarray, dst: np.ndarray) -> np.ndarray | None:
    """The similarity (2x3) that moves ``src`` [N, 2] closest to ``dst`` in the least-squares sense; None when the
    points do not fix one (fewer than two distinct points)."""
    a = np.asarray(src, np.float64)
    b = np.asarray(dst, np.float64)
    if len(a) < 2 or not np.ptp(a, axis=0).any():
        return None
    # x' = p x - q y + tx, y' = q x + p y + ty: linear in (p, q, tx, ty)
    rows = np.zeros((2 * len(a), 4))
    rows[0::2] = np.c_[a[:, 0], -a[:, 1], np.ones(len(a)), np.zeros(len(a))]
    rows[1::2] = np.c_[a[:, 1], a[:, 0], np.zeros(len(a)), np.ones(len(a))]
    (p, q, tx, ty), *_ = np.linalg.lstsq(rows, b.reshape(-1), rcond=None)
    return np.array([[p, -q, tx], [q, p, ty]])


def _scale(m: np.ndarray) -> float:
    """The isotropic scale of a similarity (2x3)."""
    return float(np.sqrt(abs(np.linalg.det(m[:, :2]))))


def _scale_ok(m: np.ndarray) -> bool:
    return 1.0 / MAX_SCALE_STEP <= _scale(m) <= MAX_SCALE_STEP


def _fit_similarity(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """RANSAC similarity ``src`` -> ``dst`` and its inlier flags; None for too few inliers or an implausible scale."""
    if len(src) < MIN_POINTS:
        return None
    m, inliers = cv2.estimateAffinePartial2D(
        src,
        dst,
        method=cv2.RANSAC,
        ransacReprojThreshold=RANSAC_PX,
        maxIters=RANSAC_ITERATIONS,
        confidence=RANSAC_CONFIDENCE,
    )
    if m is None or inliers is None or int(inliers.sum()) < MIN_POINTS:
        return None
    m = m.astype(np.float64)
    return (m, inliers.reshape(-1).astype(bool)) if _scale_ok(m) else None


def _refined(
    m: np.ndarray, src: np.ndarray, dst: np.ndarray, background: np.ndarray, keep_scale: bool = True
) -> np.ndarray:
    """``m`` refitted to the flow vectors ``src`` -> ``dst`` within ``REFINE_PX`` of it and nearer it than the
    ``background`` motion (up to ``REFINE_ROUNDS`` times): the least-squares similarity, at ``m``'s scale with
    ``keep_scale`` (its rotation, then the translation that fits those vectors best). A deforming object moves as a
    whole, and the background's vectors inside its mask stay out however near the object's motion is to the
    background's."""
    a, b = src.astype(np.float64), dst.astype(np.float64)
    off_background = np.linalg.norm(a @ background[:, :2].T + background[:, 2] - b, axis=-1)
    scale = _scale(m)
    for _ in range(REFINE_ROUNDS):
        off = np.linalg.norm(a @ m[:, :2].T + m[:, 2] - b, axis=-1)
        near = (off < REFINE_PX) & (off < off_background)
        fitted = _least_squares_similarity(a[near], b[near]) if near.sum() >= MIN_POINTS else None
        if fitted is None or not _scale_ok(fitted):
            break
        if keep_scale:
            linear = fitted[:, :2] * (scale / _scale(fitted))
            fitted = np.c_[linear, (b[near] - a[near] @ linear.T).mean(0)]
        m = fitted
    return m


def _size_error(to_ref: np.ndarray, areas: list[int]) -> float:
    """How far a chained motion ``to_ref`` [T, 2, 3] puts the object's size from the size its masks show: the median
    over the frames with a mask (``areas`` > 0) of |log| of the ratio between the motion's scale relative to the first
    such frame and the square root of the masks' area ratio. 0 with fewer than two such frames."""
    frames = [t for t, area in enumerate(areas) if area > 0]
    if len(frames) < 2:
        return 0.0
    size = np.array([1.0 / max(_scale(to_ref[t]), 1e-12) for t in frames])  # frame pixels per reference pixel
    shown = np.sqrt(np.array([areas[t] for t in frames], np.float64) / areas[frames[0]])
    return float(np.median(np.abs(np.log(size[1:] / size[0] / shown[1:]))))


@dataclass
class _PairFit:
    """The consensus motions of one frame pair's flow inside a region (frame t -> t+1 pixels, largest consensus
    first, each with its share of the region's flow vectors) and the region's sampled pixels."""

    motions: list[tuple[np.ndarray, float]]
    points: np.ndarray
    targets: np.ndarray  # where the flow takes ``points``

    @property
    def first(self) -> np.ndarray:
        """The larger consensus: the pair's motion unless an occluder's flow outvotes the object's; identity when the
        flow gives none."""
        return self.motions[0][0] if self.motions else np.eye(2, 3)


def _pair_fit(flow: np.ndarray, ok: np.ndarray, region: np.ndarray | None, count: int = 1) -> _PairFit:
    """Up to ``count`` consensus motions, each fitted (RANSAC) to the vectors the ones before leave out, while those
    are at least ``OTHER_MOTION_SHARE`` of the region's: a loose mask over an object and the tree it passes behind
    holds two motions, and the larger one can be the tree's."""
    src, dst = _flow_vectors(flow, ok, region)
    motions: list[tuple[np.ndarray, float]] = []
    rest = np.ones(len(src), bool)
    while len(motions) < count and rest.sum() >= max(MIN_POINTS, OTHER_MOTION_SHARE * len(src)):
        fitted = _fit_similarity(src[rest], dst[rest])
        if fitted is None:
            break
        m, inliers = fitted
        motions.append((m, float(inliers.sum()) / len(src)))
        rest[np.nonzero(rest)[0][inliers]] = False
    return _PairFit(motions, src, dst)


def _apart(a: np.ndarray, b: np.ndarray, points: np.ndarray) -> float:
    """Median distance (pixels) between where the motions ``a`` and ``b`` (2x3) move ``points``; nan without points."""
    if not len(points):
        return float("nan")
    d = points.astype(np.float64) @ (a[:, :2] - b[:, :2]).T + (a[:, 2] - b[:, 2])
    return float(np.median(np.linalg.norm(d, axis=-1)))


def _box_centre(mask: np.ndarray | None) -> np.ndarray | None:
    """Centre of a mask's bounding box (pixels); None for no mask. The box of a whole mask follows the object even
    where a trunk cuts through it, and stays put when the object stops."""
    if mask is None or not mask.any():
        return None
    ys, xs = np.nonzero(mask)
    return np.array([(xs.min() + xs.max() + 1) / 2.0, (ys.min() + ys.max() + 1) / 2.0])


def pair_motions(to_ref: np.ndarray) -> list[np.ndarray]:
    """The pair motions S_t (frame t -> t+1 pixels) of a chain ``to_ref`` [T, 2, 3]: ``chain_motion``'s inverse."""
    return [(np.linalg.inv(_h(to_ref[t + 1])) @ _h(to_ref[t]))[:2] for t in range(to_ref.shape[0] - 1)]


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


def _regions_and_fits(
    flow: FlowField,
    regions: list[np.ndarray | None],
    choose: Callable[[int, _PairFit, list[np.ndarray]], np.ndarray],
    size: tuple[int, int],
    count: int = 1,
    known: list[_PairFit] | None = None,
) -> tuple[list[np.ndarray], list[_PairFit]]:
    """Each pair's motion (``choose(t, fit, pairs so far)``) and its ``count`` consensus motions, in order. A frame
    without a region (a mask left out) takes the previous region carried by the motion chosen for the previous pair.
    ``known``: fits already made, reused for the frames that have a region of their own."""
    regions = list(regions)
    pairs: list[np.ndarray] = []
    fits: list[_PairFit] = []
    for t in range(len(regions) - 1):
        region = regions[t]
        if known is not None and region is not None:
            fit = known[t]
        else:
            last = regions[t - 1] if t else None
            if region is None and last is not None:
                # a frame without a mask (skipped in the roto, dropped by a detector): the object is where its own
                # motion carried the last region. Without it that pair fitted the whole frame, which is the
                # camera's motion, and every later frame of the object's atlas was displaced by it.
                region = _carried(last, pairs[-1], size)
                regions[t] = region
            fit = _pair_fit(flow.forward[t], flow.forward_ok[t], region, count)
        fits.append(fit)
        pairs.append(choose(t, fit, pairs))
    return pairs, fits


def _larger(t: int, fit: _PairFit, done: list[np.ndarray]) -> np.ndarray:
    return fit.first


def _object_pairs(
    flow: FlowField,
    regions: list[np.ndarray | None],
    fits: list[_PairFit],
    boxes: list[np.ndarray | None],
    areas: list[int],
    background: list[np.ndarray],
    size: tuple[int, int],
) -> list[np.ndarray] | None:
    """The pair motions of an object that moves apart from the background, with an occluder's flow set aside and,
    for an object that deforms (``RIGID_SHARE``), each motion refined to the object's as a whole (``_refined``);
    None when the layer does not move apart from the background. ``fits``: each pair's consensus motions in
    ``regions``, frames without a mask in the regions the larger consensus carried.

    A loose mask over an object that passes behind a tree trunk (or a bush, a post) holds the trunk's flow too, and
    behind the trunk that is the larger consensus: the pair follows the background, and every later frame of the
    object's atlas is displaced by the difference (bmx-trees: 20-28 px in each of three pairs behind the trees). Such
    a pair stands out against the layer's own pairs: its larger consensus moves the region with the background
    (``BACKGROUND_LIKE``) where the layer's pairs typically move it apart. Its motion is then the next consensus
    that moves apart from the background (``OBJECT_LIKE``), or with none, the object's previous motion relative to
    the background; kept only when it carries the whole mask's box onto the next frame's no worse than the larger
    consensus, so an object that stops is not driven on. ``areas``: the whole masks' pixel counts (0: no mask), the
    size the refit's scale is judged by (``_size_error``).
    """
    apart = [_apart(fit.first, background[t], fit.points) if fit.motions else np.nan for t, fit in enumerate(fits)]
    if np.all(np.isnan(apart)) or not float(np.nanmedian(apart)) >= MIN_SEPARATION_PX:
        return None
    typical = float(np.nanmedian(apart))
    deforms = float(np.median([fit.motions[0][1] for fit in fits if fit.motions])) < RIGID_SHARE

    def choose(t: int, fit: _PairFit, done: list[np.ndarray], keep_scale: bool = True) -> np.ndarray:
        def whole(m: np.ndarray) -> np.ndarray:
            return _refined(m, fit.points, fit.targets, background[t], keep_scale) if deforms else m

        first = fit.first
        if not fit.motions:
            return first
        if not _apart(first, background[t], fit.points) < BACKGROUND_LIKE * typical:
            return whole(first)
        others = [
            m
            for m, share in fit.motions[1:]
            if share >= OTHER_MOTION_SHARE and _apart(m, background[t], fit.points) >= OBJECT_LIKE * typical
        ]
        if others:
            option = whole(others[0])
        elif t:  # the object keeps its motion relative to the camera through the frames the occluder hides it in
            option = (_h(background[t]) @ np.linalg.inv(_h(background[t - 1])) @ _h(done[-1]))[:2]
        else:
            return first
        here, there = boxes[t], boxes[t + 1]
        if here is not None and there is not None:
            miss = [float(np.linalg.norm(m[:, :2] @ here + m[:, 2] - there)) for m in (first, option)]
            if miss[1] > miss[0]:
                return first
        return option

    chosen, _ = _regions_and_fits(flow, regions, choose, size, MAX_MOTIONS, fits)
    if deforms:  # the least-squares scale too, where it keeps the object nearer the size its masks show
        scaled, _ = _regions_and_fits(flow, regions, partial(choose, keep_scale=False), size, MAX_MOTIONS, fits)
        if _size_error(chain_motion(scaled), areas) < _size_error(chain_motion(chosen), areas):
            return scaled
    return chosen


def estimate_layer_motion(
    flow: FlowField | None,
    region_masks: np.ndarray | None,
    size: tuple[int, int],
    fit_motion: bool = True,
    margin: float = 0.06,
    extent_masks: np.ndarray | None = None,
    background: LayerMotion | None = None,
) -> LayerMotion:
    """Per-frame similarity to the reference frame for one layer.

    ``region_masks`` (bool [T, H, W]) selects the layer's pixels (None = whole frame); the atlas extent
    covers where those pixels land (the whole frame when a mask frame is empty), or where ``extent_masks``
    land when given (a scribbled part: its motion from its scribbles, its extent from the whole object's).
    A frame without a region (a mask left out) fits its pair inside the previous region carried by the layer's
    own motion; frames before the first region use the first one. ``background`` (the background layer's motion),
    for a layer that moves apart from it: each pair's motion is the object's as a whole, refined apart from the
    background's, and a pair whose flow follows the background where the layer's pairs typically do not (an
    occluder inside a loose mask) takes the object's motion instead (``_object_pairs``).
    """
    w, h = size
    t_count = 1 if flow is None else flow.forward.shape[0] + 1
    if region_masks is not None:
        t_count = region_masks.shape[0]
    regions: list[np.ndarray | None] = [None] * t_count if region_masks is None else _first_regions(region_masks)
    if not fit_motion or flow is None:
        pairs = [np.eye(2, 3) for _ in range(t_count - 1)]
    else:
        behind = None if background is None or region_masks is None else pair_motions(background.to_ref)
        pairs, fits = _regions_and_fits(flow, regions, _larger, (w, h), 1 if behind is None else MAX_MOTIONS)
        if behind is not None and region_masks is not None:
            whole = region_masks if extent_masks is None else extent_masks
            boxes = [_box_centre(m) for m in whole]
            areas = [int(np.count_nonzero(m)) for m in whole]
            chosen = _object_pairs(flow, regions, fits, boxes, areas, behind, (w, h))
            pairs = pairs if chosen is None else chosen
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
