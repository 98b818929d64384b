"""Parts of one masked object from how they move: scribbles the fit splits the object's layer by.

One layer holds an object well while the object moves as one piece. A limb that swings in front of the body does
not: one smooth mapping cannot fold the limb over the body it covers, so the alpha drops the limb or the atlas
smears it (a jumping body's limb: foreground IoU 0.84 at ``balanced``; given a layer per part, 0.995). The product
already splits an object by the user's scribbles (``fit --scribbles``, paper Sec. 4.4); this module draws those
scribbles from the motion itself, for the artist to check and fix as they would their own strokes.

On a few key frames spread over the clip, points on a grid inside the mask are followed ``gap`` frames along the
optical flow (forwards, backwards near the end), dropped where the flow fails its round trip or leaves the mask.
Affine motions are fitted to the displacements one after the other with RANSAC (``cv2.estimateAffine2D``): the
largest part first, then the largest of what it leaves, and so on. A point belongs to a part when that part's
motion explains it within ``threshold_px`` and every other part's misses it by ``separation`` times that: points
near a joint, which every motion explains, stay unlabelled; a key frame where the parts label less than
``min_labelled`` of the points has no clear split. A part needs ``min_share`` of the followed points; the
labelled grid is filled, cleaned of small islands and kept ``inset_px`` inside its part, so a stroke never reaches a
boundary the motion cannot place. Parts are numbered by size at each key frame (the body is part 0, Foreground1):
a limb is smaller than the body it swings from. The object is split when at least ``min_frames`` key frames, and at
least ``min_agreement`` of all of them, find the same number of parts, two or more; key frames finding another
number get no strokes. An object the flow follows on fewer key frames is not split: too little is known of how it
moves, and on real footage a split found on only some frames (a man vaulting a wall, a dancer spinning) follows the
body worse than one layer does (docs/accuracy-vs-time.md).

Conventions as in ``engine.data.flow``: pixel ``[y, x]`` is the point ``(x, y)``; masks are bool [T, H, W];
labels are ``engine.data.scribbles``' (0-based foreground layer, ``NO_LABEL``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from .flow import FlowField, sample_points
from .scribbles import NO_LABEL


@dataclass(frozen=True)
class PartsConfig:
    """How motion is turned into part strokes. Pixel sizes are at the working resolution of the flow."""

    key_frames: int = 6
    """Frames with strokes, spread evenly from the first to the last (strokes on six frames split a body about as
    well as part masks on every frame do: ``docs/accuracy-vs-time.md``)."""
    gap: int = 3
    """Frames each point is followed: long enough that a swinging limb moves a few pixels off the body's motion,
    short enough that the chained flow holds."""
    stride: int = 2
    """Grid step of the followed points, in pixels."""
    threshold_px: float = 3.0
    """A part's affine motion explains a point within this many pixels (RANSAC's inlier threshold)."""
    separation: float = 2.0
    """A point is labelled only when every other part's motion misses it by this many times ``threshold_px``."""
    max_parts: int = 3
    """Parts found at most (the body and two limbs); ``contract.SCRIBBLE_COLOURS`` has a colour for each."""
    min_share: float = 0.05
    """A part needs this share of the followed points (labelled), else its points go back to no label."""
    min_labelled: float = 0.3
    """A key frame whose parts label less than this share of the followed points has no clear split (most points
    explained by no motion, or by several): it counts as one piece."""
    min_points: int = 60
    """Fewer followed points than this on a key frame: it is not judged (too small or too occluded)."""
    min_frames: int = 2
    """Key frames that must agree on the number of parts for the object to be split."""
    min_agreement: float = 0.75
    """... and the share of all key frames that must (five of six): a limb that swings apart all through the clip
    is found on every key frame but where it turns back; parts found on half of them were measured to cost the
    paint more than they gave."""
    inset_px: int = 2
    """Strokes stay this many pixels inside their part's labelled region (and the mask)."""
    min_area_px: int = 30
    """A stroke region smaller than this (after filling and inset) is dropped: an island of flow noise."""


@dataclass
class KeyFrame:
    """What one key frame found."""

    frame: int
    followed: int
    """Points followed ``gap`` frames (0: the mask is empty there)."""
    shares: list[float] = field(default_factory=list)
    """Per part found (largest first), its share of the followed points labelled to it."""


@dataclass
class MotionParts:
    """Strokes ``labels`` (int8 [T, H, W]) and what each key frame found; ``parts`` 0 or 1: nothing to split."""

    labels: np.ndarray
    parts: int
    key_frames: list[KeyFrame]
    needed: int = 0
    """Key frames that had to agree for a split (``min_frames``, ``min_agreement``)."""

    @property
    def found(self) -> bool:
        return self.parts >= 2

    @property
    def message(self) -> str:
        judged = [k for k in self.key_frames if k.followed]
        if not self.found:
            split = sum(1 for k in judged if len(k.shares) >= 2)
            return (
                f"no parts move apart on at least {self.needed} of {len(self.key_frames)} key frames "
                f"(split on {split}): the object moves as one piece, nothing to split"
            )
        agree = [k for k in judged if len(k.shares) == self.parts]
        frames = ", ".join(str(k.frame) for k in agree)
        return f"{self.parts} parts that move apart, strokes on {len(agree)} frame(s) ({frames})"


def key_frame_positions(has_mask: np.ndarray, count: int) -> list[int]:
    """``count`` frames spread evenly from the first to the last, each moved to the nearest frame with a mask
    (``has_mask``, bool [T]) not taken yet; fewer on a short clip or one with few masks."""
    frames = len(has_mask)
    if frames <= 0 or count <= 0:
        return []
    free = set(np.flatnonzero(has_mask).tolist())
    out = []
    for i in range(count):
        want = i * (frames - 1) / max(count - 1, 1)
        if not free:
            break
        pick = min(free, key=lambda f: (abs(f - want), f))
        free.discard(pick)
        out.append(pick)
    return sorted(out)


def follow(
    flow: FlowField, masks: np.ndarray, start: int, steps: int, pts: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The points [N, 2] of frame ``start`` followed ``steps`` frames (negative: backwards) along the flow: their
    positions there and bool [N], False where the flow failed its round trip (at the nearest pixel), left the frame
    or left the mask of a frame passed (a frame without a mask does not judge)."""
    h, w = masks.shape[1:]
    pos = pts.astype(np.float64).copy()
    ok = np.ones(len(pts), dtype=bool)
    t = start
    direction = 1 if steps > 0 else -1
    for _ in range(abs(steps)):
        if direction > 0:
            vec, good = flow.forward[t], flow.forward_ok[t]
        else:
            vec, good = flow.backward[t - 1], flow.backward_ok[t - 1]
        xi = np.clip(np.rint(pos[:, 0]).astype(int), 0, w - 1)
        yi = np.clip(np.rint(pos[:, 1]).astype(int), 0, h - 1)
        ok &= good[yi, xi]
        pos = pos + sample_points(np.ascontiguousarray(vec, dtype=np.float32), pos)
        t += direction
        inside = (pos[:, 0] >= 0) & (pos[:, 0] <= w - 1) & (pos[:, 1] >= 0) & (pos[:, 1] <= h - 1)
        ok &= inside & np.isfinite(pos).all(1)
        if masks[t].any():  # a frame without a mask (not drawn there) says nothing about where the object is
            xi = np.clip(np.rint(pos[:, 0]).astype(int), 0, w - 1)
            yi = np.clip(np.rint(pos[:, 1]).astype(int), 0, h - 1)
            ok &= masks[t, yi, xi]
    return pos, ok


def _residual(model: np.ndarray, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Pixels by which the affine ``model`` [2, 3] misses each correspondence."""
    return np.linalg.norm(src @ model[:, :2].T + model[:, 2] - dst, axis=1)


def split_motion(src: np.ndarray, dst: np.ndarray, cfg: PartsConfig) -> np.ndarray:
    """int [N]: the part of each correspondence (``src`` -> ``dst``, [N, 2]), largest part 0, or NO_LABEL where
    no motion owns it clearly (see the module docstring). All NO_LABEL when fewer than two parts hold."""
    n = len(src)
    labels = np.full(n, NO_LABEL, dtype=np.int64)
    models: list[np.ndarray] = []
    rest = np.arange(n)
    min_part = max(3, int(np.ceil(cfg.min_share * n)))
    for _ in range(cfg.max_parts):
        if len(rest) < min_part:
            break
        model, inliers = cv2.estimateAffine2D(
            src[rest], dst[rest], method=cv2.RANSAC, ransacReprojThreshold=cfg.threshold_px, maxIters=2000,
            confidence=0.995, refineIters=10,
        )  # fmt: skip
        if model is None or inliers is None or int(inliers.sum()) < min_part:
            break
        models.append(model)
        rest = rest[~inliers.ravel().astype(bool)]
    if len(models) < 2:
        return labels
    res = np.stack([_residual(m, src, dst) for m in models], axis=1)
    order = np.sort(res, axis=1)
    best = np.argmin(res, axis=1)
    clear = (order[:, 0] <= cfg.threshold_px) & (order[:, 1] > cfg.separation * cfg.threshold_px)
    labels[clear] = best[clear]
    counts = np.bincount(labels[clear], minlength=len(models))
    kept = [k for k in np.argsort(-counts, kind="stable") if counts[k] >= min_part]
    if len(kept) < 2:
        return np.full(n, NO_LABEL, dtype=np.int64)
    remap = np.full(len(models), NO_LABEL, dtype=np.int64)
    remap[kept] = np.arange(len(kept))
    return np.where(labels >= 0, remap[np.maximum(labels, 0)], NO_LABEL)


def strokes(mask: np.ndarray, pts: np.ndarray, labels: np.ndarray, parts: int, cfg: PartsConfig) -> np.ndarray:
    """int8 [H, W]: the labelled grid points filled into regions (one grid step), kept ``inset_px`` inside their
    region and the mask, islands under ``min_area_px`` dropped; NO_LABEL elsewhere and where regions touch."""
    h, w = mask.shape
    out = np.full((h, w), NO_LABEL, dtype=np.int8)
    grid = cv2.getStructuringElement(cv2.MORPH_RECT, (cfg.stride + 1, cfg.stride + 1))
    inset = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * cfg.inset_px + 1, 2 * cfg.inset_px + 1))
    inner = cv2.erode(mask.astype(np.uint8), inset) > 0
    regions = []
    for k in range(parts):
        seeds = np.zeros((h, w), np.uint8)
        on = pts[labels == k]
        seeds[np.rint(on[:, 1]).astype(int), np.rint(on[:, 0]).astype(int)] = 1
        filled = cv2.morphologyEx(cv2.dilate(seeds, grid), cv2.MORPH_CLOSE, grid)
        regions.append(cv2.erode(filled, inset) > 0)
    overlap = np.sum(regions, axis=0) > 1
    for k, region in enumerate(regions):
        region = region & inner & ~overlap
        _, comp, stats, _ = cv2.connectedComponentsWithStats(region.astype(np.uint8), connectivity=8)
        big = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] >= cfg.min_area_px)
        keep = np.isin(comp, big[big > 0])
        out[keep] = k
    return out


def motion_parts(masks: np.ndarray, flow: FlowField, cfg: PartsConfig | None = None) -> MotionParts:
    """Strokes that split the one object of ``masks`` (bool [T, H, W]) into the parts that move apart, from
    ``flow`` (the clip's adjacent flow at the masks' resolution); all NO_LABEL when it moves as one piece."""
    cfg = PartsConfig() if cfg is None else cfg
    t_count, h, w = masks.shape
    labels = np.full((t_count, h, w), NO_LABEL, dtype=np.int8)
    found: list[tuple[KeyFrame, np.ndarray, np.ndarray]] = []
    if t_count < 2:
        return MotionParts(labels, 0, [])
    steps_max = min(cfg.gap, t_count - 1)
    shrink = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * cfg.inset_px + 1, 2 * cfg.inset_px + 1))
    for t in key_frame_positions(masks.reshape(t_count, -1).any(1), cfg.key_frames):
        inner = cv2.erode(masks[t].astype(np.uint8), shrink) > 0
        ys, xs = np.nonzero(inner[:: cfg.stride, :: cfg.stride])
        pts = np.stack([xs * cfg.stride, ys * cfg.stride], axis=1).astype(np.float64)
        steps = steps_max if t + steps_max <= t_count - 1 else -steps_max
        key = KeyFrame(t, 0)
        if len(pts) >= cfg.min_points:
            dst, ok = follow(flow, masks, t, steps, pts)
            key.followed = int(ok.sum())
            if key.followed >= cfg.min_points:
                lab = np.full(len(pts), NO_LABEL, dtype=np.int64)
                lab[ok] = split_motion(pts[ok], dst[ok], cfg)
                parts = int(lab.max()) + 1
                shares = [float(np.mean(lab[ok] == k)) for k in range(parts)]
                if parts < 2 or sum(shares) < cfg.min_labelled:
                    lab[:] = NO_LABEL
                    shares = []
                key.shares = shares
                found.append((key, pts, lab))
                continue
        found.append((key, pts, np.full(len(pts), NO_LABEL, dtype=np.int64)))
    judged = [k for k, _, _ in found if k.followed >= cfg.min_points]
    counts = np.bincount([len(k.shares) for k in judged], minlength=cfg.max_parts + 1) if judged else np.zeros(1)
    counts[:2] = 0  # one piece (or none) is not a split
    parts = int(np.argmax(counts))
    # a share of every key frame, not of those followed: an object the flow loses on most frames is not split
    needed = max(cfg.min_frames, int(np.ceil(cfg.min_agreement * len(found))))
    if parts == 0 or counts[parts] < needed:
        return MotionParts(labels, 1 if judged else 0, [k for k, _, _ in found], needed)
    for key, pts, lab in found:
        if len(key.shares) == parts:
            labels[key.frame] = strokes(masks[key.frame], pts, lab, parts, cfg)
    return MotionParts(labels, parts, [k for k, _, _ in found], needed)


__all__ = ["KeyFrame", "MotionParts", "PartsConfig", "follow", "key_frame_positions", "motion_parts", "split_motion"]
