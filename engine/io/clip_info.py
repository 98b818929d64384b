"""What an opened clip is (``ClipInfo``), and the two requests every opener honours: the frame range and the colour
space asked for.

A sequence and a movie are opened by different code (``engine.io.image_sequence``, ``engine.io.movie``) but
described alike, so everything downstream (reading, masks, the run folder) sees one kind of object.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from fractions import Fraction

from ..errors import InputError
from ..terms.colour import COLOUR_BUILTIN_CONFIG, COLOUR_SOURCE_ASKED
from . import colour

SEQUENCE = "sequence"
MOVIE = "movie"


class NumberedFrames:
    """A selection of frames, each known by its number (the clip as opened, and as a run folder records it)."""

    frame_numbers: tuple[int, ...]

    @property
    def num_frames(self) -> int:
        return len(self.frame_numbers)


@dataclass(frozen=True)
class ClipInfo(NumberedFrames):
    """What was opened: enough to read the frames later and to describe the clip in a run folder."""

    source: str
    """Absolute path of the folder or movie file."""
    kind: str
    """``"sequence"`` or ``"movie"``."""
    frame_files: tuple[str, ...]
    """Absolute paths of the selected frames (sequence); ``()`` for a movie."""
    frame_numbers: tuple[int, ...]
    """Number in each selected frame's file name (sequence) or its 0-based index (movie)."""
    width: int
    height: int
    fps: float | None
    """Stream rate of a movie; ``None`` for a sequence (image files carry no reliable rate)."""
    colorspace: str
    """The plate's colour space, a name in ``colour_config`` (``engine.io.colour``): ``--colorspace``, else the
    config's file rules, else by file type (float: scene-linear, integer and movie: sRGB)."""
    channels: int
    """Channels in the file (1 grey, 3 RGB, 4 RGBA, ...)."""
    is_float: bool = False
    """Whether the frames store floats (EXR, float TIFF): one clip is all float or all integer."""
    colour_config: str = COLOUR_BUILTIN_CONFIG
    """The OCIO config that names ``colorspace``: ``$OCIO`` when set, else the built-in one."""
    rate: Fraction | None = None
    """The plate's frame rate, exact (24000/1001, not 23.976): the EXR's ``FramesPerSecond``, the DPX header's,
    the movie stream's, or ``--fps``; ``None`` when neither the files nor the user state one."""
    pixel_aspect: float = 1.0
    """Pixel aspect ratio (2.0 for a 2x anamorphic plate), from the file's header; 1.0 when it states none."""
    timecode: str | None = None
    """SMPTE timecode of the first selected frame (``HH:MM:SS:FF``; ``;`` before the frames: drop-frame)."""
    start_frame: int = 0
    """A movie's number of its first frame (its frames are numbered ``start_frame + index``); 0 for a sequence."""
    colour_source: str | None = dataclasses.field(default=None, compare=False)
    """How ``colorspace`` was decided (``terms.colour.COLOUR_SOURCES``): asked, the file's header, $OCIO's rules, the
    file type, or assumed; None where it is not known (a clip described by hand). Not what the clip is: clips that
    differ only in it are equal."""
    colour_note: str = dataclasses.field(default="", compare=False)
    """The one ``note:`` line a fit prints when the colour space was assumed ("" otherwise)."""


def check_range(source: str, frame_range: tuple[int, int] | None, count: int) -> tuple[int, int]:
    """Validate an inclusive (first, last) position range against a clip of ``count`` frames."""
    if frame_range is None:
        return 0, count - 1
    first, last = (int(v) for v in frame_range)
    if not (0 <= first <= last <= count - 1):
        raise InputError(
            source,
            f"frame range {first}..{last} is outside the clip or reversed",
            f"choose first <= last within the valid range 0..{count - 1} ({count} frames)",
        )
    return first, last


@dataclass(frozen=True)
class ColourChoice:
    """The colour space asked for (``--colorspace``; None: the default for the file) in the OCIO config."""

    asked: str | None
    config: str

    def decide(self, path: str, facts: colour.FileColour | None) -> colour.PlateColour:
        """The plate's colour space and how it was decided: the one asked for, resolved in the config, else what
        ``path``'s header, the config's rules or its file type say (``facts``: its first frame's header; None for a
        movie)."""
        if self.asked is not None:
            return colour.PlateColour(colour.resolve(self.asked, self.config), COLOUR_SOURCE_ASKED)
        return colour.decide_colorspace(path, facts, self.config)
