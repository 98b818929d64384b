"""The mask tests' oracle (``mask_reference``): Blender's mask space and the pixel-centre polygon rasterizer."""

from __future__ import annotations

import mask_reference as M
import pytest


@pytest.mark.parametrize(("w", "h"), [(854, 480), (480, 854), (64, 64)])
def test_mask_space_round_trip(w, h):
    for x, y in ((0, 0), (w, h), (w / 3, h / 7)):
        u, v = M.px_to_mask(x, y, w, h)
        assert M.mask_to_px(u, v, w, h) == pytest.approx((x, y))
    assert M.px_to_mask(w / 2, h / 2, w, h) == pytest.approx((0.5, 0.5))
    long_side = max(w, h)
    assert M.px_to_mask(w, h, w, h) == pytest.approx((0.5 + w / long_side / 2, 0.5 + h / long_side / 2))


def test_reference_rasterizer_counts_pixel_centres():
    rows = M.rasterize_polygon([(2, 1), (6, 1), (6, 4), (2, 4)], 8, 6)
    assert sum(map(sum, rows)) == 12
    assert rows[1][2] and not rows[0][2] and not rows[1][6]
    assert M.iou(rows, rows) == 1.0
