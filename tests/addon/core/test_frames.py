"""Scene frames -> what the engine reads (``core.frames``): file numbers, mask and scribble names, positions."""

from __future__ import annotations

import pytest
from neural_atlas.addon.core import frames as F
from neural_atlas.addon.core.errors import UserError


def test_mask_file_names_follow_plate_numbers():
    assert F.file_number("/a/plate_0012.png") == 12
    assert F.file_number("/a/clip.mov") is None
    assert F.mask_file_names([1, 2], 12, 1) == ["00012.png", "00013.png"]
    assert F.mask_file_names([5, 6], None, 1) == ["00000.png", "00001.png"]


def test_scribbles_are_named_by_the_plates_numbers_or_the_movies_position():
    assert F.scribble_file_name(3, 12, 1) == "00014.png"
    assert F.scribble_file_name(3, None, 1) == "00002.png"


def test_frame_range_whole_clip_or_clipped_to_it():
    assert F.frame_range(2, 10, 0, 0, whole_clip=True) == (2, 11)
    assert F.frame_range(2, 10, 0, 5, whole_clip=False) == (2, 5)
    assert F.frame_range(2, 10, 4, 99, whole_clip=False) == (4, 11)
    with pytest.raises(UserError, match="frames 20-30 are outside the clip"):
        F.frame_range(2, 10, 20, 30, whole_clip=False)


def test_positions_count_from_the_clips_first_frame():
    assert F.positions(3, 5, 3) == (0, 2)
    assert F.positions(1, 50, 1) == (0, 49)
