"""Scene frames <-> the plate's frames, and the plate's timing as Blender's scene stores it. No bpy here.

A Movie Clip starts at scene frame ``clip_frame_start``; scene frame F is position ``F - clip_frame_start`` in
the plate. An image sequence's files carry numbers (``plate_0012.png``): the masks and scribbles the add-on
writes carry the plate's numbers, so the engine matches them to frames by number; for a movie they are
named by position. The engine's ``--frames`` speaks the plate's numbers (``plate_numbers``): a sequence's file
numbers, a movie's frames counted from 0.

Import goes the other way: scene frame 1001 shows plate frame 1001 (the Movie Clip starts at its first file's
number, the passes' sequence reads file F at scene frame F), the scene's range is the exported frames' numbers
unless the artist's range already lies within them (``scene_range``), its rate the plate's exact fraction
(``scene_fps``) and its pixel aspect the plate's (``scene_pixel_aspect``).
"""

from __future__ import annotations

import os

from ...engine import contract as C  # type: ignore[import-not-found]
from .errors import UserError

_DIGITS = C.FRAME_FILE_DIGITS


def file_number(path: str) -> int | None:
    """The frame number in a sequence file name (``plate_0012.png`` -> 12)."""
    m = _DIGITS.search(os.path.basename(path))
    return int(m.group(1)) if m else None


def sequence_pattern(path: str) -> str:
    """The engine's clip argument for an image-sequence Movie Clip: the pattern of the sequence its file belongs to
    (``/plates/plate.1001.exr`` -> ``/plates/plate.####.exr``), so the engine reads the sequence Blender shows even
    where the folder holds others; a file name without a number is its folder."""
    return C.sequence_pattern_of(path) or os.path.dirname(path)


def frame_range(
    clip_frame_start: int, clip_frame_duration: int, start: int, end: int, whole_clip: bool
) -> tuple[int, int]:
    """The scene frames to fit (first, last): the whole clip, or ``start..end`` clipped to it."""
    clip_last = clip_frame_start + clip_frame_duration - 1
    if whole_clip:
        return clip_frame_start, clip_last
    first, last = max(start, clip_frame_start), min(end, clip_last)
    if last < first:
        raise UserError(f"frames {start}-{end} are outside the clip")
    return first, last


def positions(first: int, last: int, clip_frame_start: int) -> tuple[int, int]:
    """Scene frames -> positions in the plate."""
    return first - clip_frame_start, last - clip_frame_start


def plate_numbers(first: int, last: int, clip_frame_start: int, first_file_number: int | None) -> tuple[int, int]:
    """Scene frames -> the plate's frame numbers (the engine's ``--frames``): a sequence's file numbers counted from
    its first file's, a movie's frames from 0."""
    a, b = positions(first, last, clip_frame_start)
    base = first_file_number or 0
    return base + a, base + b


def scene_range(current: tuple[int, int], imported: tuple[int, int], force: bool = False) -> tuple[int, int]:
    """The scene's range after an import of plate frames ``imported`` (first, last): the artist's ``current`` range
    when it lies within them (a range narrowed to the frames being worked on survives a re-import), else the imported
    frames (a scene numbered otherwise, such as Blender's 1-250, would show frames the export does not have);
    ``force``: the imported frames whatever the current range."""
    first, last = imported
    if not force and first <= current[0] <= current[1] <= last:
        return current
    return first, last


def frame_inside(current: int, first: int, last: int) -> int:
    """The current frame after an import of frames ``first``-``last``: as it was when it is one of them (the artist's
    place survives a re-import), else the first (Blender's frame 1 would show a plate frame the export lacks)."""
    return current if first <= current <= last else first


def clip_offset_note(name: str, clip_frame_start: int, first_file_number: int | None, aligned_clip: str) -> str | None:
    """What to tell the artist whose own clip ``name`` (a sequence starting with file ``first_file_number``) does not
    show plate frame N at scene frame N once the scene is numbered as the plate: Blender starts a sequence at scene
    frame 1 whatever its numbers, so over 1011-1022 the Clip Editor shows nothing there. The clip is not moved (the
    masks and scribbles drawn on it are keyed to scene frames); ``aligned_clip`` is. None: it lines up, or a movie."""
    if first_file_number is None or clip_frame_start == first_file_number:
        return None
    return (
        f"clip {name!r} shows plate frame {first_file_number} at scene frame {clip_frame_start}; view "
        f"{aligned_clip!r} in the Clip Editor to see plate frame N at scene frame N"
    )


def line_up_offset(clip_frame_start: int, first_file_number: int | None) -> int | None:
    """Line Up My Clip: how many frames the artist's clip (and the masks drawn on it, keyed to scene frames) move so
    that it shows plate frame N at scene frame N: its start becomes its first file's number. None: a movie, or it
    lines up already (``clip_offset_note`` says nothing then either)."""
    if first_file_number is None or clip_frame_start == first_file_number:
        return None
    return first_file_number - clip_frame_start


#: Blender stores the scene rate as ``render.fps`` (a short: at most this) over ``render.fps_base`` (a float).
BLENDER_MAX_FPS = 32767


def scene_fps(rate: tuple[int, int] | None) -> tuple[int, float] | None:
    """``(render.fps, render.fps_base)`` for the exact rate ``(num, den)``: 24000/1001 is (24000, 1001.0), exact in
    Blender's float (what Blender itself sets from such a movie), 25/1 is (25, 1.0); a numerator beyond
    ``BLENDER_MAX_FPS`` (60000/1001) becomes the nearest integer over its ratio (60, 1.001). None: no rate."""
    if rate is None:
        return None
    num, den = rate
    if num <= 0 or den <= 0:
        return None
    if num <= BLENDER_MAX_FPS:
        return num, float(den)
    fps = max(1, round(num / den))
    return fps, fps * den / num


def scene_pixel_aspect(pixel_aspect: float) -> tuple[float, float]:
    """``(render.pixel_aspect_x, render.pixel_aspect_y)`` for a plate's pixel aspect ratio: Blender takes each in
    1..200, so 2.0 (anamorphic) is (2, 1) and 0.5 is (1, 2)."""
    if not pixel_aspect > 0:
        return 1.0, 1.0
    return (float(pixel_aspect), 1.0) if pixel_aspect >= 1.0 else (1.0, 1.0 / pixel_aspect)


def mask_file_names(scene_frames: list[int], first_file_number: int | None, clip_frame_start: int) -> list[str]:
    """Names of the mask images for the given scene frames.

    For an image-sequence plate they carry the plate's file numbers (the engine then matches masks to
    frames by number); for a movie, the position in the selected range (matched by count).
    """
    if first_file_number is None:
        return [f"{i:05d}.png" for i in range(len(scene_frames))]
    return [f"{first_file_number + f - clip_frame_start:05d}.png" for f in scene_frames]


def scribble_file_name(scene_frame: int, first_file_number: int | None, clip_frame_start: int) -> str:
    """The scribble image of a scene frame: the plate's file number (a movie's frames are numbered from 0)."""
    return C.SCRIBBLE_FILE_FORMAT.format((first_file_number or 0) + scene_frame - clip_frame_start)
