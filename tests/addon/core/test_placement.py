"""Placing the add-on's planes beyond the scene's objects (``core.placement``): no plane overlaps an object or
another plane, the row starts at the origin in an empty scene, and it keeps the old side-by-side spacing."""

from __future__ import annotations

import itertools
import random

import pytest
from neural_atlas.addon.core import placement as L


def _cube(centre, half):
    return L.Box.around(
        (centre[0] + sx * half, centre[1] + sy * half, centre[2] + sz * half)
        for sx, sy, sz in itertools.product((-1, 1), repeat=3)
    )


def test_an_empty_scene_gets_the_row_at_the_origin_side_by_side():
    sizes = [(1.5, 1.0), (0.5, 1.0), (2.0, 1.0)]
    assert L.place_row([], sizes) == [(0.0, 0.0, 0.0), (pytest.approx(1.8), 0.0, 0.0), (pytest.approx(3.0), 0.0, 0.0)]


def test_the_row_starts_past_the_largest_x_with_a_margin():
    boxes = [_cube((0, 0, 0), 1.0), _cube((4, -3, 2), 0.5)]  # the factory cube; another reaching x = 4.5
    locs = L.place_row(boxes, [(1.0, 1.0), (1.0, 1.0)])
    assert locs[0] == (pytest.approx(5.0), 0.0, 0.0) and locs[1][0] == pytest.approx(6.2)


def test_a_scene_at_negative_x_leaves_the_row_at_the_origin():
    assert L.place_row([_cube((-10, 0, 0), 1.0)], [(1.0, 1.0)]) == [(0.0, 0.0, 0.0)]


def test_no_plane_overlaps_an_object_or_another_plane():
    rng = random.Random(7)
    for _ in range(200):
        boxes = [
            _cube((rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-2, 2)), rng.uniform(0.01, 3))
            for _ in range(rng.randint(0, 6))
        ]
        sizes = [(rng.uniform(0.2, 4.0), 1.0) for _ in range(rng.randint(1, 4))]
        planes = [L.plane_box(loc, size) for loc, size in zip(L.place_row(boxes, sizes), sizes, strict=True)]
        assert not any(p.overlaps(b) for p in planes for b in boxes)
        assert not any(a.overlaps(b) for a, b in itertools.combinations(planes, 2))
        assert all(p.lo[0] >= 0.0 for p in planes)


def test_boxes_overlap_when_they_share_space_or_touch():
    a = L.Box((0, 0, 0), (1, 1, 1))
    assert a.overlaps(L.Box((0.5, 0.5, 0.5), (2, 2, 2))) and a.overlaps(L.Box((1, 0, 0), (2, 1, 1)))
    assert not a.overlaps(L.Box((1.01, 0, 0), (2, 1, 1)))
    assert not a.overlaps(L.Box((0, 0, 1.5), (1, 1, 2)))  # above it


def test_bad_sizes_and_margins_are_refused():
    with pytest.raises(ValueError, match="not positive"):
        L.place_row([], [(0.0, 1.0)])
    with pytest.raises(ValueError, match="negative"):
        L.place_row([], [(1.0, 1.0)], margin=-1)
    with pytest.raises(ValueError, match="at least one point"):
        L.Box.around([])
