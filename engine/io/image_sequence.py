"""Opening an image sequence: every selected frame checked up front, so a fit never dies an hour in on one.

The first frame is decoded in full (a truncated export is caught now); the others' headers must agree with it in
size, in encoding (float scene-linear or integer display-encoded: one clip has one) and, when the headers choose the
colour space, in a DPX's declared transfer. A hole in the numbering is a frame that failed to render or copy.
"""

from __future__ import annotations

import os
from fractions import Fraction

import OpenImageIO as oiio

from ..errors import InputError
from . import colour
from .clip_info import SEQUENCE, ClipInfo, ColourChoice, check_range
from .clip_messages import FRAME, ext_list
from .image_reader import decode_image, read_header
from .movie import MOVIE_EXTENSIONS
from .sequences import IMAGE_EXTENSIONS, NumberedFile, sequence_files
from .timing import Timecode, exact_rate, pixel_aspect


def open_sequence(source: str, frame_range: tuple[int, int] | None, plate: ColourChoice) -> ClipInfo:
    folder, files = sequence_files(source)
    if not files:
        movies = sorted(n for n in os.listdir(folder) if os.path.splitext(n)[1].lower() in MOVIE_EXTENSIONS)
        hint = f" (or pass the movie {movies[0]} itself)" if movies else ""
        raise InputError(
            folder,
            f"no image files in the folder (accepted: {ext_list(IMAGE_EXTENSIONS)})",
            f"pass a folder that holds the frames as images{hint}",
        )
    first, last = check_range(folder, frame_range, len(files))
    selected = files[first : last + 1]
    _check_gaps(folder, files, first, last)
    # Decode the first frame fully (a truncated export is caught now, not hours into a fit); for the
    # rest, headers are enough to check sizes cheaply.
    head = decode_image(selected[0].path, FRAME)
    head_colour = colour.file_colour(head.spec, head.path)
    for f in selected[1:]:
        width, height, is_float, facts = read_header(f.path, FRAME)
        if (width, height) != (head.width, head.height):
            raise InputError(
                f.path,
                f"{f.name} is {width}x{height} but {selected[0].name} is {head.width}x{head.height}",
                FRAME.size_fix,
            )
        if is_float != head.is_float:
            raise mixed_encoding(f.path, selected[0].name, is_float)
        if plate.asked is None and colour.dpx_encoding(facts) != colour.dpx_encoding(head_colour):
            raise _mixed_transfer(f.path, selected[0].name, facts, head_colour)
    # Unnumbered files (all or none, see list_images) are numbered by their position.
    numbers = [f.number for f in selected]
    frame_numbers = tuple(n if n is not None else first + i for i, n in enumerate(numbers))
    rate, aspect, timecode = _image_timing(head.spec)
    decided = plate.decide(head.path, head_colour)
    return ClipInfo(
        source=folder,
        kind=SEQUENCE,
        frame_files=tuple(f.path for f in selected),
        frame_numbers=frame_numbers,
        width=head.width,
        height=head.height,
        fps=float(rate) if rate else None,
        colorspace=decided.space,
        channels=head.channels,
        is_float=head.is_float,
        colour_config=plate.config,
        colour_source=decided.source,
        colour_note=decided.note,
        rate=rate,
        pixel_aspect=aspect,
        timecode=timecode,
    )


def _image_timing(spec: oiio.ImageSpec) -> tuple[Fraction | None, float, str | None]:
    """(rate, pixel aspect ratio, timecode) from an image's header: an EXR's ``FramesPerSecond`` rational, a DPX's
    frame rate (a float: snapped to its NTSC fraction), ``PixelAspectRatio`` and the SMPTE timecode of either."""
    fraction = spec.getattribute("FramesPerSecond")
    rate = exact_rate(tuple(fraction)) if isinstance(fraction, tuple) and len(fraction) == 2 else None
    for name in ("dpx:FrameRate", "dpx:TemporalFrameRate"):
        if rate is None:
            rate = exact_rate(spec.get_float_attribute(name, 0.0))
    aspect = pixel_aspect(spec.get_float_attribute("PixelAspectRatio", 1.0))
    packed = spec.getattribute("smpte:TimeCode")
    timecode = Timecode.from_bcd(int(packed[0]), rate) if isinstance(packed, tuple) and packed else None
    return rate, aspect, None if timecode is None else str(timecode)


def _encoding(is_float: bool) -> str:
    return "float (scene-linear)" if is_float else "integer (display-encoded)"


def mixed_encoding(path: str, first_name: str, is_float: bool) -> InputError:
    """A frame stored as float in a clip of integer frames, or the reverse: one colour space cannot hold both."""
    return InputError(
        path,
        f"{os.path.basename(path)} is {_encoding(is_float)} but {first_name} is {_encoding(not is_float)}",
        "export every frame of the clip in one format and bit depth (all EXR/float, or all 8/16-bit)",
    )


def _mixed_transfer(path: str, first_name: str, facts: colour.FileColour, first: colour.FileColour) -> InputError:
    """A DPX whose header declares another transfer than the first frame's: the first frame's header chooses the
    clip's colour space, which would decode this frame with the wrong curve (a log frame as sRGB)."""
    return InputError(
        path,
        f"{os.path.basename(path)}'s header declares the transfer {facts.dpx_transfer!r} "
        f"({colour.dpx_encoding(facts)}) but {first_name}'s declares {first.dpx_transfer!r} "
        f"({colour.dpx_encoding(first)}); one clip has one encoding",
        "re-export the plate with the same transfer in every frame's header, or name its colour space, "
        "e.g. --colorspace ACEScct",
    )


def _check_gaps(folder: str, files: list[NumberedFile], first: int, last: int) -> None:
    """A hole in the numbering inside the selected range means a frame failed to render or copy."""
    for pos in range(first, last):
        prev, cur = files[pos], files[pos + 1]
        if prev.number is None or cur.number is None or cur.number == prev.number + 1:
            continue
        width = len(prev.digits)
        missing = f"{prev.number + 1:0{width}d}"
        what = (
            f"frame {missing} is missing"
            if cur.number == prev.number + 2
            else f"frames {missing}..{cur.number - 1:0{width}d} are missing"
        )
        raise InputError(
            folder,
            f"{what} between {prev.name} and {cur.name}",
            f"render or copy the missing frame, or choose a frame range that avoids it "
            f"(--frames {files[first].number}-{prev.number} or {cur.number}-{files[last].number})",
        )
