"""Loading a clip: an image-sequence folder or a movie file, plus per-layer mask folders.

Everything the user points us at is validated here, up front, so a fit never dies an hour in on a
missing frame: ``open_clip`` lists the sequence, checks numbering, sizes and that the first frame
decodes, and every bad input raises an ``InputError`` whose one-line message names the file and the fix.

Pixel values are returned in the file's own encoding (integers scaled to [0, 1], floats untouched):
colour management and sanitising are the caller's decision, not the loader's. One clip has one encoding: a
sequence that mixes float (scene-linear) and integer (display-encoded) frames is refused, naming the first frame
that differs, since decoding every frame as frame 0's colour space would silently give the others the wrong
colours in the fit and in the composite. So is a DPX sequence whose frames' headers declare different transfers
(log, linear, other) when the headers choose the colour space (no ``--colorspace``).

This module is the loader's public face; the work is done by ``sequences`` (finding and naming a sequence),
``image_sequence`` and ``movie`` (opening and decoding each kind), ``image_reader`` (one image through
OpenImageIO), ``clip_info`` (what was opened) and ``clip_messages`` (the wording of a refusal).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path
from typing import NoReturn

import cv2
import numpy as np

from .. import contract as C
from ..errors import InputError
from . import colour
from .clip_info import MOVIE, SEQUENCE, ClipInfo, ColourChoice
from .clip_messages import FRAME, MASK, ext_list, frame_ranges
from .image_reader import decode_image
from .image_sequence import mixed_encoding, open_sequence
from .movie import MOVIE_EXTENSIONS, decode_movie, movie_frame_count, open_movie
from .sequences import IMAGE_EXTENSIONS, NumberedFile, is_sequence_pattern, list_images, pattern_like, sequence_files

#: An image drawn for a clip (a mask, scribbles, a painted frame) may have another resolution than the plate,
#: but an aspect ratio that differs from the plate's by more than this fraction means it belongs to another one.
ASPECT_TOLERANCE = 0.01


# --- public API ---------------------------------------------------------------------------------------


def open_clip(
    path: str | Path,
    frame_range: tuple[int, int] | None = None,
    colorspace: str | None = None,
    colour_config: str | None = None,
    *,
    fps: Fraction | None = None,
    start_frame: int | None = None,
) -> ClipInfo:
    """Open and validate a clip without decoding it all.

    ``path`` is a folder holding one image sequence, a sequence pattern (``plates/plate.####.exr``,
    ``plate.%04d.exr``, ``plate.1001-1100#.exr``: one ``#`` per digit, the padding is not enforced; a range
    selects those frames, each of which must exist) or a movie file. ``frame_range = (first, last)`` is
    INCLUSIVE, as positions 0..N-1 in the sorted sequence (not file numbers: ``frame_positions`` turns the
    plate's numbers into these). ``None`` selects every frame. ``colorspace``: the plate's colour space (a name
    or alias in ``colour_config``, default ``$OCIO`` or the built-in config); ``None``:
    ``colour.decide_colorspace`` (``ClipInfo.colour_source`` says how). ``fps`` is the rate of a plate whose files
    state none (and overrides one that does); ``start_frame`` numbers a movie's frames from it (default 0).
    """
    source = os.path.abspath(os.path.expanduser(os.fspath(path)))
    space = ColourChoice(colorspace, colour_config or colour.active_config())
    if not os.path.exists(source) and is_sequence_pattern(source):
        info = open_sequence(source, frame_range, space)
    elif not os.path.exists(source):
        raise InputError(source, "does not exist", "check the path: pass a folder of image frames or a movie file")
    elif os.path.isdir(source):
        info = open_sequence(source, frame_range, space)
    elif os.path.splitext(source)[1].lower() in MOVIE_EXTENSIONS:
        info = open_movie(source, frame_range, space, start_frame or 0)
    else:
        _refuse_file(source)
    if start_frame is not None and info.kind == SEQUENCE:
        raise InputError(
            source,
            "--start-frame numbers a movie's frames, but this is an image sequence",
            "drop --start-frame: a sequence's frames are numbered by their file names",
        )
    if fps is not None:
        info = dataclasses.replace(info, rate=fps, fps=float(fps))
    return info


def frame_positions(path: str | Path, numbers: tuple[int, int], start_frame: int | None = None) -> tuple[int, int]:
    """The plate's frame numbers ``numbers = (first, last)`` (inclusive; ``--frames 1010-1050``) as the positions
    ``open_clip`` takes. Lists the sequence (or counts the movie's frames) without decoding; a number the plate
    does not have is one line naming the plate's frames."""
    first, last = numbers
    source = os.path.abspath(os.path.expanduser(os.fspath(path)))
    if os.path.isfile(source):
        info = open_clip(source, start_frame=start_frame)
        _, count = _position_in_full_clip(info)
        plate = list(range(info.start_frame, info.start_frame + count))
    else:
        source, files = sequence_files(source) if os.path.isdir(source) or is_sequence_pattern(source) else (
            source, [])  # fmt: skip
        if not files:
            open_clip(source)  # the one-line reason there is no clip here
        plate = [f.number if f.number is not None else i for i, f in enumerate(files)]
    if first > last or first not in plate or last not in plate:
        bad = first if first > last or first not in plate else last
        what = f"--frames {first}..{last} is reversed" if first > last else f"frame {bad} is not in the plate"
        raise InputError(
            source,
            f"{what} (its frames are {frame_ranges(plate)})",
            f"choose --frames FIRST-LAST with plate frame numbers within {plate[0]}..{plate[-1]}",
        )
    return plate.index(first), plate.index(last)


def _refuse_file(source: str) -> NoReturn:
    """One line for a file that is no clip: a single image (pass its folder or a pattern) or an unknown type."""
    ext = os.path.splitext(source)[1].lower()
    if ext in IMAGE_EXTENSIONS:
        raise InputError(
            source,
            "is a single image, not a clip",
            f"pass the folder that holds the image sequence ({os.path.dirname(source)}) or a pattern such as "
            f"{pattern_like(source)}",
        )
    raise InputError(
        source,
        f"unknown file type '{ext or os.path.basename(source)}'",
        f"pass a folder of {ext_list(IMAGE_EXTENSIONS)} frames or a movie ({ext_list(MOVIE_EXTENSIONS)})",
    )


def read_frames(info: ClipInfo, size: tuple[int, int] | None = None) -> np.ndarray:
    """All selected frames as float32 ``[T, H, W, 3]`` RGB.

    Grey is replicated to 3 channels and alpha dropped. Integer formats are scaled to [0, 1]; float
    formats keep their raw values (EXR may hold >1, negatives, NaN — not sanitised here). ``size=(W, H)``
    resizes each frame as it is read (INTER_AREA when shrinking, INTER_LINEAR when enlarging), so the
    full-resolution clip never has to fit in memory at once.
    """
    return read_frames_at(info, [(info.width, info.height) if size is None else size])[0]


def read_frames_at(info: ClipInfo, sizes: list[tuple[int, int]]) -> list[np.ndarray]:
    """The selected frames decoded once and resized to each of ``sizes``, each array exactly what
    ``read_frames(info, size)`` returns (``fit --auto-masks`` needs the clip at two sizes)."""
    sizes = [_check_size(s) for s in sizes]
    out = [np.empty((info.num_frames, h, w, 3), dtype=np.float32) for w, h in sizes]
    for i, rgb in enumerate(iter_frames(info)):
        for frames, size in zip(out, sizes, strict=True):
            frames[i] = _resize(rgb, size)
    return out


def working_size(width: int, height: int, long_edge: int = C.DEFAULT_LONG_EDGE) -> tuple[int, int]:
    """Working ``(W, H)``: the long edge scaled to ``long_edge``, aspect kept, never enlarged
    (``contract.working_size``, which the add-on's estimate uses too). 854x480 -> (768, 432); 480x854 -> (432, 768).

    Fitting cost grows with pixel count, so big plates are shrunk; small ones are kept native because
    upsampling adds no information.
    """
    return C.working_size(width, height, long_edge)


def read_masks(folder: str | Path, info: ClipInfo, size: tuple[int, int]) -> np.ndarray:
    """One foreground layer's masks as bool ``[T, H, W]`` at ``size=(W, H)``.

    The folder holds one image per frame of the FULL clip or exactly one per selected frame. Masks are
    matched by file number when the clip is a sequence whose frame numbers all exist among the masks
    (frames/00012.jpg <-> masks/00012.png); otherwise by position when the mask count equals the selected
    (or full) frame count.

    Channels: a single channel is used as is; an image with an alpha channel whose alpha is NOT constant
    uses the alpha (a cut-out matte: colour may be the plate itself); otherwise the max over the colour
    channels (so a white-on-black matte in any channel counts). Values are taken as a fraction of full
    scale (8/16-bit normalised, floats raw, NaN as background); the mask is resized with INTER_AREA on
    these float values and THEN thresholded (above ``contract.MASK_THRESHOLD``), so a coarse mask stays coarse
    instead of being sharpened.
    """
    out_w, out_h = _check_size(size)
    mask_dir = os.path.abspath(os.path.expanduser(os.fspath(folder)))
    if not os.path.isdir(mask_dir):
        what = "is not a folder" if os.path.exists(mask_dir) else "mask folder does not exist"
        raise InputError(mask_dir, what, "pass the folder that holds this layer's mask images")
    masks = list_images(mask_dir, MASK)
    if not masks:
        raise InputError(
            mask_dir,
            f"no mask images in the folder (accepted: {ext_list(IMAGE_EXTENSIONS)})",
            "export one mask image per frame into this folder",
        )
    files = _match_masks(mask_dir, masks, info)
    out = np.empty((len(files), out_h, out_w), dtype=bool)
    for i, path in enumerate(files):
        image = decode_image(path, MASK)
        if not same_aspect((image.width, image.height), (info.width, info.height)):
            raise InputError(
                path,
                f"mask is {image.width}x{image.height} (aspect {image.width / image.height:.3f}) but the clip is "
                f"{info.width}x{info.height} (aspect {info.width / info.height:.3f})",
                "export the masks at the clip's resolution, or at least with the same aspect ratio",
            )
        out[i] = _resize(image.matte(), (out_w, out_h), grow=cv2.INTER_AREA) > C.MASK_THRESHOLD
    return out


def same_aspect(size: tuple[int, int], clip_size: tuple[int, int]) -> bool:
    """Whether an image of ``size`` (W, H) has the aspect ratio of a clip of ``clip_size``, within ASPECT_TOLERANCE."""
    clip_aspect = clip_size[0] / clip_size[1]
    return abs(size[0] / size[1] - clip_aspect) <= ASPECT_TOLERANCE * clip_aspect


# --- masks ---------------------------------------------------------------------------------------------


def _match_masks(mask_dir: str, masks: list[NumberedFile], info: ClipInfo) -> list[str]:
    """The mask file for each selected frame: by number if possible, else by position."""
    if info.kind == SEQUENCE and masks[0].number is not None:
        by_number = {m.number: m.path for m in masks}
        if all(n in by_number for n in info.frame_numbers):
            return [by_number[n] for n in info.frame_numbers]
    if len(masks) == info.num_frames:
        return [m.path for m in masks]
    offset, total = _position_in_full_clip(info)
    if len(masks) == total:
        return [m.path for m in masks[offset : offset + info.num_frames]]
    full = f" ({total} in the full clip)" if total != info.num_frames else ""
    raise InputError(
        mask_dir,
        f"{len(masks)} mask files for a clip of {info.num_frames} selected frames{full}",
        "provide one mask per frame, named with the frame numbers (e.g. 00012.png for frame 00012) "
        "or exactly one per frame in the same order",
    )


def _position_in_full_clip(info: ClipInfo) -> tuple[int, int]:
    """(position of the first selected frame, frame count) of the whole clip the selection came from."""
    if info.kind == MOVIE:
        return info.frame_numbers[0] - info.start_frame, movie_frame_count(info.source)
    paths = [f.path for f in sequence_files(info.source)[1]]
    offset = paths.index(info.frame_files[0]) if info.frame_files[0] in paths else 0
    return offset, len(paths)


# --- resizing -------------------------------------------------------------------------------------------


def _check_size(size: tuple[int, int]) -> tuple[int, int]:
    width, height = (int(v) for v in size)
    if width < 1 or height < 1:
        raise ValueError(f"size must be a positive (W, H), got {size}")
    return width, height


def _resize(image: np.ndarray, size: tuple[int, int], grow: int = cv2.INTER_LINEAR) -> np.ndarray:
    """Resize to (W, H): INTER_AREA when no side grows (averages, no aliasing), ``grow`` otherwise."""
    width, height = size
    if (image.shape[1], image.shape[0]) == (width, height):
        return image
    grows = width > image.shape[1] or height > image.shape[0]
    return cv2.resize(image, (width, height), interpolation=grow if grows else cv2.INTER_AREA)


def iter_frames(info: ClipInfo, size: tuple[int, int] | None = None) -> Iterator[np.ndarray]:
    """The selected frames one at a time, float32 [H, W, 3], as ``read_frames`` returns them but without
    holding the whole clip (render and export read native-resolution plates this way)."""
    out_w, out_h = (info.width, info.height) if size is None else _check_size(size)
    if info.kind == MOVIE:
        for rgb in decode_movie(info):
            yield _resize(rgb, (out_w, out_h))
        return
    for path in info.frame_files:
        image = decode_image(path, FRAME)
        if (image.width, image.height) != (info.width, info.height):
            raise InputError(
                path,
                f"frame is {image.width}x{image.height} but the clip is {info.width}x{info.height}",
                FRAME.size_fix,
            )
        if image.is_float != info.is_float:
            raise mixed_encoding(path, os.path.basename(info.frame_files[0]), image.is_float)
        yield _resize(image.rgb(), (out_w, out_h))
