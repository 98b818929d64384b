"""Scribbles as a user draws them, made from a clip's part masks (``masks_parts/PART/``): one stroke along each
part on a few frames, in the part's scribble colour, so ``bench paint-table --scribbles`` fits the product's path
(one mask for the whole object, ``fit --scribbles``) where ``--parts`` hands the fit one mask per part.

A stroke is a line along the part's long axis (the principal axis of its pixels) through its centre, drawn
``STROKE_PX`` wide and kept inside the part eroded by ``INSET_PX``: the quick drag along a limb an artist makes,
never touching the part's edge (a stroke over the border would tell the fit the wrong owner there).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from engine import contract as C
from engine.errors import InputError
from engine.io.atomic import atomic_write_bytes

#: Width of a stroke in native pixels, and how far inside the part's edge it stays.
STROKE_PX = 5
INSET_PX = 4
#: Where along the clip the strokes are drawn (fractions of the frame count: first, middle, last).
DEFAULT_AT = (0.0, 0.5, 1.0)
#: A stroke leaves this fraction of the part's extent free at each end of its axis.
END_MARGIN = 0.1
_MASK_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


def part_stroke(mask: np.ndarray, width: int = STROKE_PX, inset: int = INSET_PX) -> np.ndarray:
    """bool [H, W]: a ``width``-pixel line along the long axis of the part ``mask`` (bool [H, W]) through its centre,
    inside the part eroded by ``inset`` (the part itself where erosion leaves nothing); empty for an empty part."""
    part = mask.astype(np.uint8)
    core = cv2.erode(part, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * inset + 1, 2 * inset + 1)))
    if not core.any():
        core = part
    ys, xs = np.nonzero(core)
    if len(xs) == 0:
        return np.zeros(mask.shape, dtype=bool)
    points = np.stack([xs, ys], axis=1).astype(np.float64)
    centre = points.mean(axis=0)
    if len(points) < 2:
        axis = np.array([1.0, 0.0])
    else:
        _, vectors = np.linalg.eigh(np.cov((points - centre).T))
        axis = vectors[:, -1]  # the largest eigenvalue's vector: the part's long axis
    t = (points - centre) @ axis
    lo, hi = np.quantile(t, [END_MARGIN, 1.0 - END_MARGIN])
    a, b = centre + lo * axis, centre + hi * axis
    line = np.zeros_like(part)
    cv2.line(line, (round(a[0]), round(a[1])), (round(b[0]), round(b[1])), 1, thickness=width, lineType=cv2.LINE_8)
    stroke = (line > 0) & (core > 0)
    if not stroke.any():  # a bent part whose axis misses its core: its centre-most pixels instead
        nearest = np.argmin(((points - centre) ** 2).sum(axis=1))
        stroke[ys[nearest], xs[nearest]] = True
    return stroke


def _mask_files(folder: Path) -> list[Path]:
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in _MASK_EXTENSIONS and not p.name.startswith("."))
    if not files:
        raise InputError(folder, "holds no mask images", "point at a masks_parts/PART folder of numbered images")
    return files


def write_part_scribbles(
    parts: list[Path], out: str | Path, at: tuple[float, ...] = DEFAULT_AT
) -> tuple[Path, list[int]]:
    """Write one RGBA scribble image per chosen frame into ``out`` (named like the part masks' files: the frame
    number), part k's strokes in ``contract.SCRIBBLE_COLOURS[k]``; returns the folder and the frame positions
    drawn. Parts are taken in the order given (the first is Foreground1). Rewriting gives the same files."""
    if not 2 <= len(parts) <= len(C.SCRIBBLE_COLOURS):
        raise ValueError(f"scribbles split an object into 2..{len(C.SCRIBBLE_COLOURS)} parts, not {len(parts)}")
    files = [_mask_files(Path(p)) for p in parts]
    names = [f.name for f in files[0]]
    if any([f.name for f in other] != names for other in files[1:]):
        raise InputError(parts[1], "does not name its frames as the first part does", "give each part every frame")
    positions = sorted({round(a * (len(names) - 1)) for a in at})
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    for i in positions:
        image = None
        for k, part_files in enumerate(files):
            mask = cv2.imread(str(part_files[i]), cv2.IMREAD_GRAYSCALE)
            if mask is None:
                raise InputError(part_files[i], "cannot be read as an image", "save masks as 8-bit PNG")
            if image is None:
                image = np.zeros((*mask.shape, 4), dtype=np.uint8)
            stroke = part_stroke(mask > 127)
            r, g, b = C.SCRIBBLE_COLOURS[k]
            image[stroke] = (b, g, r, 255)  # OpenCV writes BGRA
        ok, data = cv2.imencode(".png", image)
        assert ok
        atomic_write_bytes(folder / (Path(names[i]).stem + ".png"), data.tobytes())
    return folder, positions
