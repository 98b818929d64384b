"""Scribbles' raster maths (``core.scribble_math``): the colour code, strokes -> label pixels -> PNG."""

from __future__ import annotations

from fake_export import decode_png
from neural_atlas.addon.core import scribble_math as S

from engine import contract as C


def test_layer_colour_code():
    assert S.layer_label((1.0, 0.0, 0.0)) == 0
    assert S.layer_label((0.0, 1.0, 0.0)) == 1
    assert S.layer_label((0.0, 0.0, 1.0)) == 2
    near = 1.0 - C.SCRIBBLE_TOLERANCE / 255.0
    assert S.layer_label((near, 0.1, 0.1)) == 0
    assert S.layer_label((0.5, 0.5, 0.5)) is None
    assert S.layer_label((1.0, 0.5, 0.0)) is None  # orange is no code colour


def test_legend_names_each_code_colour_and_its_layer():
    assert S.legend()[:4] == [
        ("red", "part 1 (Foreground1)"),
        ("green", "part 2 (Foreground2)"),
        ("blue", "part 3 (Foreground3)"),
        ("yellow", "part 4 (Foreground4)"),
    ]
    assert len(S.legend()) == len(C.SCRIBBLE_COLOURS)


def test_rasterize_marks_pixel_centres_within_the_radius():
    # a horizontal stroke along y = 2.5 (bottom-up), x from 1.5 to 5.5, radius 1: rows y=1.5..3.5 of it
    rows = S.rasterize([S.Stroke(1, 1.0, ((1.5, 2.5), (5.5, 2.5)))], 8, 6)
    marked = {(i, 6 - 1 - r) for r, row in enumerate(rows) for i, v in enumerate(row) if v == 1}
    expected = {
        (i, j)
        for i in range(8)
        for j in range(6)
        if S._segment_distance(i + 0.5, j + 0.5, (1.5, 2.5), (5.5, 2.5)) <= 1.0
    }
    assert marked == expected
    assert (1, 2) in marked and (5, 2) in marked and (1, 3) in marked and (0, 2) in marked and (6, 2) in marked
    assert (3, 0) not in marked and (3, 4) not in marked
    assert all(v in (S.NO_LABEL, 1) for row in rows for v in row)


def test_single_point_and_thin_strokes_still_mark_a_pixel():
    rows = S.rasterize([S.Stroke(0, 0.0, ((2.5, 1.5),))], 5, 4)
    assert [(i, r) for r, row in enumerate(rows) for i, v in enumerate(row) if v == 0] == [(2, 2)]


def test_later_strokes_paint_over_and_points_outside_are_clipped():
    strokes = [S.Stroke(0, 2.0, ((0.5, 0.5), (3.5, 0.5))), S.Stroke(1, 1.0, ((-10.0, 0.5), (1.5, 0.5)))]
    rows = S.rasterize(strokes, 4, 2)
    assert rows[1] == [1, 1, 1, 0]  # bottom row: green over red up to x = 2.5 (distance 1), red beyond


def test_png_holds_the_code_colours_top_row_first():
    rows = [[0, S.NO_LABEL], [S.NO_LABEL, 1]]
    px = decode_png(S.encode_png(rows))
    assert px.shape == (2, 2, 3)  # 8-bit RGB
    assert px.tolist() == [[list(C.SCRIBBLE_COLOURS[0]), [0, 0, 0]], [[0, 0, 0], list(C.SCRIBBLE_COLOURS[1])]]
