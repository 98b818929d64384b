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

A movie whose decoder stops early or skips frames is refused, naming the file: a fit of the frames that did
decode would be the wrong frames, or too few, without a word. Movies are decoded on one thread
(``DECODER_THREADS``), so a damaged one is refused with the same message on every machine. An image is decoded
only when its header declares a size within ``engine.io.images.MAX_DECODED_BYTES``; a path that is not valid UTF-8
reads like any other (``engine.io.images.native_path``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import os
import re
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import NoReturn

import av
import cv2
import fileseq
import numpy as np
import OpenImageIO as oiio

from .. import contract as C
from ..errors import InputError
from . import colour
from .images import check_declared_size, open_image_input
from .timing import Timecode, exact_rate, pixel_aspect, timecode_at

IMAGE_EXTENSIONS: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".exr", ".dpx", ".tif", ".tiff")
MOVIE_EXTENSIONS: tuple[str, ...] = (".mp4", ".mov", ".mkv", ".avi", ".webm", ".m4v")

#: An image drawn for a clip (a mask, scribbles, a painted frame) may have another resolution than the plate,
#: but an aspect ratio that differs from the plate's by more than this fraction means it belongs to another one.
ASPECT_TOLERANCE = 0.01

_SEQUENCE = "sequence"
_MOVIE = "movie"
_FLOAT_TYPES = (oiio.FLOAT, oiio.HALF, oiio.DOUBLE)
_NUMBER = re.compile(r"\d+")
#: A sequence pattern's frame field: ``#``/``@`` padding (with an optional range before it) or printf ``%04d``.
_PATTERN = C.SEQUENCE_TOKEN
#: How sequence patterns are read: one ``#`` per digit (``plate.####.exr`` is 4 digits, as in Nuke and Houdini).
_PAD_STYLE = fileseq.PAD_STYLE_HASH1
_MAX_LISTED = 3  # files named in a message before "and N more"
#: A movie whose header stores no frame count (mkv, webm, some avi) is counted by its packets. When they cover
#: less than this fraction of the frames its duration declares (less one frame, for rounding), frames are
#: missing: the file is truncated or corrupt.
MOVIE_DURATION_COVERAGE = 0.95
#: Movies are decoded on one thread. With frame threads (FFmpeg's default picks one per core, up to 16) a corrupt
#: packet's error surfaces packets later, or not at all when it lands in the final flush, so one damaged file would
#: be refused with "cannot decode frame N" on a small machine and "the decoder gave N frames" on a large one.
#: Decoding is a small part of reading a frame (the RGB conversion costs more), so the threads buy little.
DECODER_THREADS = 1


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
    colour_config: str = C.COLOUR_BUILTIN_CONFIG
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
    """How ``colorspace`` was decided (``contract.COLOUR_SOURCES``): asked, the file's header, $OCIO's rules, the
    file type, or assumed; None where it is not known (a clip described by hand). Not what the clip is: clips that
    differ only in it are equal."""
    colour_note: str = dataclasses.field(default="", compare=False)
    """The one ``note:`` line a fit prints when the colour space was assumed ("" otherwise)."""


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
    space = _PlateColour(colorspace, colour_config or colour.active_config())
    if not os.path.exists(source) and is_sequence_pattern(source):
        info = _open_sequence(source, frame_range, space)
    elif not os.path.exists(source):
        raise InputError(source, "does not exist", "check the path: pass a folder of image frames or a movie file")
    elif os.path.isdir(source):
        info = _open_sequence(source, frame_range, space)
    elif os.path.splitext(source)[1].lower() in MOVIE_EXTENSIONS:
        info = _open_movie(source, frame_range, space, start_frame or 0)
    else:
        _refuse_file(source)
    if start_frame is not None and info.kind == _SEQUENCE:
        raise InputError(
            source,
            "--start-frame numbers a movie's frames, but this is an image sequence",
            "drop --start-frame: a sequence's frames are numbered by their file names",
        )
    if fps is not None:
        info = dataclasses.replace(info, rate=fps, fps=float(fps))
    return info


def is_sequence_pattern(path: str) -> bool:
    """Whether ``path`` names a sequence by pattern (``####``, ``@``, ``%04d`` in its file name)."""
    return _PATTERN.search(os.path.basename(path)) is not None


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
        source, files = _sequence_files(source) if os.path.isdir(source) or is_sequence_pattern(source) else (
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


def frame_ranges(numbers: list[int]) -> str:
    """``1001..1003, 1005..1010``: ascending frame numbers as runs (what a message says of a plate's frames)."""
    runs = []
    for _, group in itertools.groupby(enumerate(numbers), key=lambda p: p[1] - p[0]):
        run = [n for _, n in group]
        runs.append(f"{run[0]}..{run[-1]}" if len(run) > 1 else f"{run[0]}")
    return ", ".join(runs)


def _refuse_file(source: str) -> NoReturn:
    """One line for a file that is no clip: a single image (pass its folder or a pattern) or an unknown type."""
    ext = os.path.splitext(source)[1].lower()
    if ext in IMAGE_EXTENSIONS:
        raise InputError(
            source,
            "is a single image, not a clip",
            f"pass the folder that holds the image sequence ({os.path.dirname(source)}) or a pattern such as "
            f"{_pattern_like(source)}",
        )
    raise InputError(
        source,
        f"unknown file type '{ext or os.path.basename(source)}'",
        f"pass a folder of {_ext_list(IMAGE_EXTENSIONS)} frames or a movie ({_ext_list(MOVIE_EXTENSIONS)})",
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
    masks = _list_images(mask_dir, _MASK)
    if not masks:
        raise InputError(
            mask_dir,
            f"no mask images in the folder (accepted: {_ext_list(IMAGE_EXTENSIONS)})",
            "export one mask image per frame into this folder",
        )
    files = _match_masks(mask_dir, masks, info)
    out = np.empty((len(files), out_h, out_w), dtype=bool)
    for i, path in enumerate(files):
        image = _read_image(path, _MASK)
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


# --- what is being read: frames or masks (decides the wording of errors) ------------------------------


@dataclass(frozen=True)
class _Role:
    """Frames and masks go through the same readers; only the advice to the user differs."""

    noun: str
    corrupt_fix: str
    size_fix: str


_FRAME = _Role(
    noun="frame",
    corrupt_fix="re-export this frame (it is truncated or corrupt)",
    size_fix="export every frame of the clip at the same resolution",
)
_MASK = _Role(
    noun="mask",
    corrupt_fix="re-export this mask (it is truncated or corrupt)",
    size_fix="export the masks at the clip's resolution",
)


# --- listing a folder of numbered images --------------------------------------------------------------


@dataclass(frozen=True)
class _NumberedFile:
    """One image in a folder and the frame number in its name (the LAST integer of the stem)."""

    path: str
    number: int | None
    digits: str  # the number as written, to echo its zero padding in messages

    @property
    def name(self) -> str:
        return os.path.basename(self.path)


def _natural_key(name: str) -> tuple[tuple[int, int, str], ...]:
    """Sort key that orders 'shot9' before 'shot10' (for names whose numbers tie or are absent)."""
    return tuple((1, int(t), "") if t.isdigit() else (0, 0, t.lower()) for t in re.split(r"(\d+)", name) if t)


def _list_images(folder: str, role: _Role) -> list[_NumberedFile]:
    """Image files of one type in ``folder``, sorted by frame number; [] if there are none.

    Hidden files and non-image files are ignored (thumbnails, .DS_Store, notes). Mixed file types,
    numbered files mixed with unnumbered ones and duplicate numbers are errors: guessing which files
    the user meant would silently fit the wrong frames.
    """
    by_ext: dict[str, list[str]] = {}
    with os.scandir(folder) as entries:
        for entry in entries:
            if entry.name.startswith(".") or not entry.is_file():
                continue
            ext = os.path.splitext(entry.name)[1].lower()
            if ext in IMAGE_EXTENSIONS:
                by_ext.setdefault(ext, []).append(entry.name)
    if not by_ext:
        return []
    if len(by_ext) > 1:
        ranked = sorted(by_ext.items(), key=lambda kv: (-len(kv[1]), kv[0]))
        counts = " and ".join(f"{len(names)} {ext}" for ext, names in ranked)
        others = sorted((n for _, names in ranked[1:] for n in names), key=_natural_key)
        raise InputError(
            folder,
            f"mixed image types ({counts} files): {_name_list(others)}",
            f"keep one file type per {role.noun} folder: move or delete the other files",
        )
    (names,) = by_ext.values()
    files = []
    for name in names:
        numbers = _NUMBER.findall(os.path.splitext(name)[0])
        digits = numbers[-1] if numbers else ""
        files.append(_NumberedFile(os.path.join(folder, name), int(digits) if digits else None, digits))
    unnumbered = sorted((f.name for f in files if f.number is None), key=_natural_key)
    if unnumbered and len(unnumbered) < len(files):
        raise InputError(
            folder,
            f"{role.noun} files without a frame number mixed with numbered ones: {_name_list(unnumbered)}",
            "rename or remove the files without a number",
        )
    files.sort(key=lambda f: (f.number or 0, _natural_key(f.name)))
    for prev, cur in itertools.pairwise(files):
        if cur.number is not None and cur.number == prev.number:
            raise InputError(
                cur.path,
                f"{prev.name} and {cur.name} both have frame number {cur.number}",
                f"keep one {role.noun} file per frame number",
            )
    return files


def _sequence_files(source: str) -> tuple[str, list[_NumberedFile]]:
    """(the clip's source as recorded, its frame files sorted by number) for a folder or a pattern.

    A folder holding one sequence is listed as it always was (``_list_images``); a folder whose images form
    several numbered sequences of one type (``a.0001.exr`` and ``b.0001.exr``) is one line listing them, and a
    pattern picks one. A pattern's range must exist in full: a missing frame is reported, never skipped.
    """
    if os.path.isdir(source):
        _refuse_several_sequences(source)
        return source, _list_images(source, _FRAME)
    folder = os.path.dirname(source)
    if not os.path.isdir(folder):
        raise InputError(folder, "folder of the sequence pattern does not exist", "check the path of the pattern")
    pattern = fileseq.FileSequence(source, pad_style=_PAD_STYLE)
    wanted = pattern.frameSet()
    ext = pattern.extension().lower()
    if ext not in IMAGE_EXTENSIONS:
        raise InputError(source, f"pattern names {ext or 'no'} files", f"name {_ext_list(IMAGE_EXTENSIONS)} frames")
    try:
        found = fileseq.findSequenceOnDisk(source, pad_style=_PAD_STYLE)
    except fileseq.FileSeqException:
        others = _sequences_in(folder)
        hint = f" (the folder holds {_name_list([_seq_label(q) for q in others])})" if others else ""
        raise InputError(source, f"no files match this pattern{hint}", "check the file name and the padding") from None
    numbers = [int(n) for n in found.frameSet() or []]  # whole frames: subframes are not read
    if wanted is not None:
        missing = sorted({int(n) for n in wanted} - set(numbers))
        if missing:
            raise InputError(
                source,
                f"frames {frame_ranges(missing)} of the pattern's range are missing",
                "render or copy the missing frames, or give the pattern the range that exists",
            )
        numbers = sorted({int(n) for n in wanted})
    files = [_NumberedFile(found.frame(n), n, str(n).zfill(found.zfill())) for n in numbers]
    frame_range = f"{wanted}" if wanted is not None else ""
    recorded = f"{found.dirname()}{found.basename()}{frame_range}{'#' * max(1, found.zfill())}{found.extension()}"
    return recorded, files


def _sequences_in(folder: str) -> list[fileseq.FileSequence]:
    """The numbered image sequences in ``folder`` (hidden files and other types ignored)."""
    try:
        found = fileseq.FileSequence.findSequencesOnDisk(folder, pad_style=_PAD_STYLE)
    except (fileseq.FileSeqException, OSError):
        return []
    return sorted(
        (q for q in found if q.frameSet() is not None and q.extension().lower() in IMAGE_EXTENSIONS),
        key=lambda q: (q.extension().lower(), _natural_key(q.basename())),
    )


def _seq_label(seq: fileseq.FileSequence) -> str:
    """``plate.####.exr (1001..1100)``: a sequence as a message names it."""
    frames = frame_ranges(sorted(int(n) for n in seq.frameSet() or []))
    return f"{seq.basename()}{'#' * max(1, seq.zfill())}{seq.extension()} ({frames})"


def _pattern_like(path: str) -> str:
    """The pattern of the sequence an image file belongs to (``plate.1001.exr`` -> ``.../plate.####.exr``)."""
    return C.sequence_pattern_of(path) or os.path.join(os.path.dirname(path), "name.####.exr")


def _refuse_several_sequences(folder: str) -> None:
    """One line when a folder's images of one type form several numbered sequences: which one is the plate is
    the user's to say, by pattern (files of several types keep ``_list_images``' own message)."""
    by_ext: dict[str, list[fileseq.FileSequence]] = {}
    for seq in _sequences_in(folder):
        by_ext.setdefault(seq.extension().lower(), []).append(seq)
    for seqs in by_ext.values():
        names = {q.basename() for q in seqs}
        if len(names) > 1:
            first = seqs[0]
            example = os.path.join(folder, f"{first.basename()}{'#' * max(1, first.zfill())}{first.extension()}")
            raise InputError(
                folder,
                f"holds {len(seqs)} image sequences: {_name_list([_seq_label(q) for q in seqs])}",
                f"pass one of them as a pattern, e.g. {example}",
            )


def _name_list(names: list[str]) -> str:
    shown = ", ".join(names[:_MAX_LISTED])
    return shown if len(names) <= _MAX_LISTED else f"{shown} and {len(names) - _MAX_LISTED} more"


def _ext_list(exts: tuple[str, ...]) -> str:
    return "/".join(exts)


# --- opening ------------------------------------------------------------------------------------------


def _check_range(source: str, frame_range: tuple[int, int] | None, count: int) -> tuple[int, int]:
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
class _PlateColour:
    """The colour space asked for (``--colorspace``; None: the default for the file) in the OCIO config."""

    asked: str | None
    config: str

    def decide(self, path: str, facts: colour.FileColour | None) -> colour.PlateColour:
        """The plate's colour space and how it was decided: the one asked for, resolved in the config, else what
        ``path``'s header, the config's rules or its file type say (``facts``: its first frame's header; None for a
        movie)."""
        if self.asked is not None:
            return colour.PlateColour(colour.resolve(self.asked, self.config), C.COLOUR_SOURCE_ASKED)
        return colour.decide_colorspace(path, facts, self.config)


def _open_sequence(source: str, frame_range: tuple[int, int] | None, plate: _PlateColour) -> ClipInfo:
    folder, files = _sequence_files(source)
    if not files:
        movies = sorted(n for n in os.listdir(folder) if os.path.splitext(n)[1].lower() in MOVIE_EXTENSIONS)
        hint = f" (or pass the movie {movies[0]} itself)" if movies else ""
        raise InputError(
            folder,
            f"no image files in the folder (accepted: {_ext_list(IMAGE_EXTENSIONS)})",
            f"pass a folder that holds the frames as images{hint}",
        )
    first, last = _check_range(folder, frame_range, len(files))
    selected = files[first : last + 1]
    _check_gaps(folder, files, first, last)
    # Decode the first frame fully (a truncated export is caught now, not hours into a fit); for the
    # rest, headers are enough to check sizes cheaply.
    head = _read_image(selected[0].path, _FRAME)
    head_colour = colour.file_colour(head.spec, head.path)
    for f in selected[1:]:
        width, height, is_float, facts = _read_header(f.path, _FRAME)
        if (width, height) != (head.width, head.height):
            raise InputError(
                f.path,
                f"{f.name} is {width}x{height} but {selected[0].name} is {head.width}x{head.height}",
                _FRAME.size_fix,
            )
        if is_float != head.is_float:
            raise _mixed_encoding(f.path, selected[0].name, is_float)
        if plate.asked is None and colour.dpx_encoding(facts) != colour.dpx_encoding(head_colour):
            raise _mixed_transfer(f.path, selected[0].name, facts, head_colour)
    # Unnumbered files (all or none, see _list_images) are numbered by their position.
    numbers = [f.number for f in selected]
    frame_numbers = tuple(n if n is not None else first + i for i, n in enumerate(numbers))
    rate, aspect, timecode = _image_timing(head.spec)
    decided = plate.decide(head.path, head_colour)
    return ClipInfo(
        source=folder,
        kind=_SEQUENCE,
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


def _mixed_encoding(path: str, first_name: str, is_float: bool) -> InputError:
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


def _check_gaps(folder: str, files: list[_NumberedFile], first: int, last: int) -> None:
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


def _open_movie(path: str, frame_range: tuple[int, int] | None, plate: _PlateColour, start_frame: int = 0) -> ClipInfo:
    with _open_container(path) as container:
        stream = _video_stream(container, path)
        rate = stream.average_rate or stream.guessed_rate
        aspect = stream.sample_aspect_ratio
        stamp = next((s.metadata["timecode"] for s in container.streams if "timecode" in s.metadata), None)
        stamp = stamp or container.metadata.get("timecode")
        count = stream.frames
        only_stream = len(container.streams) == 1
        duration = container.duration / av.time_base if container.duration else None
        _one_decoder_thread(stream)
        try:
            frame = next(container.decode(stream), None)
        except av.FFmpegError as exc:
            raise InputError(path, f"cannot decode the first frame ({_one_line(exc)})", _MOVIE_FIX) from exc
    if frame is None:
        raise InputError(path, "the video stream has no frames", _MOVIE_FIX)
    if count <= 0:  # the container has no frame count (mkv, webm, some avi): count the packets instead
        count = _count_packets(path, float(rate) if rate else None, duration if only_stream else None)
    first, last = _check_range(path, frame_range, count)
    exact = exact_rate(Fraction(rate)) if rate else None
    timecode = timecode_at(stamp, exact, first)
    decided = plate.decide(path, None)
    return ClipInfo(
        source=path,
        kind=_MOVIE,
        frame_files=(),
        frame_numbers=tuple(range(start_frame + first, start_frame + last + 1)),
        width=frame.width,
        height=frame.height,
        fps=float(rate) if rate else None,
        colorspace=decided.space,
        channels=len(frame.format.components),
        colour_config=plate.config,
        colour_source=decided.source,
        colour_note=decided.note,
        rate=exact,
        pixel_aspect=pixel_aspect(float(aspect)) if aspect else 1.0,
        timecode=None if timecode is None else str(timecode),
        start_frame=start_frame,
    )


_MOVIE_FIX = "re-encode the movie (e.g. with ffmpeg) or export it as an image sequence"


def _open_container(path: str) -> av.container.InputContainer:
    try:
        return av.open(path)
    except (av.FFmpegError, OSError, ValueError, UnicodeError) as exc:
        raise InputError(path, f"cannot open the movie ({_one_line(exc)})", _MOVIE_FIX) from exc


def _video_stream(container: av.container.InputContainer, path: str) -> av.VideoStream:
    if not container.streams.video:
        raise InputError(
            path,
            "has no video stream",
            "pass a movie file with a video stream, or a folder holding an image sequence",
        )
    return container.streams.video[0]


def _count_packets(path: str, rate: float | None = None, duration: float | None = None) -> int:
    """Frame count by demuxing (cheap: no decoding) for containers whose header does not store it.

    With the stream's ``rate`` the count is checked against the span of the packets' timestamps and, when given,
    the container's declared ``duration`` (seconds; pass it only for a file whose one stream is this video): a
    demuxer that resynchronises past garbage, or a file cut short, yields fewer packets than the movie declares,
    and a fit of those would be the wrong frames or too few.
    """
    with _open_container(path) as container:
        stream = _video_stream(container, path)
        stamps = []
        try:
            for packet in container.demux(stream):
                if packet.size and not packet.is_discard:
                    stamps.append(packet.pts)
        except av.FFmpegError as exc:
            raise InputError(path, f"cannot read the movie ({_one_line(exc)})", _MOVIE_FIX) from exc
        time_base = float(stream.time_base) if stream.time_base else None
    count = len(stamps)
    declared = []
    timed = [t for t in stamps if t is not None]
    if rate and time_base and len(timed) > 1:
        declared.append(("its timestamps span", (max(timed) - min(timed)) * time_base * rate + 1))
    if rate and duration:
        declared.append((f"its declared duration ({duration:.2f} s at {rate:g} fps) holds", duration * rate))
    for what, frames in declared:
        if count + 1 < MOVIE_DURATION_COVERAGE * frames:
            raise InputError(
                path,
                f"only {count} frames can be read but {what} {round(frames)}: the file is truncated or corrupt",
                _MOVIE_FIX,
            )
    return count


def _one_decoder_thread(stream: av.VideoStream) -> None:
    """Give ``stream`` the decoder threading every read uses (``DECODER_THREADS``), before its first packet."""
    stream.thread_type = "SLICE"
    stream.codec_context.thread_count = DECODER_THREADS


def _decoded_frames(
    container: av.container.InputContainer, stream: av.VideoStream, path: str
) -> Iterator[av.VideoFrame]:
    """Every frame of the stream in order, then a check that the decoder gave one frame per packet it was fed.

    A decoder that meets a corrupt packet may drop its frame and carry on: every later frame would then be
    fitted under the wrong number. The whole stream is decoded (frames after the selection are not converted)
    so a dropped frame anywhere is a one-line refusal naming the file. (Timestamps cannot tell: some containers,
    AVI among them, carry none that follow the presentation order.)
    """
    fed = decoded = 0
    for packet in container.demux(stream):
        if packet.size and not packet.is_discard:
            fed += 1
        for frame in packet.decode():
            decoded += 1
            yield frame
    if decoded < fed:
        raise InputError(
            path,
            f"the decoder gave {decoded} frames for the {fed} the file holds: frames are corrupt and were dropped",
            _MOVIE_FIX,
        )


def _decode_movie(info: ClipInfo) -> Iterator[np.ndarray]:
    """Yield the selected frames as float32 RGB in [0, 1], decoding from the start (exact, no seeking)."""
    first, last = info.frame_numbers[0] - info.start_frame, info.frame_numbers[-1] - info.start_frame
    produced = 0
    with _open_container(info.source) as container:
        stream = _video_stream(container, info.source)
        _one_decoder_thread(stream)
        try:
            for index, frame in enumerate(_decoded_frames(container, stream, info.source)):
                if not first <= index <= last:
                    continue  # decoded to the end all the same: a frame dropped later is refused too
                if (frame.width, frame.height) != (info.width, info.height):
                    raise InputError(
                        info.source,
                        f"frame {index} is {frame.width}x{frame.height} but the movie is {info.width}x{info.height}",
                        _MOVIE_FIX,
                    )
                deep = max(c.bits for c in frame.format.components) > 8
                if deep:
                    rgb = frame.to_ndarray(format="rgb48le").astype(np.float32) / 65535.0
                else:
                    rgb = frame.to_ndarray(format="rgb24").astype(np.float32) / 255.0
                yield rgb
                produced += 1
        except av.FFmpegError as exc:
            raise InputError(
                info.source, f"cannot decode frame {first + produced} ({_one_line(exc)})", _MOVIE_FIX
            ) from exc
    if produced < info.num_frames:
        raise InputError(
            info.source,
            f"the decoder stopped after frame {first + produced - 1} but the movie declares frames up to {last} "
            f"(frames {first}..{last} were selected): the file is truncated or corrupt",
            f"{_MOVIE_FIX}, or choose a frame range that ends earlier",
        )


# --- reading one image through OpenImageIO ------------------------------------------------------------


@dataclass(frozen=True)
class _Image:
    """One decoded image, pixels in its display window, as float32 [H, W, C] in the file's encoding."""

    path: str
    pixels: np.ndarray
    channel_names: tuple[str, ...]
    alpha_channel: int
    is_float: bool
    spec: oiio.ImageSpec
    """The file's header (colour and timing facts are read from it: the file is not opened again)."""

    @property
    def width(self) -> int:
        return self.pixels.shape[1]

    @property
    def height(self) -> int:
        return self.pixels.shape[0]

    @property
    def channels(self) -> int:
        return self.pixels.shape[2]

    def _colour_channels(self) -> list[int]:
        return [i for i in range(self.channels) if i != self.alpha_channel]

    def rgb(self) -> np.ndarray:
        """[H, W, 3]: R,G,B by name when present (EXR can hold extra channels), grey replicated."""
        upper = [n.upper() for n in self.channel_names]
        if all(c in upper for c in "RGB"):
            index = [upper.index(c) for c in "RGB"]
        else:
            colour = self._colour_channels()
            if len(colour) == 1:
                index = colour * 3
            elif len(colour) >= 3:
                index = colour[:3]
            else:
                raise InputError(
                    self.path,
                    f"has channels {', '.join(self.channel_names)}, which are neither grey nor RGB",
                    "export the frames as RGB, RGBA or greyscale images",
                )
        return np.ascontiguousarray(self.pixels[:, :, index])

    def matte(self) -> np.ndarray:
        """[H, W] coverage: a varying alpha if there is one, else the max over colour channels."""
        pixels = np.nan_to_num(self.pixels, nan=0.0, posinf=1.0, neginf=0.0)
        colour = self._colour_channels()
        if self.alpha_channel >= 0:
            alpha = pixels[:, :, self.alpha_channel]
            if not colour or alpha.min() != alpha.max():
                return np.ascontiguousarray(alpha)
        return pixels[:, :, colour].max(axis=2)


def _read_config() -> oiio.ImageSpec:
    # Keep colour as written: by default OIIO premultiplies PNG/TIFF colour by alpha on read, which
    # would darken the plate wherever an exporter left a partial alpha we are about to drop anyway.
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    return config


@contextlib.contextmanager
def _quiet_codec_stderr() -> Iterator[None]:
    """Silence file descriptor 2 while a codec library decodes.

    libpng, libjpeg and OpenEXR print their complaints about a corrupt file straight to fd 2, which would
    put extra lines around our one-line error; OIIO's ``geterror()`` already carries the same text into it.
    """
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no usable fd 2 (embedded interpreter): nothing to silence
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


def _open_image(path: str, role: _Role) -> oiio.ImageInput:
    """The open image, its header checked: a size beyond ``images.MAX_DECODED_BYTES`` is refused before decoding."""
    inp = open_image_input(path, _read_config())
    if inp is None:
        raise InputError(path, f"cannot open this {role.noun} image ({_one_line(oiio.geterror())})", role.corrupt_fix)
    try:
        check_declared_size(path, inp.spec(), role.noun)
    except InputError:
        inp.close()
        raise
    return inp


def _read_header(path: str, role: _Role) -> tuple[int, int, bool, colour.FileColour]:
    """(width, height) of the display window, whether the pixels are floats and the colour facts, from the header
    only."""
    with _quiet_codec_stderr():
        inp = _open_image(path, role)
    try:
        spec = inp.spec()
        is_float = spec.format.basetype in _FLOAT_TYPES
        return spec.full_width or spec.width, spec.full_height or spec.height, is_float, colour.file_colour(spec, path)
    finally:
        inp.close()


def _read_image(path: str, role: _Role) -> _Image:
    """Decode subimage 0; any decoder complaint (even with partial pixels) counts as corrupt."""
    with _quiet_codec_stderr():
        inp = _open_image(path, role)
    try:
        spec = inp.spec()
        with _quiet_codec_stderr():
            pixels = inp.read_image(0, 0, 0, spec.nchannels, "float")  # integers come back normalised
        error = inp.geterror()
        if pixels is None or error:
            raise InputError(path, f"cannot read this {role.noun} ({_one_line(error)})", role.corrupt_fix)
        return _Image(
            path=path,
            pixels=_display_window(pixels.reshape(spec.height, spec.width, -1), spec),
            channel_names=tuple(spec.channelnames),
            alpha_channel=spec.alpha_channel,
            is_float=spec.format.basetype in _FLOAT_TYPES,
            spec=spec,
        )
    finally:
        inp.close()


def _display_window(pixels: np.ndarray, spec: oiio.ImageSpec) -> np.ndarray:
    """Place an EXR's data window (bounding box) into its display window, zeros outside."""
    fx, fy = spec.full_x, spec.full_y
    fw, fh = spec.full_width or spec.width, spec.full_height or spec.height
    if (spec.x, spec.y, spec.width, spec.height) == (fx, fy, fw, fh):
        return pixels
    out = np.zeros((fh, fw, pixels.shape[2]), dtype=np.float32)
    x0, x1 = max(spec.x, fx), min(spec.x + spec.width, fx + fw)
    y0, y1 = max(spec.y, fy), min(spec.y + spec.height, fy + fh)
    if x0 < x1 and y0 < y1:
        out[y0 - fy : y1 - fy, x0 - fx : x1 - fx] = pixels[y0 - spec.y : y1 - spec.y, x0 - spec.x : x1 - spec.x]
    return out


def _one_line(message: object) -> str:
    text = " ".join(str(message).split())
    return text or "unknown error"


# --- masks ---------------------------------------------------------------------------------------------


def _match_masks(mask_dir: str, masks: list[_NumberedFile], info: ClipInfo) -> list[str]:
    """The mask file for each selected frame: by number if possible, else by position."""
    if info.kind == _SEQUENCE and masks[0].number is not None:
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
    if info.kind == _MOVIE:
        with _open_container(info.source) as container:
            count = _video_stream(container, info.source).frames
        return info.frame_numbers[0] - info.start_frame, count if count > 0 else _count_packets(info.source)
    paths = [f.path for f in _sequence_files(info.source)[1]]
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
    if info.kind == _MOVIE:
        for rgb in _decode_movie(info):
            yield _resize(rgb, (out_w, out_h))
        return
    for path in info.frame_files:
        image = _read_image(path, _FRAME)
        if (image.width, image.height) != (info.width, info.height):
            raise InputError(
                path,
                f"frame is {image.width}x{image.height} but the clip is {info.width}x{info.height}",
                _FRAME.size_fix,
            )
        if image.is_float != info.is_float:
            raise _mixed_encoding(path, os.path.basename(info.frame_files[0]), image.is_float)
        yield _resize(image.rgb(), (out_w, out_h))
