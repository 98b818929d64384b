"""Where the add-on's planes go in the 3D viewport (the paint canvases, the live preview): in a row beyond every
object of the artist's scene, so nothing the extension adds sits inside or on top of their work. No bpy here.

A plane lies in the XY plane (facing +Z, as a canvas is painted from the top view), its corner at its location and
its size ``(w, h)`` along +X and +Y. The row starts ``margin`` to the +X of the scene's largest X (at X = 0 when
the scene is empty or lies at negative X) and runs along +X, one plane per slot: past the scene's largest X, a
plane cannot overlap any object whatever their Y and Z. The row lies on the ground (Z = 0) from Y = 0, as in an
empty scene, so it stays beside the scene rather than floating away from it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

Vec3 = tuple[float, float, float]

#: Space between the scene's objects and the row, in scene units.
MARGIN = 0.5
#: A plane's slot in the row is this much wider than the plane (at least 1 unit wide before it), so planes never touch.
SLOT = 1.2


@dataclass(frozen=True)
class Box:
    """An axis-aligned box in world space."""

    lo: Vec3
    hi: Vec3

    @staticmethod
    def around(points: Iterable[Sequence[float]]) -> Box:
        """The smallest box holding ``points`` (an object's eight world-space bound-box corners)."""
        pts = [tuple(float(c) for c in p) for p in points]
        if not pts:
            raise ValueError("a box needs at least one point")
        lo = (min(p[0] for p in pts), min(p[1] for p in pts), min(p[2] for p in pts))
        hi = (max(p[0] for p in pts), max(p[1] for p in pts), max(p[2] for p in pts))
        return Box(lo, hi)

    def overlaps(self, other: Box) -> bool:
        """Do the two boxes share any volume or face (touching counts: a plane lying on a face is on the object)?"""
        return all(self.lo[k] <= other.hi[k] and other.lo[k] <= self.hi[k] for k in range(3))


def plane_box(location: Vec3, size: tuple[float, float]) -> Box:
    """The box of a plane placed at ``location`` with ``size`` (its thickness is zero)."""
    x, y, z = location
    return Box((x, y, z), (x + size[0], y + size[1], z))


def place_row(boxes: Sequence[Box], sizes: Sequence[tuple[float, float]], margin: float = MARGIN) -> list[Vec3]:
    """Locations for planes of ``sizes`` (each ``(w, h)``) in one row along +X that overlaps none of ``boxes`` (the
    scene's objects, the add-on's own left out) nor each other; the first plane first."""
    if margin < 0:
        raise ValueError(f"margin {margin} is negative")
    x = max(0.0, max(b.hi[0] for b in boxes) + margin) if boxes else 0.0
    out: list[Vec3] = []
    for w, h in sizes:
        if w <= 0 or h <= 0:
            raise ValueError(f"plane size {(w, h)} is not positive")
        out.append((x, 0.0, 0.0))
        x += SLOT * max(1.0, w)
    return out
