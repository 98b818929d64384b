"""A plate's timing (engine.io.timing): exact rates, SMPTE timecode arithmetic (drop-frame included) and the EXR
header attributes that carry both (engine.io.images.exr_timing), read back by OpenImageIO as Nuke's reader does."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import OpenImageIO as oiio
import pytest

from engine.io.images import exr_timing, write_exr
from engine.io.timing import Timecode, exact_rate, parse_rate, pixel_aspect

NTSC_FILM = Fraction(24000, 1001)
NTSC_VIDEO = Fraction(30000, 1001)


@pytest.mark.parametrize(
    ("value", "rate"),
    [
        (23.976, NTSC_FILM),
        (23.97599983215332, NTSC_FILM),  # a DPX header's float32
        (29.97, NTSC_VIDEO),
        (59.94, Fraction(60000, 1001)),
        (24.0, Fraction(24)),
        (25, Fraction(25)),
        (12.5, Fraction(25, 2)),
        ((24000, 1001), NTSC_FILM),
        (0.0, None),
        (-24.0, None),
        (float("nan"), None),
        (None, None),
    ],
)
def test_rates_are_exact_fractions(value, rate):
    assert exact_rate(value) == rate


def test_fps_text_is_read_as_the_rate_it_names():
    assert parse_rate("24000/1001") == NTSC_FILM
    assert parse_rate("23.976") == NTSC_FILM
    assert parse_rate("25") == 25
    assert parse_rate("30000:1001") == NTSC_VIDEO
    assert parse_rate("1") == 1 and parse_rate("1000") == 1000
    for bad in ("0", "fast", "24/0", "-25", "1e-300", "1e308", "0.5", "1001", "1/1000000", "9" * 400):
        with pytest.raises(ValueError, match="is not a number or fraction of 1 to 1000 fps"):
            parse_rate(bad)


def test_a_rate_no_plate_plays_at_is_none():
    """A header's rate below 1 or above 1000 fps (a broken file) is taken as no rate, as 0 or NaN are."""
    assert exact_rate(1e-300) is None and exact_rate(1e308) is None and exact_rate((1, 10**300)) is None
    assert exact_rate(Fraction(10**9)) is None and exact_rate(0.5) is None and exact_rate(1000.0) == 1000


def test_an_absurd_pixel_aspect_ratio_is_square():
    assert pixel_aspect(2.0) == 2.0 and pixel_aspect(0.5) == 0.5
    assert pixel_aspect(None) == pixel_aspect(float("inf")) == pixel_aspect(0.0) == pixel_aspect(1e9) == 1.0


def test_non_drop_timecode_counts_at_the_nominal_rate():
    """23.976 is counted at 24 frames a second, as editorial does: 01:00:00:23 + 1 = 01:00:01:00."""
    tc = Timecode.parse("01:00:00:23", NTSC_FILM)
    assert tc is not None and tc.nominal == 24 and not tc.drop
    assert str(tc.offset(1)) == "01:00:01:00"
    assert str(Timecode.parse("23:59:59:23", NTSC_FILM).offset(1)) == "00:00:00:00"  # wraps at 24 hours
    assert Timecode.parse("01:00:00:24", NTSC_FILM) is None  # no frame 24 at 24 fps
    assert Timecode.parse("1:00:00", NTSC_FILM) is None


def test_drop_frame_timecode_skips_two_numbers_a_minute_but_every_tenth():
    tc = Timecode.parse("00:00:59;29", NTSC_VIDEO)
    assert tc is not None and tc.drop
    assert str(tc.offset(1)) == "00:01:00;02"  # ;00 and ;01 are dropped
    assert str(Timecode.parse("00:09:59;29", NTSC_VIDEO).offset(1)) == "00:10:00;00"  # not at minute 10
    assert Timecode.parse("00:10:00;00", NTSC_VIDEO).frames == 17982  # 10 minutes of 29.97: SMPTE's count
    assert not Timecode.parse("00:00:59;23", NTSC_FILM).drop  # drop-frame exists at 29.97 and 59.94 only


def test_the_smpte_word_round_trips():
    for text, rate in (("01:02:03:04", NTSC_FILM), ("10:59:59;29", NTSC_VIDEO), ("23:59:59:24", Fraction(25))):
        tc = Timecode.parse(text, rate)
        assert str(Timecode.from_bcd(tc.bcd(), rate)) == text
    assert Timecode.parse("01:02:03:04", NTSC_FILM).bcd() == 0x01020304


def test_exr_timing_attributes_read_back_through_openimageio(tmp_path):
    """The standard OpenEXR attributes: OIIO (and so Nuke's and RV's readers) shows them as the frame's rate, pixel
    aspect ratio and timecode; the timecode is the first frame's plus the offset."""
    path = tmp_path / "f.exr"
    write_exr(path, {"R": np.zeros((2, 3), np.float32)}, attributes=exr_timing((24000, 1001), 2.0, "01:00:00:20", 5))
    spec = oiio.ImageInput.open(str(path)).spec()
    assert spec.getattribute("FramesPerSecond") == (24000, 1001)
    assert spec.getattribute("PixelAspectRatio") == 2.0
    assert spec.get_string_attribute("smpte:TimeCode") == "01:00:01:01"
    square = tmp_path / "g.exr"
    write_exr(square, {"R": np.zeros((2, 3), np.float32)}, attributes=exr_timing(None, 1.0))
    spec = oiio.ImageInput.open(str(square)).spec()
    assert spec.getattribute("FramesPerSecond") is None and spec.getattribute("smpte:TimeCode") is None
