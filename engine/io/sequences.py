"""Finding and naming image sequences: the numbered images of a folder, or those a pattern names.

Frames are numbered the way pipeline tools number them (``fileseq``; one ``#`` per digit). Guessing which files the
user meant would silently fit the wrong frames, so a folder whose images mix types, numbered and unnumbered files,
duplicate numbers or several sequences is refused in one line, and a pattern's range must exist in full.
"""

from __future__ import annotations

import itertools
import os
import re
from dataclasses import dataclass
from typing import NoReturn

import fileseq

from .. import contract as C
from ..errors import InputError
from ..terms.paths import SEQUENCE_TOKEN
from .clip_messages import FRAME, Role, ext_list, frame_ranges, name_list

IMAGE_EXTENSIONS: tuple[str, ...] = (".png", ".jpg", ".jpeg", ".exr", ".dpx", ".tif", ".tiff")


_NUMBER = re.compile(r"\d+")
#: A sequence pattern's frame field: ``#``/``@`` padding (with an optional range before it) or printf ``%04d``.
_PATTERN = SEQUENCE_TOKEN
#: The longest range a pattern may name: 70 minutes at 24 frames a second, longer than any shot; a range of
#: 100 million frames would be expanded into numbers before the first file is looked for.
MAX_PATTERN_FRAMES = 100_000
#: How sequence patterns are read: one ``#`` per digit (``plate.####.exr`` is 4 digits, as in Nuke and Houdini).
_PAD_STYLE = fileseq.PAD_STYLE_HASH1


def is_sequence_pattern(path: str) -> bool:
    """Whether ``path`` names a sequence by pattern (``####``, ``@``, ``%04d`` in its file name)."""
    return _PATTERN.search(os.path.basename(path)) is not None


# --- listing a folder of numbered images --------------------------------------------------------------


@dataclass(frozen=True)
class NumberedFile:
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


def list_images(folder: str, role: Role) -> list[NumberedFile]:
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
            f"mixed image types ({counts} files): {name_list(others)}",
            f"keep one file type per {role.noun} folder: move or delete the other files",
        )
    (names,) = by_ext.values()
    files = []
    for name in names:
        numbers = _NUMBER.findall(os.path.splitext(name)[0])
        digits = numbers[-1] if numbers else ""
        if digits and _NEGATIVE.search(os.path.splitext(name)[0]):
            _refuse_negative(os.path.join(folder, name), role)
        files.append(NumberedFile(os.path.join(folder, name), int(digits) if digits else None, digits))
    unnumbered = sorted((f.name for f in files if f.number is None), key=_natural_key)
    if unnumbered and len(unnumbered) < len(files):
        raise InputError(
            folder,
            f"{role.noun} files without a frame number mixed with numbered ones: {name_list(unnumbered)}",
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


#: A frame number below 0 in a file name: a minus sign before the stem's last number that follows a separator
#: ("plate.-001", "plate_-001", "-001"); "plate-001" is frame 1 after a dash.
_NEGATIVE = re.compile(r"(?:^|[._])-\d+$")


def _refuse_negative(path: str, role: Role) -> NoReturn:
    """One line for a frame numbered below 0: no verb reads such a plate (Blender's scenes, Nuke's scripts and the
    exported passes number frames from 0), so it is refused before anything is read or written."""
    raise InputError(
        path,
        f"{role.noun} file numbered below 0",
        f"renumber the {role.noun} files from 0 or above (e.g. add an offset of 1001 to every number)",
    )


def sequence_files(source: str) -> tuple[str, list[NumberedFile]]:
    """(the clip's source as recorded, its frame files sorted by number) for a folder or a pattern.

    A folder holding one sequence is listed as it always was (``list_images``); a folder whose images form
    several numbered sequences of one type (``a.0001.exr`` and ``b.0001.exr``) is one line listing them, and a
    pattern picks one. A pattern's range must exist in full: a missing frame is reported, never skipped.
    """
    if os.path.isdir(source):
        _refuse_several_sequences(source)
        return source, list_images(source, FRAME)
    folder = os.path.dirname(source)
    if not os.path.isdir(folder):
        raise InputError(folder, "folder of the sequence pattern does not exist", "check the path of the pattern")
    try:
        pattern = fileseq.FileSequence(source, pad_style=_PAD_STYLE)
    except (fileseq.ParseException, ValueError):  # fileseq's MaxSizeException is a ValueError
        raise InputError(
            source, "is not a sequence pattern this reads", f"name one frame token and a range of at most "
            f"{MAX_PATTERN_FRAMES} frames, e.g. plate.1001-1100#.exr or plate.####.exr",
        ) from None  # fmt: skip
    wanted = pattern.frameSet()
    if wanted is not None and len(wanted) > MAX_PATTERN_FRAMES:  # before the range is expanded into numbers
        raise InputError(
            source,
            f"the pattern's range names {len(wanted)} frames",
            f"give it the shot's range (at most {MAX_PATTERN_FRAMES} frames), or drop the range to read every frame",
        )
    if wanted is not None and len(wanted) != int(wanted.end()) - int(wanted.start()) + 1:
        raise InputError(
            source,
            f"the pattern's range {wanted} skips frames, but a fit follows the motion from each frame to the next",
            f"give the range without a step or gap (e.g. {wanted.start()}-{wanted.end()}), or copy the frames to fit",
        )
    ext = pattern.extension().lower()
    if ext not in IMAGE_EXTENSIONS:
        raise InputError(source, f"pattern names {ext or 'no'} files", f"name {ext_list(IMAGE_EXTENSIONS)} frames")
    try:
        found = fileseq.findSequenceOnDisk(source, pad_style=_PAD_STYLE)
    except fileseq.FileSeqException:
        others = _sequences_in(folder)
        hint = f" (the folder holds {name_list([_seq_label(q) for q in others])})" if others else ""
        raise InputError(source, f"no files match this pattern{hint}", "check the file name and the padding") from None
    numbers = [int(n) for n in found.frameSet() or []]  # whole frames: subframes are not read
    if numbers and min(numbers) < 0:
        _refuse_negative(found.frame(min(numbers)), FRAME)
    if wanted is not None:
        missing = sorted({int(n) for n in wanted} - set(numbers))
        if missing:
            raise InputError(
                source,
                f"frames {frame_ranges(missing)} of the pattern's range are missing",
                "render or copy the missing frames, or give the pattern the range that exists",
            )
        numbers = sorted({int(n) for n in wanted})
    files = [NumberedFile(found.frame(n), n, str(n).zfill(found.zfill())) for n in numbers]
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


def image_sequences_in(folder: str | os.PathLike[str]) -> list[tuple[str, list[tuple[int, str]]]]:
    """The numbered image sequences of two frames or more in ``folder``: each as a message names it
    (``plate.####.exr (1001..1100)``) with its frames' numbers and files' names."""
    found = []
    for seq in _sequences_in(os.fspath(folder)):
        frames = [int(n) for n in seq.frameSet() or ()]
        if len(frames) >= 2:
            found.append((_seq_label(seq), [(n, os.path.basename(seq.frame(n))) for n in frames]))
    return found


def _seq_label(seq: fileseq.FileSequence) -> str:
    """``plate.####.exr (1001..1100)``: a sequence as a message names it."""
    frames = frame_ranges(sorted(int(n) for n in seq.frameSet() or []))
    return f"{seq.basename()}{'#' * max(1, seq.zfill())}{seq.extension()} ({frames})"


def pattern_like(path: str) -> str:
    """The pattern of the sequence an image file belongs to (``plate.1001.exr`` -> ``.../plate.####.exr``)."""
    return C.sequence_pattern_of(path) or os.path.join(os.path.dirname(path), "name.####.exr")


def _refuse_several_sequences(folder: str) -> None:
    """One line when a folder's images of one type form several numbered sequences: which one is the plate is
    the user's to say, by pattern (files of several types keep ``list_images``' own message)."""
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
                f"holds {len(seqs)} image sequences: {name_list([_seq_label(q) for q in seqs])}",
                f"pass one of them as a pattern, e.g. {example}",
            )
