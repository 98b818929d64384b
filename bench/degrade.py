"""Precise masks made as coarse as the masks artists and detectors really give: grown, shrunk, simplified to a
polygon, with some frames missing. Fixed recipes and a seed, so every run of the bench fits the same masks.

A recipe applies, per frame and in this order: polygon simplification of each outer contour
(``cv2.approxPolyDP`` with ``simplify_px`` as the tolerance, holes filled), dilation by ``dilate_px``, erosion by
``erode_px`` (both with a disc of that radius), all in the mask's own pixels. Then ``drop_fraction`` of the
frames (rounded, never the first frame; which ones from the seed) are dropped.

A dropped frame is written as an all-black mask: the engine reads an empty mask as "no mask for this frame"
(no mask term and no mask prior there, ``engine.data.video``), while a mask folder with files missing is
refused. An object eroded away in a frame becomes such an empty mask too.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from engine.errors import InputError

#: Mask files a degradation reads (a GT folder of DAVIS: 8-bit single-channel 0/255 PNGs).
MASK_SUFFIXES: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
#: A GT pixel is foreground above this 8-bit value.
GT_THRESHOLD = 127
#: The seed every standard measurement uses.
DEFAULT_SEED = 0


@dataclass(frozen=True)
class Degradation:
    """How to spoil a precise mask; distances in the mask's own pixels."""

    dilate_px: int = 0
    erode_px: int = 0
    drop_fraction: float = 0.0  # of the frames, written as empty masks (never the first frame)
    simplify_px: float = 0.0  # polygon tolerance of cv2.approxPolyDP; 0: the outline is kept

    def __post_init__(self) -> None:
        if self.dilate_px < 0 or self.erode_px < 0 or self.simplify_px < 0:
            raise ValueError(f"distances must be >= 0: {self}")
        if not 0.0 <= self.drop_fraction < 1.0:
            raise ValueError(f"drop_fraction must be in [0, 1): {self}")


#: The named recipes (``--degrade NAME``).
RECIPES: dict[str, Degradation] = {
    "exact": Degradation(),
    "dilated10": Degradation(dilate_px=10),
    "eroded5": Degradation(erode_px=5),
    "dropped10": Degradation(drop_fraction=0.1),
    "polygon8": Degradation(simplify_px=8.0),
    "dilated10_dropped10": Degradation(dilate_px=10, drop_fraction=0.1),
    "polygon8_dilated5_dropped10": Degradation(dilate_px=5, drop_fraction=0.1, simplify_px=8.0),
}


def recipe(name: str) -> Degradation:
    """The named recipe; an unknown name is a one-line input error listing the names."""
    if name not in RECIPES:
        raise InputError(None, f"no degradation recipe {name!r}", f"use one of {', '.join(RECIPES)}")
    return RECIPES[name]


def _disc(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def degrade_mask(mask: np.ndarray, deg: Degradation) -> np.ndarray:
    """One bool [H, W] mask spoilt by ``deg``'s shape steps (simplify, dilate, erode); dropping is per clip."""
    m: np.ndarray = np.asarray(mask, bool).astype(np.uint8)
    if deg.simplify_px > 0 and m.any():
        contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        poly = [cv2.approxPolyDP(c, deg.simplify_px, True) for c in contours]
        m = cv2.fillPoly(np.zeros_like(m), poly, (1,))
    if deg.dilate_px > 0:
        m = cv2.dilate(m, _disc(deg.dilate_px))
    if deg.erode_px > 0:
        m = cv2.erode(m, _disc(deg.erode_px))
    return m.astype(bool)


def dropped_frames(count: int, fraction: float, seed: int) -> list[int]:
    """Sorted positions of the ``round(fraction * count)`` frames to drop, drawn from frames 1.. by ``seed``."""
    n = min(round(fraction * count), max(count - 1, 0))
    if n <= 0:
        return []
    rng = np.random.default_rng(seed)
    return sorted(int(i) for i in rng.choice(np.arange(1, count), size=n, replace=False))


def mask_files(folder: Path) -> list[Path]:
    """The mask images of ``folder``, sorted by name."""
    return sorted(p for p in Path(folder).iterdir() if p.is_file() and p.suffix.lower() in MASK_SUFFIXES)


def read_gt(path: Path) -> np.ndarray:
    """A ground-truth mask file as bool [H, W] (any channel count: the first channel)."""
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise InputError(path, "cannot be read as an image", "pass a folder of 8-bit mask PNGs")
    return np.asarray(image > GT_THRESHOLD)


def masks_iou(masks_dir: str | Path, gt_dir: str | Path) -> float | None:
    """IoU of the masks of ``masks_dir`` against those of ``gt_dir`` (same stems), pooled over the frames whose
    mask is not empty (an empty one is "no mask", not "no object"): how good the masks a fit is given are. None
    when none has a mask."""
    inter = union = 0
    for path in mask_files(Path(masks_dir)):
        m = read_gt(path)
        if not m.any():
            continue
        gt = read_gt(Path(gt_dir) / path.name)
        inter += int((m & gt).sum())
        union += int((m | gt).sum())
    return inter / union if union else None


def write_degraded(gt_dir: str | Path, out_dir: str | Path, deg: Degradation | str, seed: int = DEFAULT_SEED) -> Path:
    """Every mask of ``gt_dir`` spoilt by ``deg`` (a ``Degradation`` or a recipe name) as an 8-bit 0/255 PNG of
    the same stem in ``out_dir`` (created; files of the same name replaced). Same input and seed, same bytes."""
    deg = recipe(deg) if isinstance(deg, str) else deg
    files = mask_files(Path(gt_dir))
    if not files:
        raise InputError(gt_dir, "holds no mask images", "pass the clip's ground-truth mask folder")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    drop = set(dropped_frames(len(files), deg.drop_fraction, seed))
    for i, path in enumerate(files):
        gt = read_gt(path)
        m = np.zeros_like(gt) if i in drop else degrade_mask(gt, deg)
        ok, data = cv2.imencode(".png", m.astype(np.uint8) * 255)
        if not ok:
            raise OSError(f"could not encode {path.name} as PNG")
        (out / (path.stem + ".png")).write_bytes(data.tobytes())
    return out


__all__ = [
    "DEFAULT_SEED",
    "RECIPES",
    "Degradation",
    "degrade_mask",
    "dropped_frames",
    "mask_files",
    "masks_iou",
    "read_gt",
    "recipe",
    "write_degraded",
]
