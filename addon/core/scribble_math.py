"""Scribbles from annotation strokes -> the engine's scribble images. No bpy here.

The Movie Clip Editor stores an annotation stroke's points in frame-normalised coordinates (0..1 along
the width and the height, origin bottom-left). A stroke's colour is its annotation layer's colour; the
engine's colour code (``engine.contract.SCRIBBLE_COLOURS``: red -> Foreground1, green -> Foreground2, ...)
decides which foreground layer it marks. Pure Python (stdlib PNG writer), so it is tested without Blender.
"""

from __future__ import annotations

import itertools
import math
import struct
import zlib
from dataclasses import dataclass

from ...engine import contract as C  # type: ignore[import-not-found]

#: No label at this pixel (the PNG is black there).
NO_LABEL = -1
#: A stroke thinner than this radius (pixels) is widened to it, so a one-pixel stroke still marks pixels.
MIN_RADIUS_PX = 0.75
#: The names of the code colours in the panel (any other colour is shown as its hex code).
COLOUR_NAMES: dict[tuple[int, int, int], str] = {
    (255, 0, 0): "red",
    (0, 255, 0): "green",
    (0, 0, 255): "blue",
    (255, 255, 0): "yellow",
}
#: The scribble PNGs: 8 bits per channel, RGB (PNG colour type 2).
PNG_BIT_DEPTH = 8
PNG_COLOUR_TYPE_RGB = 2


@dataclass(frozen=True)
class Stroke:
    """One annotation stroke in frame pixels (origin bottom-left), the layer it marks and its half width."""

    label: int
    radius_px: float
    points: tuple[tuple[float, float], ...]


def layer_label(rgb: tuple[float, float, float]) -> int | None:
    """The foreground layer (0-based) an annotation layer colour marks, or None when it is no code colour.

    Each channel, as 8-bit, must be within SCRIBBLE_TOLERANCE of a code colour (pure primaries read the
    same in linear and sRGB, so the colour space of the picker does not matter for them).
    """
    c8 = [round(min(max(float(v), 0.0), 1.0) * 255.0) for v in rgb[:3]]
    for k, colour in enumerate(C.SCRIBBLE_COLOURS):
        if all(abs(a - b) <= C.SCRIBBLE_TOLERANCE for a, b in zip(c8, colour, strict=True)):
            return k
    return None


def to_pixels(points: list[tuple[float, float]], width: int, height: int) -> tuple[tuple[float, float], ...]:
    """Frame-normalised annotation points -> frame pixels (origin bottom-left)."""
    return tuple((float(x) * width, float(y) * height) for x, y in points)


def _segment_distance(px: float, py: float, a: tuple[float, float], b: tuple[float, float]) -> float:
    ax, ay = a
    dx, dy = b[0] - ax, b[1] - ay
    len2 = dx * dx + dy * dy
    s = 0.0 if len2 == 0.0 else min(max(((px - ax) * dx + (py - ay) * dy) / len2, 0.0), 1.0)
    return math.hypot(px - ax - s * dx, py - ay - s * dy)


def rasterize(strokes: list[Stroke], width: int, height: int) -> list[list[int]]:
    """Label image, rows TOP-first (image file order): a pixel centre within a stroke's radius of its
    polyline gets the stroke's label; later strokes paint over earlier ones."""
    rows = [[NO_LABEL] * width for _ in range(height)]
    for stroke in strokes:
        r = max(stroke.radius_px, MIN_RADIUS_PX)
        pts = stroke.points if len(stroke.points) > 1 else stroke.points * 2
        for a, b in itertools.pairwise(pts):
            x0 = max(0, math.floor(min(a[0], b[0]) - r))
            x1 = min(width - 1, math.ceil(max(a[0], b[0]) + r))
            y0 = max(0, math.floor(min(a[1], b[1]) - r))
            y1 = min(height - 1, math.ceil(max(a[1], b[1]) + r))
            for j in range(y0, y1 + 1):  # j counts pixels bottom-up
                row = rows[height - 1 - j]
                for i in range(x0, x1 + 1):
                    if _segment_distance(i + 0.5, j + 0.5, a, b) <= r:
                        row[i] = stroke.label
    return rows


def encode_png(rows: list[list[int]]) -> bytes:
    """8-bit RGB PNG of a label image: each label in its code colour, black where nothing is scribbled."""
    height, width = len(rows), len(rows[0]) if rows else 0
    palette = {NO_LABEL: b"\x00\x00\x00"} | {k: bytes(c) for k, c in enumerate(C.SCRIBBLE_COLOURS)}
    raw = b"".join(b"\x00" + b"".join(palette[v] for v in row) for row in rows)

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", width, height, PNG_BIT_DEPTH, PNG_COLOUR_TYPE_RGB, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def legend() -> list[tuple[str, str]]:
    """(colour name, what it marks) for each code colour, from the engine's colour code."""
    return [
        (COLOUR_NAMES.get(rgb, "#{:02x}{:02x}{:02x}".format(*rgb)), f"part {k + 1} (Foreground{k + 1})")
        for k, rgb in enumerate(C.SCRIBBLE_COLOURS)
    ]
