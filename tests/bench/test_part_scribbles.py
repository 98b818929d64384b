"""Strokes drawn from part masks, as a user scribbles: inside each part, away from its edge, in the part's colour,
read back by the engine's own scribble reader as that part's layer."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from bench.motion_scenes import PART_MASKS, write_motion_clips
from bench.paint_table import TableFit, part_queries
from bench.part_scribbles import INSET_PX, part_stroke, write_part_scribbles
from bench.report_file import read_tracks
from engine import contract as C
from engine.data.scribbles import NO_LABEL, read_scribbles
from engine.io.clip import open_clip
from engine.terms.run_folder import RUN_CLIP
from tests.bench.test_paint_table import tiny_limbs_table


def test_a_stroke_runs_along_the_long_axis_inside_the_part_away_from_its_edge():
    mask = np.zeros((60, 100), bool)
    mask[20:40, 10:90] = True  # a bar 80 wide, 20 tall
    stroke = part_stroke(mask)
    ys, xs = np.nonzero(stroke)
    assert (xs.max() - xs.min()) > 40 and (ys.max() - ys.min()) <= 6  # along the bar, not across it
    inner = cv2.erode(mask.astype(np.uint8), np.ones((2 * INSET_PX + 1,) * 2, np.uint8)) > 0
    assert (stroke <= inner).all()


def test_an_empty_part_has_no_stroke_and_a_tiny_one_keeps_a_pixel():
    assert not part_stroke(np.zeros((20, 20), bool)).any()
    tiny = np.zeros((20, 20), bool)
    tiny[9:11, 9:11] = True
    stroke = part_stroke(tiny)
    assert stroke.any() and (stroke <= tiny).all()


def test_the_engine_reads_each_parts_strokes_as_its_layer(tmp_path):
    root = tmp_path / "scenes"
    write_motion_clips(root, width=96, height=64, frames=5, kinds=("limbs_jump",))
    clip = root / "limbs_jump"
    parts = sorted(p for p in (clip / PART_MASKS).iterdir() if p.is_dir())
    folder, drawn = write_part_scribbles(parts, tmp_path / "scribbles")
    assert drawn == [0, 2, 4]
    info = open_clip(str(clip / "frames"))
    labels = read_scribbles(folder, info, (info.width, info.height))
    for i in range(5):
        if i not in drawn:
            assert (labels[i] == NO_LABEL).all()
            continue
        for k, part in enumerate(parts):
            mask = cv2.imread(str(sorted(part.iterdir())[i]), cv2.IMREAD_GRAYSCALE) > 127
            assert (labels[i] == k).any() and (mask[labels[i] == k]).all()
    assert write_part_scribbles(parts, tmp_path / "every", tuple(np.linspace(0.0, 1.0, 5)))[1] == [0, 1, 2, 3, 4]
    again = {p.name: p.read_bytes() for p in folder.iterdir()}
    write_part_scribbles(parts, folder)
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == again


def test_one_part_or_too_many_is_refused(tmp_path):
    most = len(C.SCRIBBLE_COLOURS)
    with pytest.raises(ValueError, match=rf"2\.\.{most} parts, not 1"):
        write_part_scribbles([tmp_path], tmp_path / "s")
    with pytest.raises(ValueError, match=rf"not {most + 1}"):
        write_part_scribbles([tmp_path] * (most + 1), tmp_path / "s")


@pytest.mark.slow
def test_the_table_fits_the_one_mask_split_by_the_strokes(tmp_path):
    root, record = tiny_limbs_table(tmp_path, scribbles=True)
    (row,) = record["rows"]
    assert row["layers"] == 3 and row["scribbles"] == str(tmp_path / "out" / "scribbles" / "limbs_jump")
    clip_json = (tmp_path / "out" / "runs" / "limbs_jump" / RUN_CLIP).read_text()
    assert "scribbles" in clip_json and str(root / "limbs_jump" / "masks") in clip_json
    # scored per part too: the queries on each part's mask at their frame
    tracks = read_tracks(root / "limbs_jump" / "tracks_tapvid.npz")
    owned = part_queries(root / "limbs_jump", tracks)
    assert set(owned) == {"body", "front_limb"} and not (owned["body"] & owned["front_limb"]).any()
    assert set(row["paint_by_part"]) == {name for name, keep in owned.items() if keep.any()}
    assert all(0.0 <= v <= 1.0 for v in row["paint_by_part"].values())
    with pytest.raises(ValueError, match="choose one"):
        TableFit.of_flags(parts=True, scribbles=True)
