"""Export's pure pieces: the atlas frame of a layer and the per-frame coverage binning, at edge cases."""

from __future__ import annotations

import numpy as np

from engine.export.exporter import MIN_BOX_EXTENT, _Coverage, _fill_holes, layer_frame_for


def test_degenerate_box_gets_a_minimum_extent():
    fr = layer_frame_for((0.2, 0.2, 0.2, 0.2), 100)  # a layer that never shows: zero extent
    assert fr.size == (100, 100)
    assert abs(fr.box[2] - fr.box[0] - MIN_BOX_EXTENT) < 1e-12
    uv, inside = fr.to_texture_uv(np.array([[0.2, 0.2], [5.0, -5.0]]))
    assert np.isfinite(uv).all() and inside.tolist() == [True, False]


def test_texture_uv_is_bottom_left_with_texel_centres():
    fr = layer_frame_for((-1.0, -0.5, 1.0, 0.5), 8)  # 2:1 box -> 8x4 texels
    assert fr.size == (8, 4)
    centres = fr.texel_centres()
    uv, inside = fr.to_texture_uv(centres)
    assert inside.all()
    np.testing.assert_allclose(uv[0, 0], [0.5 / 8, 1 - 0.5 / 4], atol=1e-6)  # file row 0 is the top: v near 1
    np.testing.assert_allclose(uv[3, 7], [7.5 / 8, 0.5 / 4], atol=1e-6)


def test_fill_holes_closes_one_cell_gaps_only():
    count = np.zeros((7, 7))
    total = np.zeros((7, 7))
    count[::2, ::2] = 1  # a frame magnified 2x: every other cell hit
    total[::2, ::2] = 0.8
    out = _fill_holes(total, count)
    assert np.allclose(out, 0.8)  # every gap cell had a hit neighbour
    lone = np.zeros((7, 7))
    lone[3, 3] = 1
    out = _fill_holes(lone * 0.5, lone)
    assert np.isnan(out[0, 0]) and out[3, 3] == 0.5 and out[2, 2] == 0.5


def test_coverage_median_for_foreground_max_for_background():
    uv = np.array([[0.0, 0.0]])
    fg = _Coverage(uv_per_px=0.1, frames=3, foreground=True)
    bg = _Coverage(uv_per_px=0.1, frames=3, foreground=False)
    for t, a in enumerate((1.0, 0.0, 1.0)):  # seen, occluded once, seen
        fg.add(t, uv, np.array([a]))
        bg.add(t, uv, np.array([a]))
    cell = fg.cells // 2
    assert fg.grid()[cell, cell] == 1.0  # median ignores the one occluded frame
    fg2 = _Coverage(uv_per_px=0.1, frames=3, foreground=True)
    for t, a in enumerate((0.0, 0.0, 1.0)):
        fg2.add(t, uv, np.array([a]))
    assert fg2.grid()[cell, cell] == 0.0  # mostly not object: not object
    assert bg.grid()[cell, cell] == 1.0
    assert np.isfinite(fg.box()).all() and fg.grid().max() <= 1.0


def test_coverage_of_a_layer_that_never_shows():
    cov = _Coverage(uv_per_px=0.05, frames=2, foreground=True)
    for t in range(2):
        cov.add(t, np.random.default_rng(t).uniform(-1, 1, (50, 2)), np.zeros(50))
    u0, v0, u1, v1 = cov.box()  # nothing owned, nothing faintly visible: the model's whole atlas square
    assert np.allclose([u0, v0], [-u1, -v1]) and 1.0 < u1 < 1.3
    assert np.isfinite(cov.box()).all() and cov.grid().max() == 0.0
