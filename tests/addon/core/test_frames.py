"""Scene frames <-> the plate (``core.frames``): file numbers, mask and scribble names, the engine's --frames in
the plate's numbers, and the plate's rate and pixel aspect ratio as Blender's scene stores them."""

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


def test_the_engine_is_given_the_plates_frame_numbers():
    """A sequence plate.1001.exr ... loaded at scene frame 1 (Blender's default) fits --frames 1003-1005 for scene
    frames 3-5; a movie's frames count from 0."""
    assert F.plate_numbers(3, 5, 1, 1001) == (1003, 1005)
    assert F.plate_numbers(1001, 1100, 1001, 1001) == (1001, 1100)
    assert F.plate_numbers(3, 5, 1, None) == (2, 4)
    assert F.plate_numbers(3, 5, 3, 0) == (0, 2)


def test_scene_rate_is_the_plates_exact_fraction():
    assert F.scene_fps((24000, 1001)) == (24000, 1001.0)  # 24000 / 1001.0 exactly, as Blender sets from a movie
    assert F.scene_fps((25, 1)) == (25, 1.0)
    assert F.scene_fps((30000, 1001)) == (30000, 1001.0)
    fps, base = F.scene_fps((60000, 1001))  # beyond Blender's short: 60 / 1.001
    assert fps == 60 and abs(fps / base - 60000 / 1001) < 1e-12
    assert F.scene_fps(None) is None and F.scene_fps((0, 1)) is None


def test_scene_pixel_aspect_is_the_plates():
    assert F.scene_pixel_aspect(2.0) == (2.0, 1.0)  # 2x anamorphic: pixels twice as wide
    assert F.scene_pixel_aspect(0.5) == (1.0, 2.0)
    assert F.scene_pixel_aspect(1.0) == (1.0, 1.0)
    assert F.scene_pixel_aspect(0.0) == (1.0, 1.0)


def test_a_sequence_clip_is_given_to_the_engine_as_its_pattern():
    assert F.sequence_pattern("/plates/plate.1001.exr") == "/plates/plate.####.exr"
    assert F.sequence_pattern("/plates/00003.png") == "/plates/#####.png"
    assert F.sequence_pattern("/plates/shot2_v3_0012.png") == "/plates/shot2_v3_####.png"
    assert F.sequence_pattern("/plates/still.png") == "/plates"


def test_the_scene_range_is_the_imported_frames_unless_the_artists_lies_within_them():
    """Blender's 1-250 (or a range beside the shot) becomes the shot's 1011-1022; a range narrowed to 1014-1018
    (or the shot's own) is left alone; ``force`` sets the imported frames whatever the range."""
    shot = (1011, 1022)
    assert F.scene_range((1, 250), shot) == shot
    assert F.scene_range((10, 21), shot) == shot
    assert F.scene_range((1000, 1015), shot) == shot  # partly outside: frames the export does not have
    assert F.scene_range((1014, 1018), shot) == (1014, 1018)
    assert F.scene_range(shot, shot) == shot
    assert F.scene_range((1015, 1015), shot) == (1015, 1015)
    assert F.scene_range((1014, 1018), shot, force=True) == shot


def test_a_clip_numbered_otherwise_than_the_scene_is_named():
    """plate.1011.png loaded at scene frame 1 (Blender's default) is named with what to view instead; a clip at
    1011, or a movie, is not."""
    assert F.clip_offset_note("plate.1011.png", 1, 1011, "NA_Plate") == (
        "clip 'plate.1011.png' shows plate frame 1011 at scene frame 1; view 'NA_Plate' in the Clip Editor to see "
        "plate frame N at scene frame N"
    )
    assert F.clip_offset_note("plate.1011.png", 1011, 1011, "NA_Plate") is None
    assert F.clip_offset_note("shot.mov", 1, None, "NA_Plate") is None
