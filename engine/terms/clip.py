"""The plate and what comes with it: its kinds, its frame files' numbers, its rate, the working size a fit
scales it to, and the masks' and scribbles' conventions."""

from __future__ import annotations

import math
import os
import re
from fractions import Fraction
from typing import Any

CLIP_KINDS: tuple[str, ...] = ("sequence", "movie")
#: The highest number a movie's first frame may be given (``fit --start-frame``, a shot's ``start_frame``): Blender's
#: highest frame (its MAXFRAME), so a movie numbered from it can be laid on a Blender scene.
MAX_START_FRAME = 1_048_574


#: A frame file's number: the digits just before its extension (``plate.1001.exr``, ``plate_0012.png``).
FRAME_FILE_DIGITS = re.compile(r"(\d+)(?=\.[^.]+$)")


def sequence_pattern_of(path: str) -> str | None:
    """The pattern of the image sequence a frame file belongs to, one ``#`` per digit of its number
    (``/plates/plate.1001.exr`` -> ``/plates/plate.####.exr``: the clip argument ``fit`` takes); None for a file
    name without a number before its extension."""
    name = os.path.basename(path)
    m = FRAME_FILE_DIGITS.search(name)
    if m is None:
        return None
    return os.path.join(os.path.dirname(path), f"{name[: m.start()]}{'#' * len(m.group(1))}{name[m.end() :]}")


def clip_rate(clip: dict[str, Any]) -> tuple[int, int] | None:
    """A manifest clip's frame rate as an exact (num, den): its "rate", else its float "fps" as the fraction it
    stands for (23.976... -> 24000/1001, 25.0 -> 25/1); None when it has neither."""
    if clip.get("rate"):
        num, den = clip["rate"]
        return int(num), int(den)
    fps = clip.get("fps")
    if not fps:
        return None
    rate = Fraction(fps).limit_denominator(1001)
    return rate.numerator, rate.denominator


#: The working resolution's long edge when none is asked for (``fit --set long_edge=N``, the add-on's Working Size).
DEFAULT_LONG_EDGE = 768
#: A mask image's pixel marks foreground above this fraction of full scale.
MASK_THRESHOLD = 0.5


def working_size(width: int, height: int, long_edge: int = DEFAULT_LONG_EDGE) -> tuple[int, int]:
    """Working ``(W, H)``: the long edge scaled to ``long_edge``, aspect kept, never enlarged; each side rounds
    half up (``floor(x + 0.5)``, not Python's half-to-even ``round``). 854x480 -> (768, 432)."""
    if width < 1 or height < 1 or long_edge < 1:
        raise ValueError(f"working_size needs positive sizes, got {width}x{height}, long_edge={long_edge}")
    scale = long_edge / max(width, height)
    if scale >= 1.0:
        return width, height
    return max(1, math.floor(width * scale + 0.5)), max(1, math.floor(height * scale + 0.5))


#: Scribbles (``fit --mask OBJECT --scribbles FOLDER``, paper Sec. 4.4): one image per scribbled frame, named
#: with the frame number like masks (00012.png for frame 00012); frames without a file have no scribbles.
#: An 8-bit pixel whose R, G, B are each within SCRIBBLE_TOLERANCE of SCRIBBLE_COLOURS[k] (and whose alpha,
#: if any, is above SCRIBBLE_ALPHA_CUTOFF) marks foreground layer k+1; anything else (black, transparent) marks
#: nothing. The mask is the whole object; the fit gives it as many foreground layers as the highest colour index used.
SCRIBBLE_ARG = "--scribbles"
SCRIBBLE_COLOURS: tuple[tuple[int, int, int], ...] = (
    (255, 0, 0),  # red -> Foreground1
    (0, 255, 0),  # green -> Foreground2
    (0, 0, 255),  # blue -> Foreground3
    (255, 255, 0),  # yellow -> Foreground4
)
SCRIBBLE_TOLERANCE = 48
SCRIBBLE_ALPHA_CUTOFF = 127  # half of 8-bit full scale: a stroke's soft edge counts where it is mostly opaque
SCRIBBLE_FILE_FORMAT = "{:05d}.png"  # what the add-on writes; the engine reads any numbered png/tif

#: What ``engine.contract`` re-exports from this module (its own names, not its imports).
__all__ = [
    "CLIP_KINDS",
    "DEFAULT_LONG_EDGE",
    "FRAME_FILE_DIGITS",
    "MASK_THRESHOLD",
    "MAX_START_FRAME",
    "SCRIBBLE_ALPHA_CUTOFF",
    "SCRIBBLE_ARG",
    "SCRIBBLE_COLOURS",
    "SCRIBBLE_FILE_FORMAT",
    "SCRIBBLE_TOLERANCE",
    "clip_rate",
    "sequence_pattern_of",
    "working_size",
]
