"""Scribbles from Movie Clip Editor annotations (``addon/scribbles.py``): stroke reading on stand-in annotation
objects, and the datablock access on real annotations of this test's Blender (the raster maths:
core/test_scribble_math.py).

``frame.strokes`` has no ``new`` (real strokes need the Annotate operator in a clip editor:
test_scribble_fit.py), so here the strokes are stand-ins shaped like the RNA (layer.color/thickness/frames,
frame.frame_number/strokes, point.co); what bpy can build (clip, annotation datablock, layers, frames) is
tested for real.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace as NS

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from fake_export import decode_png, write_png  # noqa: E402
from neural_atlas.addon import compat, scribbles  # noqa: E402
from neural_atlas.addon.core import scribble_math as S  # noqa: E402

from engine import contract as C  # noqa: E402


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
    px = decode_png(Path(paths[0]).read_bytes())
    assert tuple(px[20 - 1 - 10][10]) == C.SCRIBBLE_COLOURS[0]  # on the red stroke (pixel row 10 from the bottom)
    assert tuple(px[20 - 1 - 4][32]) == C.SCRIBBLE_COLOURS[1]  # the green dot at (0.8, 0.2)
    assert tuple(px[0][0]) == (0, 0, 0)


def test_real_clip_annotation_datablock(tmp_path):
    write_png(tmp_path / "00001.png", np.zeros((20, 40, 4), np.uint8) + 255)
    clip = bpy.data.movieclips.load(str(tmp_path / "00001.png"))
    assert scribbles.clip_annotation(clip) is None  # nothing drawn yet
    ann = compat.new_clip_annotation(clip, "NA_test_scribbles")
    layer = ann.layers.new("part 1")
    layer.color = (1.0, 0.0, 0.0)
    layer.frames.new(1)
    assert scribbles.clip_annotation(clip) == ann
    assert S.layer_label(tuple(layer.color)) == 0
    # a keyframe without strokes is not a scribbled frame, and writes nothing
    assert scribbles.scribbled_frames(ann) == []
    assert scribbles.write_scribbles(clip, str(tmp_path / "scr"), 40, 20, str) == []
    assert not hasattr(layer.frames[0].strokes, "new")  # real strokes need the Annotate operator (test_scribble_fit)
