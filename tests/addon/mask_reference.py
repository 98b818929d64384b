"""Blender's mask space and an exact polygon rasterizer: the oracle the mask tests compare Blender with (no bpy).

Blender's mask space spans 0..1 along the frame's longer side and centres the shorter side; pixels are
counted bottom-up.
"""

from __future__ import annotations


def px_to_mask(x: float, y: float, width: int, height: int) -> tuple[float, float]:
    """Pixel coordinates (origin bottom-left, in pixels) -> mask space."""
    side = max(width, height)
    return (x / width - 0.5) * width / side + 0.5, (y / height - 0.5) * height / side + 0.5


def mask_to_px(u: float, v: float, width: int, height: int) -> tuple[float, float]:
    side = max(width, height)
    return ((u - 0.5) * side / width + 0.5) * width, ((v - 0.5) * side / height + 0.5) * height


def rasterize_polygon(points: list[tuple[float, float]], width: int, height: int) -> list[list[bool]]:
    """Inside test at pixel centres (even-odd), rows bottom-up like Blender's pixels."""
    rows = []
    n = len(points)
    for j in range(height):
        yc = j + 0.5
        row = []
        for i in range(width):
            xc = i + 0.5
            inside = False
            for k in range(n):
                x0, y0 = points[k]
                x1, y1 = points[(k + 1) % n]
                if (y0 > yc) != (y1 > yc) and xc < x0 + (yc - y0) * (x1 - x0) / (y1 - y0):
                    inside = not inside
            row.append(inside)
        rows.append(row)
    return rows


def iou(a: list[list[bool]], b: list[list[bool]]) -> float:
    inter = sum(x and y for ra, rb in zip(a, b, strict=True) for x, y in zip(ra, rb, strict=True))
    union = sum(x or y for ra, rb in zip(a, b, strict=True) for x, y in zip(ra, rb, strict=True))
    return 1.0 if union == 0 else inter / union
