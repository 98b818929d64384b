"""Scene frames -> what the engine reads: sequence file numbers, mask and scribble file names, frame positions.
No bpy here.

A Movie Clip starts at scene frame ``clip_frame_start``; scene frame F is position ``F - clip_frame_start`` in
the plate. An image sequence's files carry numbers (``plate_0012.png``): the masks and scribbles the add-on
writes carry the plate's numbers, so the engine matches them to frames by number; for a movie they are
named by position.
"""

from __future__ import annotations

import os
import re

from ...engine import contract as C  # type: ignore[import-not-found]
from .errors import UserError

_DIGITS = re.compile(r"(\d+)(?=\.[^.]+$)")


def file_number(path: str) -> int | None:
    """The frame number in a sequence file name (``plate_0012.png`` -> 12)."""
    m = _DIGITS.search(os.path.basename(path))
    return int(m.group(1)) if m else None


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
    """Scene frames -> positions in the plate (the engine's ``--frames``)."""
    return first - clip_frame_start, last - clip_frame_start


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
