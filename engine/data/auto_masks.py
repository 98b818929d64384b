"""Coarse foreground masks from motion alone, for a user who has no masks (no model weights involved).

Per adjacent frame pair the dominant (camera) motion is a homography fitted with RANSAC to the reliable
flow vectors (those that survive the forward-backward round trip); a pixel is *moving* where its flow
departs from that homography by more than the flow's own noise (measured on the reliable pixels, never
below a floor). Every frame is judged in both directions (towards t+1 and towards t-1): the background
that the object uncovers or covers fails the round trip in one direction only, so the other decides and
the masks do not smear along the motion. Votes of the neighbouring frames are pulled into each frame
through the flow and averaged, then cleaned (opening, closing, holes filled, small blobs dropped) and a
blob is kept only if a neighbouring frame also sees it (a one-frame flicker is flow noise, not an object).

A camera whose homographies move no pixel by more than ``static_camera_px`` is *static*: every pair then
uses the identity, so the foreground is simply what moves. Nothing moving gives empty masks and a
"no foreground found" message (the caller fits a background-only atlas); a single frame has no flow and
gives no masks.

Conventions as in ``engine.data.flow``: pixel ``[y, x]`` is the point ``(x, y)``; masks are bool [T, H, W].

The masks are written by ``engine.data.mask_files``: all or nothing, never over an existing file.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from .. import contract as C
from ..errors import InputError
from ..io.clip import open_clip, read_frames, read_masks, working_size
from ..io.colour import to_working
from .flow import DISFlow, FlowField, compute_flow
from .mask_files import already_holds, holds_the_same, mask_folder, write_mask_files

#: Fewer reliable flow vectors than this in a pair: no homography is fitted and the pair casts no vote.
MIN_POINTS = 50
#: About this many flow vectors (on a regular grid) go into each RANSAC fit.
TARGET_POINTS = 4000
#: Median residual -> standard deviation of Gaussian noise (1 / Phi^-1(3/4)).
MAD_TO_SIGMA = 1.4826
#: Lowest residual threshold (px) whatever the config says: the divisor of every residual score.
MIN_THRESHOLD_PX = 1e-3
#: Guard for the vote normalisation where no neighbour reaches a pixel (its total weight is 0).
MIN_WEIGHT = 1e-6
#: A pair counts as static when its homography moves no grid point by more than the config's limit;
#: the camera is static when at least this fraction of the pairs are.
STATIC_PAIR_FRACTION = 0.8
#: GrabCut draws its colour models' starting clusters from OpenCV's process-wide random generator; it is reset to
#: this seed before the refinement, so the masks do not depend on earlier calls (0: OpenCV's own initial state,
#: what the first call in a process has always seen).
GRABCUT_SEED = 0


@dataclass(frozen=True)
class AutoMaskConfig:
    """How motion is turned into masks. Pixel sizes are at the analysis resolution (``long_edge``)."""

    long_edge: int = 512
    """Long edge (px) of the resolution the motion is analysed at; masks are then resized to the clip's."""
    flow_preset: str = "medium"
    """DIS preset of the flow (``ultrafast``, ``fast``, ``medium``)."""
    flow_threshold_px: float = 1.0
    """Forward-backward round-trip error (px) under which a flow vector is reliable."""
    ransac_px: float = 1.0
    """RANSAC inlier threshold (px) of the background homography."""
    residual_sigmas: float = 6.0
    """A pixel moves when its residual exceeds this many noise standard deviations of the reliable flow..."""
    min_residual_px: float = 1.0
    """...and at least this many pixels (so a perfectly clean flow does not turn noise into objects)."""
    unreliable_weight: float = 0.5
    """Weight of a vote from a pixel whose flow fails the round trip in both directions (motion blur,
    deforming parts): it still counts, but less than a reliable one."""
    window: int = 2
    """Neighbouring frames on each side whose votes are pulled in through the flow and averaged."""
    vote_threshold: float = 0.4
    """A pixel is foreground when the weighted mean vote over the window exceeds this."""
    open_px: int = 2
    """Radius (px) of the opening that removes specks."""
    close_px: int = 6
    """Radius (px) of the closing that joins the parts of one object."""
    min_area_fraction: float = 0.001
    """Blobs smaller than this fraction of the frame are dropped."""
    persist_overlap: float = 0.2
    """A blob survives when at least this fraction of it is foreground in a neighbouring frame (pulled in
    through the flow); with a single neighbour-less frame nothing survives."""
    static_camera_px: float = 0.3
    """A pair whose homography moves no pixel by more than this is static (camera on a tripod)."""
    refine_iterations: int = 3
    """GrabCut iterations that snap each motion mask to the colour edges (0 = no refinement). Flow bleeds
    over textureless surroundings (road, water) and moving reflections share the object's motion; their
    colour tells them apart."""
    refine_band_px: int = 8
    """Pixels around the motion mask that the refinement may add (beyond: certainly background)."""
    refine_min_keep: float = 0.3
    """A refinement that keeps less than this fraction of a frame's motion mask is distrusted (the colours
    did not separate) and the motion mask is used as it is."""

    def __post_init__(self) -> None:
        if self.long_edge < 16:
            raise ValueError(f"long_edge must be at least 16 px, got {self.long_edge}")
        if self.window < 0 or self.open_px < 0 or self.close_px < 0:
            raise ValueError("window, open_px and close_px must not be negative")
        if not 0.0 < self.vote_threshold < 1.0:
            raise ValueError(f"vote_threshold must lie in (0, 1), got {self.vote_threshold}")
        if self.min_residual_px <= 0.0 or self.ransac_px <= 0.0 or self.residual_sigmas <= 0.0:
            raise ValueError("min_residual_px, ransac_px and residual_sigmas must be positive")


@dataclass
class AutoMasks:
    """Masks found from motion and what the analysis saw."""

    masks: np.ndarray  # bool [T, H, W] at the analysis resolution
    found: bool
    """False when nothing moves against the background (or the clip has one frame)."""
    static_camera: bool
    message: str
    """One line for the user: what was found, or why nothing was."""
    homographies: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    """float64 [T-1, 3, 3]: background motion of each pair, frame t pixels -> frame t+1 pixels."""

    @property
    def coverage(self) -> np.ndarray:
        """Foreground fraction of each frame."""
        t = self.masks.shape[0]
        return self.masks.reshape(t, -1).mean(1) if t else np.zeros(0)


# --- background motion per pair -----------------------------------------------------------------------


def _grid(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    return np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))


def fit_background_homography(flow: np.ndarray, ok: np.ndarray, ransac_px: float) -> np.ndarray | None:
    """Homography (3x3, frame a -> frame b pixels) of the dominant motion in ``flow`` ([H, W, 2], a -> b)
    from its reliable vectors (``ok``); None when too few are reliable or RANSAC fails."""
    h, w = ok.shape
    stride = max(1, int(np.sqrt(h * w / TARGET_POINTS)))
    ys, xs = np.mgrid[stride // 2 : h : stride, stride // 2 : w : stride]
    sel = ok[ys, xs]
    if int(sel.sum()) < MIN_POINTS:
        return None
    src = np.stack((xs[sel], ys[sel]), -1).astype(np.float32)
    dst = src + flow[ys[sel], xs[sel]].astype(np.float32)
    hom, inliers = cv2.findHomography(src, dst, cv2.RANSAC, ransac_px, maxIters=2000, confidence=0.995)
    if hom is None or inliers is None or int(inliers.sum()) < MIN_POINTS or not np.isfinite(hom).all():
        return None
    return hom.astype(np.float64)


def homography_displacement(hom: np.ndarray, size: tuple[int, int]) -> float:
    """Largest displacement (px) the homography gives a point of a coarse grid over a (W, H) frame."""
    w, h = size
    gx, gy = np.meshgrid(np.linspace(0, w - 1, 5), np.linspace(0, h - 1, 5))
    pts = np.stack((gx.ravel(), gy.ravel()), -1).reshape(-1, 1, 2)
    moved = cv2.perspectiveTransform(pts, hom).reshape(-1, 2)
    return float(np.linalg.norm(moved - pts.reshape(-1, 2), axis=1).max())


def _residual(flow: np.ndarray, hom: np.ndarray) -> np.ndarray:
    """|x + flow(x) - H x| per pixel."""
    h, w = flow.shape[:2]
    xs, ys = _grid(h, w)
    pts = np.stack((xs, ys), -1).reshape(-1, 1, 2).astype(np.float64)
    bg = cv2.perspectiveTransform(pts, hom).reshape(h, w, 2).astype(np.float32)
    target = np.stack((xs, ys), -1) + flow
    return np.linalg.norm(target - bg, axis=-1)


def _scores(flow: np.ndarray, ok: np.ndarray, hom: np.ndarray, cfg: AutoMaskConfig) -> np.ndarray:
    """Residual divided by its threshold (> 1: moving against the background)."""
    res = _residual(flow, hom)
    noise = MAD_TO_SIGMA * float(np.median(res[ok])) if ok.any() else 0.0
    thr = max(cfg.min_residual_px, cfg.residual_sigmas * noise, MIN_THRESHOLD_PX)
    return res / thr


# --- votes and their temporal accumulation ----------------------------------------------------------------


def _pull(values: np.ndarray, flow: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``values`` of the frame ``flow`` points into, sampled at each pixel's target, and where the target
    lies inside that frame."""
    h, w = flow.shape[:2]
    xs, ys = _grid(h, w)
    qx, qy = xs + flow[..., 0], ys + flow[..., 1]
    out = cv2.remap(values.astype(np.float32), qx, qy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    inside = (qx >= 0) & (qx <= w - 1) & (qy >= 0) & (qy <= h - 1)
    return out, inside


def _frame_votes(flow: FlowField, homs: list[np.ndarray | None], cfg: AutoMaskConfig) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: a moving-vote in {0, 1} and its weight (1 reliable, ``unreliable_weight`` otherwise, 0
    where no pair of the frame had a background fit)."""
    n = flow.pairs
    t_count = n + 1
    h, w = flow.forward.shape[1:3]
    votes = np.zeros((t_count, h, w), dtype=np.float32)
    weights = np.zeros((t_count, h, w), dtype=np.float32)
    for t in range(t_count):
        dirs = []  # (score, ok) of frame t's flow towards t+1 and towards t-1
        if t < n and homs[t] is not None:
            dirs.append((_scores(flow.forward[t], flow.forward_ok[t], homs[t], cfg), flow.forward_ok[t]))
        if t > 0 and homs[t - 1] is not None:
            back = np.linalg.inv(homs[t - 1])
            dirs.append((_scores(flow.backward[t - 1], flow.backward_ok[t - 1], back, cfg), flow.backward_ok[t - 1]))
        if not dirs:
            continue
        big = np.float32(np.inf)
        rel_min = np.full((h, w), big, dtype=np.float32)
        any_ok = np.zeros((h, w), dtype=bool)
        raw = np.zeros((h, w), dtype=np.float32)
        for score, ok in dirs:
            rel_min = np.where(ok, np.minimum(rel_min, score), rel_min)
            any_ok |= ok
            raw += score / len(dirs)
        # Moving in EVERY direction where the flow is reliable; with none reliable, the mean decides.
        votes[t] = np.where(any_ok, rel_min > 1.0, raw > 1.0)
        weights[t] = np.where(any_ok, 1.0, cfg.unreliable_weight)
    return votes, weights


def _chain_sum(values: np.ndarray, flow: FlowField, window: int) -> np.ndarray:
    """Sum over frames t-window..t+window of ``values`` [T, H, W], each pulled into frame t through the
    chained flow; a neighbour adds nothing where its chain leaves the frame."""
    t_count = values.shape[0]
    total = values.astype(np.float32).copy()
    ahead, behind = total.copy(), total.copy()
    for _ in range(window):
        # Frame t+k seen from frame t = frame t+k seen from t+1, pulled through forward[t]; likewise back.
        new = np.zeros_like(ahead)
        for t in range(t_count - 1):
            v, inside = _pull(ahead[t + 1], flow.forward[t])
            new[t] = v * inside
        ahead = new
        new = np.zeros_like(behind)
        for t in range(1, t_count):
            v, inside = _pull(behind[t - 1], flow.backward[t - 1])
            new[t] = v * inside
        behind = new
        total += ahead + behind
    return total


def _accumulate(votes: np.ndarray, weights: np.ndarray, flow: FlowField, window: int) -> np.ndarray:
    """Mean vote over the window, each vote scaled by its weight and each frame that reaches the pixel
    counting once: a pixel whose flow is unreliable in every frame can reach ``unreliable_weight`` at most."""
    num = _chain_sum(votes * weights, flow, window)
    den = _chain_sum((weights > 0).astype(np.float32), flow, window)
    return num / np.maximum(den, MIN_WEIGHT)


# --- clean-up ------------------------------------------------------------------------------------------


def _disk(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """Background regions not connected to the frame border become foreground."""
    h, w = mask.shape
    padded = np.zeros((h + 2, w + 2), dtype=np.uint8)
    padded[1:-1, 1:-1] = mask
    flood = padded.copy()
    cv2.floodFill(flood, np.zeros((h + 4, w + 4), dtype=np.uint8), (0, 0), 1)
    return (padded[1:-1, 1:-1] > 0) | (flood[1:-1, 1:-1] == 0)


def clean_mask(mask: np.ndarray, cfg: AutoMaskConfig) -> np.ndarray:
    """Opening, closing, hole filling, then blobs under ``min_area_fraction`` of the frame dropped."""
    m = mask.astype(np.uint8)
    if cfg.open_px:
        m = cv2.morphologyEx(m, cv2.MORPH_OPEN, _disk(cfg.open_px))
    if cfg.close_px:
        # Pad so a blob touching the border is not eaten by the closing's erosion of the zero border.
        pad = cfg.close_px + 1
        m = cv2.copyMakeBorder(m, pad, pad, pad, pad, cv2.BORDER_REPLICATE)
        m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, _disk(cfg.close_px))[pad:-pad, pad:-pad]
    filled = fill_holes(m > 0)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(filled.astype(np.uint8), connectivity=8)
    min_area = cfg.min_area_fraction * mask.size
    keep = np.zeros(count, dtype=bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_area
    return keep[labels]


def refine_with_colour(frame: np.ndarray, mask: np.ndarray, cfg: AutoMaskConfig) -> np.ndarray:
    """Snap a motion mask to colour edges with GrabCut, on a crop around it (local colour models)."""
    if cfg.refine_iterations <= 0 or not mask.any():
        return mask
    h, w = mask.shape
    band = max(1, cfg.refine_band_px)
    grown = cv2.dilate(mask.astype(np.uint8), _disk(band)) > 0
    ys, xs = np.nonzero(grown)
    margin = 2 * band
    y0, y1 = max(0, ys.min() - margin), min(h, ys.max() + 1 + margin)
    x0, x1 = max(0, xs.min() - margin), min(w, xs.max() + 1 + margin)
    m, g = mask[y0:y1, x0:x1], grown[y0:y1, x0:x1]
    if g.all():  # no certain background left in the crop: nothing to learn the background colours from
        return mask
    gc = np.full(m.shape, cv2.GC_BGD, dtype=np.uint8)
    gc[g] = cv2.GC_PR_BGD
    gc[m] = cv2.GC_PR_FGD
    img = np.ascontiguousarray(np.clip(frame[y0:y1, x0:x1] * 255.0 + 0.5, 0, 255).astype(np.uint8))
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    try:
        cv2.grabCut(img, gc, None, bgd, fgd, cfg.refine_iterations, cv2.GC_INIT_WITH_MASK)
    except cv2.error:  # degenerate colour statistics (e.g. a flat crop): keep the motion mask
        return mask
    refined = np.zeros_like(mask)
    refined[y0:y1, x0:x1] = (gc == cv2.GC_FGD) | (gc == cv2.GC_PR_FGD)
    if refined.sum() < cfg.refine_min_keep * mask.sum():
        return mask
    return refined


def _persistent(masks: np.ndarray, flow: FlowField, cfg: AutoMaskConfig) -> np.ndarray:
    """Keep the blobs of each frame that a neighbouring frame (pulled in through the flow) also sees."""
    t_count = masks.shape[0]
    out = np.zeros_like(masks)
    for t in range(t_count):
        if not masks[t].any():
            continue
        seen = np.zeros(masks.shape[1:], dtype=bool)
        if t + 1 < t_count:
            v, inside = _pull(masks[t + 1].astype(np.float32), flow.forward[t])
            seen |= (v > C.MASK_THRESHOLD) & inside
        if t > 0:
            v, inside = _pull(masks[t - 1].astype(np.float32), flow.backward[t - 1])
            seen |= (v > C.MASK_THRESHOLD) & inside
        count, labels = cv2.connectedComponents(masks[t].astype(np.uint8), connectivity=8)
        if count <= 1:
            continue
        area = np.bincount(labels.ravel(), minlength=count).astype(np.float64)
        hit = np.bincount(labels.ravel(), weights=seen.ravel().astype(np.float64), minlength=count)
        keep = hit >= cfg.persist_overlap * np.maximum(area, 1.0)
        keep[0] = False
        out[t] = keep[labels]
    return out


# --- the whole analysis ----------------------------------------------------------------------------------


def auto_masks(
    frames: np.ndarray,
    cfg: AutoMaskConfig | None = None,
    flow: FlowField | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> AutoMasks:
    """Foreground masks of ``frames`` (float32 [T, H, W, 3] display-encoded in [0, 1], at the analysis
    resolution) from motion. ``flow`` may be passed when the caller already has it for these frames."""
    cfg = AutoMaskConfig() if cfg is None else cfg
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.shape[0] < 1:
        raise ValueError(f"frames must be [T, H, W, 3] with T >= 1, got {frames.shape}")
    t_count, h, w = frames.shape[:3]
    # NaN/Inf would poison GrabCut's colour models (the flow sanitises its own copy).
    frames = np.clip(np.nan_to_num(frames.astype(np.float32), nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    empty = np.zeros((t_count, h, w), dtype=bool)
    if t_count < 2:
        return AutoMasks(empty, False, False, "no foreground masks: a single frame has no motion to find an object by")
    if flow is None:
        flow = compute_flow(frames, DISFlow(cfg.flow_preset), threshold_px=cfg.flow_threshold_px, progress=progress)
    if flow.forward.shape[:3] != (t_count - 1, h, w):
        raise ValueError(f"flow of shape {flow.forward.shape} does not belong to frames of shape {frames.shape}")

    homs = [fit_background_homography(flow.forward[t], flow.forward_ok[t], cfg.ransac_px) for t in range(t_count - 1)]
    fitted = [hm for hm in homs if hm is not None]
    static_pairs = sum(homography_displacement(hm, (w, h)) <= cfg.static_camera_px for hm in fitted)
    static = bool(fitted) and static_pairs >= STATIC_PAIR_FRACTION * len(fitted)
    if static:
        homs = [np.eye(3) for _ in homs]  # a tripod: a moving crowd must not tilt the fit
    if not fitted:
        return AutoMasks(
            empty,
            False,
            False,
            "no foreground masks: the flow is unreliable everywhere (no texture, or frames unrelated)",
            np.stack([np.eye(3)] * (t_count - 1)),
        )

    votes, weights = _frame_votes(flow, homs, cfg)
    mean_vote = _accumulate(votes, weights, flow, cfg.window)
    raw = mean_vote > cfg.vote_threshold
    cleaned = np.stack([clean_mask(m, cfg) for m in raw])
    masks = _persistent(cleaned, flow, cfg)
    cv2.setRNGSeed(GRABCUT_SEED)
    masks = np.stack([clean_mask(refine_with_colour(f, m, cfg), cfg) for f, m in zip(frames, masks, strict=True)])
    homographies = np.stack([np.eye(3) if hm is None else hm for hm in homs])
    camera = "static camera" if static else "moving camera"
    frames_with = int(masks.reshape(t_count, -1).any(1).sum())
    if frames_with == 0:
        return AutoMasks(
            masks,
            False,
            static,
            f"no foreground found ({camera}): nothing moves against the background; fit a background-only atlas",
            homographies,
        )
    message = f"foreground in {frames_with}/{t_count} frames ({camera}), mean coverage {masks.mean() * 100:.1f}%"
    return AutoMasks(masks, True, static, message, homographies)


def mask_iou(pred: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-frame intersection over union of bool [T, H, W] masks (1 where both are empty)."""
    pred, truth = np.asarray(pred, bool), np.asarray(truth, bool)
    if pred.shape != truth.shape:
        raise ValueError(f"mask shapes differ: {pred.shape} vs {truth.shape}")
    t = pred.shape[0]
    inter = (pred & truth).reshape(t, -1).sum(1).astype(np.float64)
    union = (pred | truth).reshape(t, -1).sum(1).astype(np.float64)
    return np.where(union > 0, inter / np.maximum(union, 1.0), 1.0)


def resize_masks(masks: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Bool masks [T, h, w] to ``size = (W, H)``: smooth (linear) resample of the 0/1 values, then
    above ``contract.MASK_THRESHOLD``."""
    w, h = size
    if masks.shape[1:] == (h, w):
        return masks.copy()
    out = np.empty((masks.shape[0], h, w), dtype=bool)
    for i, m in enumerate(masks):
        out[i] = cv2.resize(m.astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR) > C.MASK_THRESHOLD
    return out


# --- the `masks` verb: a clip in, one PNG per frame out ----------------------------------------------------


@dataclass
class MasksReport:
    """What ``write_auto_masks`` did, for the CLI's summary."""

    folder: str
    files: list[str]
    result: AutoMasks
    iou: np.ndarray | None = None
    """Per-frame IoU against ``truth`` when it was given, at the clip's resolution (the written masks)."""
    reused: bool = False
    """The folder held this very set already (the same command run before): it was left as it is."""

    def summary(self) -> list[str]:
        again = " (the folder held these very masks already: left as they are)" if self.reused else ""
        lines = [f"auto masks: {self.result.message}{again}"]
        if self.iou is not None and len(self.iou):
            lines.append(f"IoU against the given masks: mean {self.iou.mean():.3f}, min {self.iou.min():.3f}")
        return lines


def write_auto_masks(
    clip: str | Path,
    out: str | Path,
    frame_range: tuple[int, int] | None = None,
    cfg: AutoMaskConfig | None = None,
    truth: str | Path | None = None,
    say: Callable[[str], None] | None = None,
    colorspace: str | None = None,
) -> MasksReport:
    """Find masks for ``clip`` and write them to ``out`` as 8-bit 0/255 PNGs at the clip's resolution,
    named like the frames, all or nothing (``write_mask_files``). Never overwrites: a folder already holding one
    of those names is refused, but for a folder holding these very masks (the same command run before: a retried
    farm task), which is left as it is and succeeds. ``say`` receives a progress line before the slow part.
    ``colorspace``: the clip's colour space (default: ``engine.io.colour.default_colorspace``); the motion is found in
    the fit's working encoding."""
    cfg = AutoMaskConfig() if cfg is None else cfg
    info = open_clip(clip, frame_range, colorspace)
    if info.num_frames < 2:
        raise InputError(
            info.source,
            "a single frame has no motion to find the foreground by",
            "select at least two frames (--frames FIRST:LAST), or paint the mask by hand",
        )
    folder, names = mask_folder(info, out, whole_set=True)
    size = working_size(info.width, info.height, cfg.long_edge)
    if say is not None:
        say(f"finding what moves in {info.num_frames} frames at {size[0]}x{size[1]}")
    frames = read_frames(info, size)
    frames = to_working(np.nan_to_num(frames, nan=0.0, posinf=1.0, neginf=0.0), info.colorspace, info.colour_config)
    frames = np.clip(np.nan_to_num(frames, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0).astype(np.float32)
    result = auto_masks(frames, cfg)
    full = resize_masks(result.masks, (info.width, info.height))
    iou = None if truth is None else mask_iou(full, read_masks(truth, info, (info.width, info.height)))
    if all((folder / n).exists() for n in names):  # written before: the very same set, or refused
        if not holds_the_same(folder, names, full):
            raise already_holds(folder, names)
        return MasksReport(str(folder), [str(folder / n) for n in names], result, iou, reused=True)
    return MasksReport(str(folder), write_mask_files(folder, names, full), result, iou)
