"""Scribbles from Movie Clip Editor annotations: the pure raster maths, stroke reading on stand-in
annotation objects, and the datablock access on real bpy 4.5 / 5.0 annotations.

``frame.strokes`` has no ``new`` (real strokes need the Annotate operator in a clip editor:
test_scribble_fit.py), so here the strokes are stand-ins shaped like the RNA (layer.color/thickness/frames,
frame.frame_number/strokes, point.co); what bpy can build (clip, annotation datablock, layers, frames) is
tested for real.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path
from types import SimpleNamespace as NS

import pytest
from neural_atlas.addon import scribble_math as S
from neural_atlas.addon import scribbles

from engine import contract as C


def _decode_rgb_png(data: bytes) -> tuple[int, int, list[list[tuple[int, int, int]]]]:
    pos, idat, w, h = 8, b"", 0, 0
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos : pos + 4])
        tag, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + n]
        if tag == b"IHDR":
            w, h = struct.unpack(">II", body[:8])
            assert body[8:10] == b"\x08\x02"  # 8-bit RGB
        elif tag == b"IDAT":
            idat += body
        pos += 12 + n
    raw = zlib.decompress(idat)
    rows = []
    for r in range(h):
        line = raw[r * (1 + 3 * w) + 1 : (r + 1) * (1 + 3 * w)]
        rows.append([tuple(line[3 * i : 3 * i + 3]) for i in range(w)])
    return w, h, rows


def test_layer_colour_code():
    assert S.layer_label((1.0, 0.0, 0.0)) == 0
    assert S.layer_label((0.0, 1.0, 0.0)) == 1
    assert S.layer_label((0.0, 0.0, 1.0)) == 2
    near = 1.0 - C.SCRIBBLE_TOLERANCE / 255.0
    assert S.layer_label((near, 0.1, 0.1)) == 0
    assert S.layer_label((0.5, 0.5, 0.5)) is None
    assert S.layer_label((1.0, 0.5, 0.0)) is None  # orange is no code colour


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
    w, h, px = _decode_rgb_png(S.encode_png(rows))
    assert (w, h) == (2, 2)
    assert px == [[C.SCRIBBLE_COLOURS[0], (0, 0, 0)], [(0, 0, 0), C.SCRIBBLE_COLOURS[1]]]


def _fake_clip(attr: str) -> NS:
    def frame(n, strokes):
        return NS(frame_number=n, strokes=[NS(points=[NS(co=(x, y)) for x, y in s]) for s in strokes])

    red = NS(color=(1.0, 0.0, 0.0), thickness=2, annotation_hide=False, frames=[frame(3, [[(0.1, 0.5), (0.4, 0.5)]])])
    green = NS(
        color=(0.0, 1.0, 0.0),
        thickness=4,
        annotation_hide=False,
        frames=[frame(3, [[(0.8, 0.2)]]), frame(7, [[(0.5, 0.5)]])],
    )
    note = NS(color=(1.0, 1.0, 1.0), thickness=3, annotation_hide=False, frames=[frame(5, [[(0.5, 0.5)]])])
    hidden = NS(color=(0.0, 0.0, 1.0), thickness=3, annotation_hide=True, frames=[frame(9, [[(0.5, 0.5)]])])
    return NS(**{attr: NS(layers=[red, green, note, hidden])})


@pytest.mark.parametrize("attr", ["annotation", "grease_pencil"])  # 5.0, 4.5
def test_strokes_read_from_either_versions_attribute(tmp_path, attr):
    clip = _fake_clip(attr)
    ann = scribbles.clip_annotation(clip)
    assert scribbles.scribbled_frames(ann) == [3, 7]  # white notes and hidden layers are ignored
    strokes = scribbles.frame_strokes(ann, 3, 40, 20)
    assert [(s.label, s.radius_px) for s in strokes] == [(0, 1.0), (1, 2.0)]
    assert strokes[0].points == ((4.0, 10.0), (16.0, 10.0))
    paths = scribbles.write_scribbles(clip, str(tmp_path / "scr"), 40, 20, lambda f: f"{f:05d}.png")
    assert [p.rsplit("/", 1)[1] for p in paths] == ["00003.png", "00007.png"]
    _, _, px = _decode_rgb_png(Path(paths[0]).read_bytes())
    assert px[20 - 1 - 10][10] == C.SCRIBBLE_COLOURS[0]  # on the red stroke (pixel row 10 from the bottom)
    assert px[20 - 1 - 4][32] == C.SCRIBBLE_COLOURS[1]  # the green dot at (0.8, 0.2)
    assert px[0][0] == (0, 0, 0)


def test_real_clip_annotation_datablock(tmp_path):
    bpy = pytest.importorskip("bpy")
    import numpy as np
    from fake_export import write_png

    write_png(tmp_path / "00001.png", np.zeros((20, 40, 4), np.uint8) + 255)
    clip = bpy.data.movieclips.load(str(tmp_path / "00001.png"))
    assert scribbles.clip_annotation(clip) is None  # nothing drawn yet
    data = bpy.data.annotations if hasattr(bpy.data, "annotations") else bpy.data.grease_pencils
    ann = data.new("NA_test_scribbles")
    if hasattr(clip, "annotation"):
        clip.annotation = ann
    else:
        clip.grease_pencil = ann
    layer = ann.layers.new("part 1")
    layer.color = (1.0, 0.0, 0.0)
    layer.frames.new(1)
    assert scribbles.clip_annotation(clip) == ann
    assert S.layer_label(tuple(layer.color)) == 0
    # a keyframe without strokes is not a scribbled frame, and writes nothing
    assert scribbles.scribbled_frames(ann) == []
    assert scribbles.write_scribbles(clip, str(tmp_path / "scr"), 40, 20, str) == []
    assert not hasattr(layer.frames[0].strokes, "new")  # real strokes need the Annotate operator (test_scribble_fit)
