"""Loose masks snapped to the object's outline: how far a mask is trusted, measured on the clip itself.

Masks from an artist's quick roto, a detector or a garbage matte are drawn loose: typically a few to a dozen pixels
outside the object all round (or inside it). The fit copies what it is taught: with the DAVIS masks dilated by
10 px, a draft fit's foreground alpha came out as wide as the mask (blackswan: IoU 0.74 against the precise masks,
the mask itself 0.72), and the ring of background it carried made points on the swan follow the water.

An object's outline is where the image has edges, so the offset at which the mask's outline meets the strongest
edges says how loose the mask is. For each offset d (pixels, negative inside) the mean image-gradient magnitude
along the mask's level line at signed distance d is averaged over every frame of the layer; a mask drawn on the
object peaks at the layers next to its own outline (d = -1 or +1), a mask dilated by 10 px peaks near d = -9. When
a line is clearly stronger than the edges along the mask's own outline (``SNAP_CONTRAST``), the mask is moved to the
first such edge met going inward (or outward; ``best_offset``): shrunk to the pixels within d of the inside, or grown
by d. It moves only when its own outline runs through what lies beyond it (a precise outline is itself an edge),
so neither a precise mask nor a small textured object's interior lines can move it. A clip-wide offset (per mask
layer) is robust where a per-frame one would chase texture: one frame's background edges cannot move it.

Measured at 768x432 against the precise DAVIS masks (docs/bench/experiments.md): masks dilated by 10 px go from
IoU 0.72 / 0.44 / 0.53 / 0.83 (blackswan, bmx-trees, libby, car-roundabout) to 0.97 / 0.73 / 0.90 / 0.99, and the
precise masks themselves are left as they are.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: The peak's edge strength must be at least this many times the mean edge strength along the mask's own outline
#: (the level lines at -1 and +1) for the mask to move: a dilated mask's peak is about 3x, a precise mask's own
#: outline is the peak itself.
SNAP_CONTRAST = 1.5
#: Level lines, from the first one strong enough on, among which the outline goes to the strongest: an object's
#: edge, blurred by motion and resampling, rises over a few pixels to its peak.
PEAK_WINDOW = 3
#: A mask's own outline counts as an edge (the mask is drawn on the object that way) when it is this many times as
#: strong as the median of the level lines at least ``FAR_LINE`` pixels to the other side: blackswan's precise
#: outline is 2.7x the water beyond it, a mask dilated by 10 px 1.0x, car-roundabout's 1.1x (its background is busy).
OUTLINE_EDGE = 1.3
#: The lines nearer than this to the outline carry its blur (the Sobel kernel, anti-aliasing) and are left out of
#: what lies beyond it.
FAR_LINE = 3


@dataclass
class MaskSnap:
    """What the snap found for one mask layer: ``offset_px`` (0: left as drawn; negative: shrunk), the edge
    profile it was read from (``offsets`` and ``strength``, mean gradient magnitude per level line) and the frames
    where the shrunk mask would have been empty, which keep the mask as drawn."""

    offset_px: int
    offsets: list[int]
    strength: list[float]
    kept_frames: list[int]


def signed_distance(mask: np.ndarray) -> np.ndarray:
    """float32 [H, W]: distance to the mask's outline, negative inside (the pixels next to the outline are -1 and
    +1; no pixel is 0). A mask without an outline (empty, or covering the whole frame) is +inf / -inf everywhere:
    the distance transform has no zero pixel to measure from there."""
    if not mask.any() or mask.all():
        return np.full(mask.shape, -np.inf if mask.any() else np.inf, dtype=np.float32)
    m = mask.astype(np.uint8)
    return cv2.distanceTransform(1 - m, cv2.DIST_L2, 5) - cv2.distanceTransform(m, cv2.DIST_L2, 5)


def edge_strength(frame: np.ndarray) -> np.ndarray:
    """float32 [H, W]: colour gradient magnitude (3x3 Sobel, summed over channels) of a frame, clipped to the
    display range first so an HDR highlight does not outweigh every outline."""
    img = np.clip(np.nan_to_num(np.asarray(frame, dtype=np.float32)), 0.0, 1.0)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3)
    mag = np.sqrt(gx * gx + gy * gy)
    return mag.sum(-1) if mag.ndim == 3 else mag


def edge_profile(frames: np.ndarray, masks: np.ndarray, reach_px: int) -> tuple[list[int], np.ndarray]:
    """The mean edge strength along each level line -reach..reach (but 0) of one layer's masks ([T, H, W]) over
    the frames that have a mask; NaN for a line no pixel lies on (deeper inside than the thickest part)."""
    offsets = [d for d in range(-reach_px, reach_px + 1) if d != 0]
    total = np.zeros(2 * reach_px + 1)
    count = np.zeros(2 * reach_px + 1)
    for t in range(masks.shape[0]):
        if not masks[t].any() or masks[t].all():
            continue  # no outline: no mask, or one covering the frame
        # the level line at d is the pixels whose signed distance rounds to d: one bincount for every line
        line = np.rint(signed_distance(masks[t])).astype(np.int64).ravel()
        near = np.abs(line) <= reach_px
        idx = line[near] + reach_px
        total += np.bincount(idx, weights=edge_strength(frames[t]).ravel()[near], minlength=total.size)
        count += np.bincount(idx, minlength=count.size)
    keep = np.array([d + reach_px for d in offsets])
    with np.errstate(invalid="ignore", divide="ignore"):
        return offsets, np.where(count[keep] > 0, total[keep] / np.maximum(count[keep], 1.0), np.nan)


def best_offset(offsets: list[int], strength: np.ndarray) -> int:
    """The offset the outline moves by: 0 (a precise mask, a clip without edges, no mask) unless some level line
    is at least ``SNAP_CONTRAST`` times as strong as the mask's own outline (the lines at -1 and +1).

    Scanning from the outline inward (and, separately, outward), the first line that strong is where the object's
    edge begins: between a loose mask's outline and the object lies only background, and the object's own texture
    lies beyond its edge. So the outline moves to the strongest of the ``PEAK_WINDOW`` lines from that first one on,
    not to the profile's global maximum, which a textured object's interior can hold. When both directions find an
    edge, the nearer wins (the stronger, if as near).

    A mask is only shrunk when its own outline runs through what lies outside it (as strong as the lines beyond
    ``FAR_LINE``: a dilated mask's outline is on background), and only grown when it runs through what lies inside
    (an eroded mask's outline is on the object): a precise mask's outline is an edge, stronger than both by
    ``OUTLINE_EDGE``, so a small textured object's interior lines, stronger still, cannot move it. Lines no pixel
    lies on (NaN) are skipped."""
    at = {d: float(v) for d, v in zip(offsets, strength, strict=True) if np.isfinite(v)}
    if -1 not in at or 1 not in at:
        return 0
    own = 0.5 * (at[-1] + at[1])
    found: list[tuple[int, float, int]] = []
    for step in (-1, 1):
        beyond = [v for d, v in at.items() if d * step < 0 and abs(d) >= FAR_LINE]
        if not beyond or own >= OUTLINE_EDGE * float(np.median(beyond)):
            continue  # the outline is an edge against that side: the mask is not loose that way
        d = 2 * step
        while d in at:
            if at[d] > 0 and at[d] >= SNAP_CONTRAST * own:
                window = [d + k * step for k in range(PEAK_WINDOW) if d + k * step in at]
                peak = max(window, key=lambda x: at[x])
                found.append((abs(peak), -at[peak], peak))
                break
            d += step
    return min(found)[2] if found else 0


def snap_masks(frames: np.ndarray, masks: np.ndarray, reach_px: int) -> tuple[np.ndarray, list[MaskSnap]]:
    """Each mask layer of ``masks`` (bool [F, T, H, W]) moved to the outline its clip's edges show (module
    docstring), searching ``reach_px`` pixels either side. ``reach_px`` < 2 or no mask: unchanged."""
    out = np.array(masks, dtype=bool, copy=True)
    snaps: list[MaskSnap] = []
    for f in range(masks.shape[0]):
        if reach_px < 2 or not masks[f].any():
            snaps.append(MaskSnap(0, [], [], []))
            continue
        offsets, strength = edge_profile(frames, masks[f], reach_px)
        d = best_offset(offsets, strength)
        kept = []
        if d:
            for t in range(masks.shape[1]):
                if not masks[f, t].any():
                    continue
                # the level line at d is the new outline's last pixel: inside for a shrink, outside for a growth
                moved = signed_distance(masks[f, t]) <= d
                if moved.any():
                    out[f, t] = moved
                else:
                    kept.append(t)
        snaps.append(MaskSnap(d, offsets, [round(float(s), 4) for s in strength], kept))
    return out, snaps


__all__ = [
    "FAR_LINE",
    "OUTLINE_EDGE",
    "PEAK_WINDOW",
    "SNAP_CONTRAST",
    "MaskSnap",
    "best_offset",
    "edge_profile",
    "edge_strength",
    "signed_distance",
    "snap_masks",
]
