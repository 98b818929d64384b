"""Plates found and numbered the way pipeline tools do (engine.io.clip with fileseq): a folder of one sequence, a
pattern (``plate.####.exr``, ``%04d``, ``plate.1001-1100#.exr``), several sequences in a folder, gaps, ``--frames``
in the plate's numbers, and the plate's timing (rate, pixel aspect ratio, timecode) read from EXR, DPX and movies."""

from __future__ import annotations

import argparse
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import OpenImageIO as oiio
import pytest

from engine.cli_options import frame_range
from engine.errors import InputError
from engine.io.clip import frame_positions, iter_frames, open_clip
from engine.io.images import exr_timing, write_exr
from tests.media_files import write_image

FIRST = 1001
W, H = 8, 6


def _plate(folder: Path, numbers: list[int], name: str = "plate", timed: bool = True) -> Path:
    """EXR frames ``name.1001.exr`` ..., each filled with its own number / 10000 (so a frame read is known by its
    pixels), at 24000/1001 with 2:1 pixels and timecode 01:00:00:00 on frame 1001 (``timed``)."""
    folder.mkdir(parents=True, exist_ok=True)
    for n in numbers:
        timing = exr_timing((24000, 1001), 2.0, "01:00:00:00", n - FIRST) if timed else None
        write_exr(folder / f"{name}.{n:04d}.exr", {c: np.full((H, W), n / 10000, np.float32) for c in "RGB"},
                  attributes=timing)  # fmt: skip
    return folder


def _values(info) -> list[float]:
    return [round(float(rgb[0, 0, 0]) * 10000) for rgb in iter_frames(info)]


@pytest.mark.parametrize("pattern", ["plate.####.exr", "plate.%04d.exr", "plate.@.exr", "plate.#.exr"])
def test_a_pattern_names_the_sequence_and_its_frames_keep_their_numbers(tmp_path, pattern):
    folder = _plate(tmp_path / "plates", [1001, 1002, 1003])
    info = open_clip(folder / pattern)
    assert info.frame_numbers == (1001, 1002, 1003) and _values(info) == [1001, 1002, 1003]
    assert info.source == str(folder / "plate.####.exr")  # recorded one way, whatever spelling was given
    assert open_clip(info.source).frame_files == info.frame_files


def test_a_pattern_range_selects_those_frames_and_each_must_exist(tmp_path):
    folder = _plate(tmp_path / "plates", list(range(1001, 1006)))
    info = open_clip(folder / "plate.1002-1004#.exr")
    assert info.frame_numbers == (1002, 1003, 1004) and _values(info) == [1002, 1003, 1004]
    assert info.timecode == "01:00:00:01"
    with pytest.raises(InputError, match=r"frames 1006\.\.1009 of the pattern's range are missing"):
        open_clip(folder / "plate.1003-1009#.exr")


def test_a_folder_of_one_sequence_opens_as_before(tmp_path):
    folder = _plate(tmp_path / "plates", [1001, 1002])
    info = open_clip(folder)
    assert info.source == str(folder) and info.frame_numbers == (1001, 1002)


def test_several_sequences_in_a_folder_are_one_line_and_a_pattern_picks_one(tmp_path):
    folder = _plate(tmp_path / "plates", [1001, 1002, 1003])
    _plate(folder, [1, 2], name="slap_comp", timed=False)
    with pytest.raises(InputError) as err:
        open_clip(folder)
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"{folder}: holds 2 image sequences: ")
    assert "plate.####.exr (1001..1003)" in message and "slap_comp.####.exr (1..2)" in message
    assert f"pass one of them as a pattern, e.g. {folder}/" in message
    assert open_clip(folder / "slap_comp.####.exr").frame_numbers == (1, 2)
    assert _values(open_clip(folder / "plate.####.exr")) == [1001, 1002, 1003]


def test_a_pattern_that_matches_nothing_names_what_the_folder_holds(tmp_path):
    folder = _plate(tmp_path / "plates", [1001, 1002])
    with pytest.raises(InputError, match=r"no files match this pattern \(the folder holds plate\.####\.exr"):
        open_clip(folder / "plate_v2.####.exr")
    with pytest.raises(InputError, match="folder of the sequence pattern does not exist"):
        open_clip(tmp_path / "nowhere" / "plate.####.exr")


def test_one_frame_of_a_sequence_points_at_its_pattern(tmp_path):
    folder = _plate(tmp_path / "plates", [1001, 1002])
    with pytest.raises(InputError, match=r"is a single image, not a clip — .* a pattern such as .*plate\.####\.exr"):
        open_clip(folder / "plate.1001.exr")


def test_a_gap_is_reported_with_the_ranges_that_avoid_it_in_plate_numbers(tmp_path):
    folder = _plate(tmp_path / "plates", [1001, 1002, 1004, 1005])
    for source in (folder, folder / "plate.####.exr"):
        with pytest.raises(InputError) as err:
            open_clip(source)
        assert "frame 1003 is missing between plate.1002.exr and plate.1004.exr" in str(err.value)
        assert "(--frames 1001-1002 or 1004-1005)" in str(err.value)
    info = open_clip(folder / "plate.####.exr", frame_positions(folder / "plate.####.exr", (1004, 1005)))
    assert _values(info) == [1004, 1005]
    with pytest.raises(
        InputError, match=r"frame 1003 is not in the plate \(its frames are 1001\.\.1002, 1004\.\.1005\)"
    ):
        frame_positions(folder, (1003, 1004))


def test_frames_speak_plate_numbers(tmp_path):
    folder = _plate(tmp_path / "plates", list(range(1001, 1011)))
    assert frame_positions(folder, (1010, 1010)) == (9, 9)
    assert frame_positions(folder / "plate.####.exr", (1003, 1007)) == (2, 6)
    info = open_clip(folder, frame_positions(folder, (1003, 1007)))
    assert info.frame_numbers == tuple(range(1003, 1008)) and _values(info)[0] == 1003
    assert info.timecode == "01:00:00:02"  # the first selected frame's
    for numbers, needle in (((1000, 1005), "frame 1000 is not in the plate"),
                            ((1005, 1011), "frame 1011 is not in the plate"),
                            ((1007, 1003), "--frames 1007..1003 is reversed")):  # fmt: skip
        with pytest.raises(InputError) as err:
            frame_positions(folder, numbers)
        assert needle in str(err.value) and "(its frames are 1001..1010)" in str(err.value)
        assert "within 1001..1010" in str(err.value)


def test_frames_text_is_a_pipeline_range():
    assert frame_range("1010-1050") == (1010, 1050)
    assert frame_range("1010:1050") == (1010, 1050)
    assert frame_range("1010") == (1010, 1010)
    for bad in ("a-b", "1010-", "-5", "1:2:3"):
        with pytest.raises(argparse.ArgumentTypeError, match="FIRST-LAST in the plate's frame numbers"):
            frame_range(bad)
    with pytest.raises(argparse.ArgumentTypeError, match="frame range '1050-1010' is reversed: write 1010-1050"):
        frame_range("1050-1010")


def test_exr_plate_timing_is_read_from_its_header(tmp_path):
    info = open_clip(_plate(tmp_path / "plates", [1001, 1002]))
    assert info.rate == Fraction(24000, 1001) and info.fps == pytest.approx(23.976, abs=1e-3)
    assert info.pixel_aspect == 2.0 and info.timecode == "01:00:00:00"


def test_a_sequence_without_a_rate_takes_fps(tmp_path):
    folder = tmp_path / "pngs"
    folder.mkdir()
    for n in (1, 2):
        write_image(folder / f"f.{n:04d}.png", np.zeros((H, W, 3), np.uint8))
    info = open_clip(folder)
    assert (info.rate, info.fps, info.pixel_aspect, info.timecode) == (None, None, 1.0, None)
    assert open_clip(folder, fps=Fraction(25)).rate == 25
    with pytest.raises(InputError, match="--start-frame numbers a movie's frames, but this is an image sequence"):
        open_clip(folder, start_frame=1001)


def test_dpx_plate_timing_snaps_its_float_rate_to_the_ntsc_fraction(tmp_path):
    folder = tmp_path / "dpx"
    folder.mkdir()
    for n in (86400, 86401):
        spec = oiio.ImageSpec(W, H, 3, "uint16")
        spec.attribute("oiio:BitsPerSample", 10)
        spec.attribute("dpx:FrameRate", 23.976)
        spec.attribute("PixelAspectRatio", 2.0)
        spec.attribute("smpte:TimeCode", oiio.TypeDesc("timecode"), (0x01000000 + (n - 86400), 0))
        out = oiio.ImageOutput.create("dpx")
        assert out.open(str(folder / f"plate.{n}.dpx"), spec)
        out.write_image(np.zeros((H, W, 3), np.uint16))
        out.close()
    info = open_clip(folder / "plate.#####.dpx", (1, 1))
    assert info.frame_numbers == (86401,) and info.rate == Fraction(24000, 1001)
    assert info.pixel_aspect == 2.0 and info.timecode == "01:00:00:01"


def _timed_movie(path: Path, frames: int) -> Path:
    """An H.264 movie at 24000/1001 with 2:1 pixels and timecode 01:00:00:00; frame k is grey k * 40."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=Fraction(24000, 1001))
        stream.width, stream.height, stream.pix_fmt = 16, 8, "yuv420p"
        stream.codec_context.sample_aspect_ratio = Fraction(2)
        stream.metadata["timecode"] = "01:00:00:00"
        stream.options = {"qp": "0"}
        for k in range(frames):
            rgb = np.full((8, 16, 3), k * 40, np.uint8)
            container.mux(stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")))
        container.mux(stream.encode())
    return path


def test_a_movie_is_numbered_from_its_start_frame_with_its_rate_and_timecode(tmp_path):
    movie = _timed_movie(tmp_path / "plate.mov", 5)
    info = open_clip(movie)
    assert info.frame_numbers == (0, 1, 2, 3, 4) and info.start_frame == 0
    assert info.rate == Fraction(24000, 1001) and info.pixel_aspect == 2.0 and info.timecode == "01:00:00:00"
    first, last = frame_positions(movie, (1002, 1003), start_frame=1001)
    assert (first, last) == (1, 2)
    info = open_clip(movie, (first, last), start_frame=1001)
    assert info.frame_numbers == (1002, 1003) and info.timecode == "01:00:00:01"
    grey = [round(float(rgb.mean()) * 255 / 40) for rgb in iter_frames(info)]
    assert grey == [1, 2]  # positions 1 and 2 are the frames decoded
    with pytest.raises(InputError, match=r"frame 1006 is not in the plate \(its frames are 1001\.\.1005\)"):
        frame_positions(movie, (1004, 1006), start_frame=1001)
