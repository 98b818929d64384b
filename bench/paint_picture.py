"""The picture of where paint goes: a checkerboard painted once on the foreground atlases, shown at the first,
middle and last frame (top row, rendered through the export as ``render`` does), above the same checkerboard's
colours carried from the first frame by chained DIS flow on the native plate (bottom row: one dot per grid point
of the object's first mask, in the colour the checkerboard gives it there).

Where the atlas follows the object, the top row's squares stay on the same part of the body; where flow drifts
or loses a limb, the bottom row's dots leave it or bunch up. The two rows carry the same paint, so they compare
directly.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from bench.flow_tracks import dis_flow_tracks, plate_codes
from engine.edit.preview import checker_edits, grid, label, tile, write_png_u8
from engine.edit.render import render_frames, to_display_u8
from engine.errors import InputError
from engine.export.manifest import Manifest
from engine.io.clip import open_clip, read_masks

#: Frames shown: the first, the middle and the last of the export.
PICTURE_FRAMES = 3
#: Grid points per mask: about this many along the mask's longer side.
DOTS_ACROSS = 24
#: Dot radius as a share of the grid spacing.
DOT_RADIUS = 0.35


def picture_frames(frames: list[int]) -> list[int]:
    """The first, middle and last of ``frames`` (fewer when the export has fewer)."""
    n = len(frames)
    return [frames[i] for i in sorted({0, (n - 1) // 2, n - 1})][:PICTURE_FRAMES]


def grid_points(mask: np.ndarray) -> tuple[np.ndarray, float]:
    """Pixel centres (x, y) [N, 2] on a regular grid inside ``mask`` [H, W], and the grid's spacing in pixels."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return np.zeros((0, 2)), 1.0
    step = max(2.0, max(xs.max() - xs.min(), ys.max() - ys.min()) / DOTS_ACROSS)
    gx = np.arange(xs.min() + step / 2, xs.max() + 1, step)
    gy = np.arange(ys.min() + step / 2, ys.max() + 1, step)
    px, py = np.meshgrid(gx, gy)
    pts = np.stack([px.ravel(), py.ravel()], -1)
    inside = mask[np.clip(pts[:, 1].astype(int), 0, mask.shape[0] - 1), np.clip(pts[:, 0].astype(int), 0,
                                                                                mask.shape[1] - 1)]  # fmt: skip
    return pts[inside] + 0.5, float(step)


def draw_dots(frame_u8: np.ndarray, xy: np.ndarray, colours: np.ndarray, radius: float) -> np.ndarray:
    """``frame_u8`` with a filled dot (dark rim) per point inside the frame."""
    out = frame_u8.copy()
    h, w = out.shape[:2]
    r = max(1, round(radius))
    for (x, y), c in zip(xy, colours, strict=True):
        if not (np.isfinite(x) and np.isfinite(y)) or not (0 <= x < w and 0 <= y < h):
            continue
        centre = (int(x), int(y))
        cv2.circle(out, centre, r + 1, (0, 0, 0), -1, lineType=cv2.LINE_AA)
        cv2.circle(out, centre, r, tuple(int(v) for v in c), -1, lineType=cv2.LINE_AA)
    return out


def paint_picture(manifest_path: str | Path, frames_dir: str | Path, masks_dir: str | Path, out: str | Path) -> Path:
    """Write the two-row picture (``out``, PNG) for the export at ``manifest_path`` of the plate in ``frames_dir``
    (its frames in order, the export's frames among them), the dots seeded in the first picture frame's mask of
    ``masks_dir``; returns ``out``."""
    manifest = Manifest(manifest_path)
    info = open_clip(frames_dir)
    numbers = list(info.frame_numbers)
    picks = picture_frames(manifest.frames)
    missing = [f for f in picks if f not in numbers]
    if missing:
        raise InputError(info.source, f"has no frame {missing[0]} of the export", "pass the plate it was made from")
    checker = {n: to_display_u8(f) for n, f in render_frames(manifest, checker_edits(manifest), picks)}
    first = numbers.index(picks[0])
    mask = read_masks(masks_dir, info, manifest.resolution)[first]
    seeds, step = grid_points(mask)
    colours = checker[picks[0]][np.clip(seeds[:, 1].astype(int), 0, mask.shape[0] - 1),
                                np.clip(seeds[:, 0].astype(int), 0, mask.shape[1] - 1)]  # fmt: skip
    codes, _ = plate_codes(frames_dir)
    query = np.concatenate([np.full((len(seeds), 1), float(first)), seeds], 1)
    followed = dis_flow_tracks(codes, query, len(codes)) if len(seeds) else np.zeros((0, len(codes), 2))
    top, bottom = [], []
    for n in picks:
        k = numbers.index(n)
        top.append(label(tile(checker[n]), f"atlas paint, frame {n}"))
        dots = draw_dots(codes[k], followed[:, k] if len(seeds) else np.zeros((0, 2)), colours, step * DOT_RADIUS)
        bottom.append(label(tile(dots), f"chained flow, frame {n}"))
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_png_u8(path, grid([top, bottom]))


__all__ = ["DOTS_ACROSS", "PICTURE_FRAMES", "draw_dots", "grid_points", "paint_picture", "picture_frames"]
