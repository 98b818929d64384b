"""A plate's timing: its frame rate as an exact fraction, its pixel aspect ratio and its SMPTE timecode.

Studio plates run at 24000/1001 (shown as 23.976) far more often than at 24: a rate kept as a float drifts a
frame every 41 s against the plate's own timecode and the editorial cut, so the rate is a ``Fraction`` from the
file to the movie the engine writes. Files that store the rate as a float (DPX) are snapped to the NTSC fraction
they stand for (``exact_rate``). Timecode is counted at the nominal integer rate (24 for 24000/1001, as every
editing system does), drop-frame only where SMPTE defines it (29.97 and 59.94, written ``HH:MM:SS;FF``).

Reading these from a file is the clip openers' job (``engine.io.image_sequence``, ``engine.io.movie``); this
module holds the arithmetic, with no image library.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from fractions import Fraction

#: The NTSC family: a float rate within ``RATE_SNAP`` of one of these is that fraction (a DPX header stores
#: 23.976 as float32 23.97599983...).
NTSC_RATES: tuple[Fraction, ...] = tuple(Fraction(n * 1000, 1001) for n in (24, 30, 48, 60, 120))
#: How close (frames per second) a float rate must be to an NTSC fraction or an integer to be taken as it.
RATE_SNAP = 1e-3
#: The largest denominator accepted when a float rate is none of the above (25.0 -> 25, 12.5 -> 25/2).
RATE_MAX_DENOMINATOR = 1001
#: Frame rates (fps) a plate can play at: a rate outside is not a plate's (a broken header is taken as none, and
#: ``--fps`` outside is refused): below 1 no timecode or movie holds it, above 1000 is a typo.
RATE_RANGE = (1, 1000)
#: Pixel aspect ratios outside this range are not a plate's (a broken header): taken as square pixels.
PIXEL_ASPECT_RANGE = (0.01, 100.0)

_TIMECODE = re.compile(r"^(\d{2}):(\d{2}):(\d{2})([:;.])(\d{2,3})$")
_FRAMES = re.compile(r"\s*(\d+)\s*(?:[-:]\s*(\d+)\s*)?")


def exact_rate(value: float | Fraction | tuple[int, int] | None) -> Fraction | None:
    """The rate as an exact positive fraction, or None when there is none (0, negative, NaN, missing, outside
    ``RATE_RANGE``)."""
    if value is None:
        return None
    if isinstance(value, tuple):
        num, den = value
        return _in_range(Fraction(int(num), int(den))) if num > 0 and den > 0 else None
    if isinstance(value, Fraction):
        return _in_range(value)
    rate = float(value)
    if not math.isfinite(rate) or not RATE_RANGE[0] <= rate <= RATE_RANGE[1]:
        return None
    for ntsc in NTSC_RATES:
        if abs(rate - float(ntsc)) < RATE_SNAP:
            return ntsc
    if abs(rate - round(rate)) < RATE_SNAP:
        return Fraction(round(rate))
    return Fraction(rate).limit_denominator(RATE_MAX_DENOMINATOR)


def _in_range(rate: Fraction) -> Fraction | None:
    return rate if RATE_RANGE[0] <= rate <= RATE_RANGE[1] else None


def parse_rate(text: str) -> Fraction:
    """``--fps`` text: ``24``, ``23.976`` (the NTSC fraction), ``24000/1001`` or ``25:1``; ValueError otherwise."""
    num, sep, den = text.replace(":", "/").partition("/")
    try:
        rate = exact_rate((int(num), int(den))) if sep else exact_rate(float(num))
    except (ValueError, ZeroDivisionError):
        rate = None
    if rate is None:
        low, high = RATE_RANGE
        raise ValueError(
            f"frame rate {text[:40]!r} is not a number or fraction of {low} to {high} fps (e.g. 24, 23.976, 24000/1001)"
        )
    return rate


class ReversedFrames(ValueError):
    """A frame range written last first; its text is the range the right way round (``1001-1100``)."""


def parse_frames(text: str) -> tuple[int, int]:
    """A range of the plate's frame numbers as pipeline tools write it: ``FIRST-LAST`` (``1010-1050``),
    ``FIRST:LAST`` or one frame ``N``, inclusive; ValueError otherwise, ``ReversedFrames`` for FIRST > LAST. The
    one reading of ``--frames`` and of a shot's ``frames``: the farm's plan hands a shot's range on to the fit's
    ``--frames``, so the two accept exactly the same text."""
    match = _FRAMES.fullmatch(text)
    if match is None:
        raise ValueError(f"frame range {text[:40]!r} is not FIRST-LAST")
    first, last = int(match[1]), int(match[2] or match[1])
    if first > last:
        raise ReversedFrames(f"{last}-{first}")
    return first, last


def rate_text(rate: Fraction) -> str:
    """``24000/1001 (23.976 fps)`` or ``25 fps``, for messages and docs."""
    if rate.denominator == 1:
        return f"{rate.numerator} fps"
    return f"{rate.numerator}/{rate.denominator} ({float(rate):.3f} fps)"


def pixel_aspect(value: float | None) -> float:
    """The pixel aspect ratio, square (1.0) when missing or absurd."""
    if value is None or not math.isfinite(value):
        return 1.0
    low, high = PIXEL_ASPECT_RANGE
    return float(value) if low <= value <= high else 1.0


@dataclass(frozen=True)
class Timecode:
    """SMPTE timecode: a frame count from 00:00:00:00 at a nominal integer rate, drop-frame or not."""

    frames: int
    nominal: int
    drop: bool = False

    @classmethod
    def parse(cls, text: str, rate: Fraction | None) -> Timecode | None:
        """``"01:00:00:00"`` (``;`` or ``.`` before the frames: drop-frame) at ``rate``; None if it is not one."""
        m = _TIMECODE.match(text.strip())
        if m is None:
            return None
        hh, mm, ss, sep, ff = m.groups()
        nominal = nominal_rate(rate, int(ff))
        drop = sep in ";." and _drop_allowed(nominal)
        h, mi, s, f = int(hh), int(mm), int(ss), int(ff)
        if mi > 59 or s > 59 or f >= nominal:
            return None
        frames = ((h * 60 + mi) * 60 + s) * nominal + f
        if drop:
            skip = nominal // 15  # 2 frame numbers dropped per minute at 29.97, 4 at 59.94
            minutes = h * 60 + mi
            frames -= skip * (minutes - minutes // 10)
        return cls(frames, nominal, drop)

    @classmethod
    def from_bcd(cls, packed: int, rate: Fraction | None) -> Timecode | None:
        """From the SMPTE 12M packed word of an EXR ``timeCode`` / DPX header (BCD digits, flags in bits 6-7)."""

        def bcd(byte: int) -> int:
            return (byte >> 4) * 10 + (byte & 0x0F)

        frame_byte = packed & 0xFF
        drop = bool(frame_byte & 0x40)
        ff, ss = bcd(frame_byte & 0x3F), bcd((packed >> 8) & 0x7F)
        mm, hh = bcd((packed >> 16) & 0x7F), bcd((packed >> 24) & 0x3F)
        return cls.parse(f"{hh:02d}:{mm:02d}:{ss:02d}{';' if drop else ':'}{ff:02d}", rate)

    def offset(self, frames: int) -> Timecode:
        """The timecode ``frames`` later (wraps at 24 hours, as a timecode does)."""
        return Timecode((self.frames + frames) % (self.nominal * 86400 - self._dropped_per_day()), self.nominal,
                        self.drop)  # fmt: skip

    def _dropped_per_day(self) -> int:
        return (self.nominal // 15) * (24 * 60 - 24 * 6) if self.drop else 0

    def fields(self) -> tuple[int, int, int, int]:
        """(hours, minutes, seconds, frames)."""
        frames = self.frames
        if self.drop:
            skip = self.nominal // 15
            per_ten = self.nominal * 600 - skip * 9  # frames in ten minutes
            per_minute = self.nominal * 60 - skip
            tens, rest = divmod(frames, per_ten)
            frames += skip * 9 * tens + (skip * ((rest - skip) // per_minute) if rest > skip else 0)
        seconds, ff = divmod(frames, self.nominal)
        minutes, ss = divmod(seconds, 60)
        hh, mm = divmod(minutes, 60)
        return hh, mm, ss, ff

    def __str__(self) -> str:
        hh, mm, ss, ff = self.fields()
        return f"{hh:02d}:{mm:02d}:{ss:02d}{';' if self.drop else ':'}{ff:02d}"

    def bcd(self) -> int:
        """The SMPTE 12M packed word (what an EXR ``timeCode`` attribute holds): BCD digits, drop flag in bit 6."""

        def pack(value: int) -> int:
            return ((value // 10) << 4) | (value % 10)

        hh, mm, ss, ff = self.fields()
        return (pack(hh) << 24) | (pack(mm) << 16) | (pack(ss) << 8) | pack(ff) | (0x40 if self.drop else 0)


def timecode_at(first: str | None, rate: Fraction | None, offset: int = 0) -> Timecode | None:
    """The timecode ``offset`` frames after ``first`` (a recorded ``HH:MM:SS:FF`` at ``rate``): a pass, a rendered
    frame or a movie's first frame carries its plate frame's timecode. None without a (valid) first timecode."""
    parsed = None if first is None else Timecode.parse(first, rate)
    return None if parsed is None else parsed.offset(offset)


def nominal_rate(rate: Fraction | None, highest_frame: int = 0) -> int:
    """The integer rate timecode counts at: 24 for 24000/1001, 25 for 25; without a rate, the smallest common
    one (24, 25, 30, 48, 50, 60) the frame field fits."""
    if rate is not None:
        return max(1, round(rate))
    return next((n for n in (24, 25, 30, 48, 50, 60) if highest_frame < n), highest_frame + 1)


def _drop_allowed(nominal: int) -> bool:
    return nominal in (30, 60)


__all__ = [
    "ReversedFrames",
    "Timecode",
    "exact_rate",
    "nominal_rate",
    "parse_frames",
    "parse_rate",
    "pixel_aspect",
    "rate_text",
    "timecode_at",
]
