"""Export's pure pieces: the atlas frame of a layer and the per-frame coverage binning, at edge cases."""

from __future__ import annotations

import warnings

import numpy as np

from engine.export.atlas_frame import MIN_BOX_EXTENT, _Coverage, _fill_holes, layer_frame_for


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


def _body_and_limb(frames: int, limb_frames: set[int], stray: bool = False) -> _Coverage:
    """A foreground whose body (u, v in [-0.2, 0.2]) is owned in every frame and whose limb (u in [0.4, 0.6]) is
    owned only in ``limb_frames`` (a leg swinging through atlas cells that are background in the other frames);
    ``stray``: a pixel far out at u = 1.2, owned in one frame only."""
    rng = np.random.default_rng(0)
    cov = _Coverage(uv_per_px=0.01, frames=frames, foreground=True)
    for t in range(frames):
        body = rng.uniform(-0.2, 0.2, (4000, 2))
        limb = np.c_[rng.uniform(0.4, 0.6, 1000), rng.uniform(-0.1, 0.1, 1000)]
        uv = np.concatenate((body, limb))
        alpha = np.concatenate((np.ones(4000), np.full(1000, 1.0 if t in limb_frames else 0.0)))
        if stray:  # background maps there in the other frames, so the cell's median coverage is 0
            uv, alpha = np.concatenate((uv, [[1.2, 0.0]])), np.concatenate((alpha, [1.0 if t == 0 else 0.0]))
        cov.add(t, uv, alpha)
    return cov


def test_a_limb_owned_in_a_few_frames_is_inside_the_box():
    """Median coverage alone drops a limb owned in 3 of 10 frames (its pixels would get Z = 0: no paint there);
    the box holds every atlas point the layer owns, but for BOX_OWNED_TRIM at each end."""
    cov = _body_and_limb(10, {1, 4, 7})
    cell = cov.cells // 2 + int(0.5 * cov.scale)
    assert cov.grid()[cov.cells // 2, cell] == 0.0  # the limb's cells: median says not object
    u0, v0, u1, v1 = cov.box()
    assert u1 >= 0.6 and u0 <= -0.2 and v0 <= -0.2 and v1 >= 0.2
    assert u1 < 0.6 + 0.1  # the limb's end plus the margin, not the whole atlas square
    frame = layer_frame_for(cov.box(), 64)
    limb_uv = np.array([[0.45, 0.0], [0.59, 0.09], [0.59, -0.09]])
    assert frame.to_texture_uv(limb_uv)[1].all()


def test_one_stray_owned_pixel_does_not_stretch_the_box():
    """One owned pixel far from the body (a fleck of mis-fitted alpha) is within the trimmed share: the box is the
    body's and limb's, as without it."""
    with_stray, without = _body_and_limb(10, {1, 4, 7}, stray=True).box(), _body_and_limb(10, {1, 4, 7}).box()
    assert np.allclose(with_stray, without, atol=0.02) and with_stray[2] < 0.7  # a cell or two of the trim, not 1.2


def test_the_background_box_is_unchanged_by_the_owned_points():
    """The background's box is its maximum coverage's (it owns every cell it ever shows): no owned-point rule."""
    cov = _Coverage(uv_per_px=0.01, frames=2, foreground=False)
    for t in range(2):
        cov.add(t, np.array([[0.0, 0.0], [0.5, 0.5]]), np.array([1.0, 0.0]))
    _, _, u1, v1 = cov.box()
    assert u1 < 0.1 and v1 < 0.1


def test_the_texture_keeps_what_is_seen_in_a_few_frames_and_the_box_does_not_move():
    """The body behind a swinging limb, or the limb itself, is seen in a minority of frames: the plain median gives
    its texels coverage 0 (their colour lost from the texture); the texture's coverage is the median over the frames
    where they are seen, while the box, decided by the plain median and the owned points, is the same as before."""
    cov = _body_and_limb(10, {1, 4, 7})
    row, limb = cov.cells // 2, cov.cells // 2 + int(0.5 * cov.scale)
    assert cov.grid()[row, limb] == 0.0
    assert cov.texture_grid()[row, limb] == 1.0
    assert cov.texture_grid()[row, row] == 1.0  # the body: seen in every frame either way
    far = cov.cells // 2 + int(1.0 * cov.scale)  # background that the layer's mapping sends there, never seen
    assert cov.texture_grid()[row, far] == cov.grid()[row, far] == 0.0
    frame = layer_frame_for(cov.box(), 64)
    tex = cov.sample(frame)
    uv, _ = frame.to_texture_uv(np.array([[0.5, 0.0]]))
    x, y = int(uv[0, 0] * 64), int((1.0 - uv[0, 1]) * frame.size[1])
    assert tex[y, x] > 0.99  # the limb's texel in the written texture


def test_a_fleck_seen_in_one_frame_keeps_the_plain_median():
    cov = _Coverage(uv_per_px=0.1, frames=5, foreground=True)
    for t in range(5):
        cov.add(t, np.array([[0.0, 0.0]]), np.array([0.9 if t == 2 else 0.0]))
    cell = cov.cells // 2
    assert cov.texture_grid()[cell, cell] == cov.grid()[cell, cell] == 0.0
    one = _Coverage(uv_per_px=0.1, frames=1, foreground=True)  # a one-frame clip: seen once is seen in every frame
    one.add(0, np.array([[0.0, 0.0]]), np.array([0.6]))
    assert abs(one.texture_grid()[cell, cell] - 0.6) < 1e-3


def test_the_medians_over_frames_do_not_depend_on_the_chunk(monkeypatch):
    """Chunked medians equal the medians of the whole stack (NaN where nothing landed in a frame)."""
    from engine.export import atlas_frame

    rng = np.random.default_rng(3)
    stack = rng.uniform(0, 1, (7, 1000)).astype(np.float16)
    stack[rng.uniform(size=stack.shape) < 0.4] = np.nan
    stack[:, :50] = np.nan  # never landed
    whole = atlas_frame._median_over_frames(stack, seen_only=True)
    plain = atlas_frame._median_over_frames(stack, seen_only=False)
    monkeypatch.setattr(atlas_frame, "MEDIAN_CHUNK_CELLS", 64)
    np.testing.assert_array_equal(atlas_frame._median_over_frames(stack, seen_only=True), whole)
    np.testing.assert_array_equal(atlas_frame._median_over_frames(stack, seen_only=False), plain)
    assert (whole[:50] == 0).all() and (plain[:50] == 0).all()
    s = stack.astype(np.float32)
    with warnings.catch_warnings():  # a column that no frame saw (p = 0.4^7): numpy warns, its median is NaN -> 0
        warnings.simplefilter("ignore", RuntimeWarning)
        np.testing.assert_allclose(plain[50:], np.nan_to_num(np.nanmedian(s[:, 50:], 0)))
    col = s[:, 100]
    seen = col[col > atlas_frame.SEEN_ALPHA]
    expect = np.median(seen) if len(seen) >= 2 else np.nanmedian(col)
    assert abs(whole[100] - expect) < 1e-6
