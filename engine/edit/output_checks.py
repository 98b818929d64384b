"""What a writer's output may not be: the plate's frames, a mask folder of the fit, or anything inside the run
folder (its fit, exports and edit layers).

Checked before anything is written, so what render, preview and a movie write can never destroy what they read.
"""

from __future__ import annotations

import os
from pathlib import Path

from .. import contract as C
from ..errors import InputError
from ..export.manifest import Manifest
from ..io.sequences import image_sequences_in
from ..terms.paths import is_within
from .movie import MOVIE_SIZE_FIX, movie_size_problem
from .render_record import RECORD_NAME


def _same(a: str | Path, b: str | Path) -> bool:
    return os.path.normcase(os.path.realpath(a)) == os.path.normcase(os.path.realpath(b))


def protected_folders(manifest: Manifest) -> list[tuple[Path, str, str]]:
    """Folders outside the run that an output must never be: (folder, what it is, what it holds). The folders of
    the plate's frames and the fit's mask folders (the manifest records both)."""
    clip = manifest.clip
    found: list[tuple[Path, str, str]] = []
    if clip["kind"] == C.CLIP_KINDS[0]:
        plate = [manifest.plate_path(), *(manifest.plate_path(i).parent for i in range(len(clip["frame_files"])))]
        found += [(folder, "the folder of the plate's frames", "the plate") for folder in plate]
    found += [(manifest.resolve(m), "a mask folder of the fit", "the masks") for m in clip.get("masks", [])]
    return found


def check_output(
    manifest: Manifest, out: Path, option: str, allow: Path | None = None, writes: str | None = None
) -> None:
    """One line, before anything is written, when the folder ``out`` (frames are written straight into it) is or
    directly holds the plate's frames or a mask folder, lies inside the run folder (RUN_DIR itself, its exports,
    edits, records), or holds a numbered image sequence that is neither a render's (its record there) nor named as
    this writer names its frames (``writes``, a format pattern of ``frame``: a render made before renders recorded
    themselves); ``allow`` is the one folder inside the run folder this writer may use."""
    if allow is not None and _same(out, allow):
        return
    root = manifest.run_root
    if is_within(str(out), str(root)):
        raise InputError(
            out,
            f"is inside the run folder {root} (its fit, exports and edit layers)",
            f"choose a {option} outside the run folder",
        )
    for folder, what, holds in protected_folders(manifest):
        if _same(out, folder):
            raise InputError(out, f"is {what}", f"choose another {option}: nothing is written over {holds}")
    if out.is_dir() and not (out / RECORD_NAME).exists():
        for label, frames in image_sequences_in(out):
            if writes is None or any(writes.format(frame=number) != name for number, name in frames):
                raise InputError(
                    out,
                    f"holds the frames {label}, which no render of these names wrote (another plate's frames?)",
                    f"choose another {option}: nothing is written among another sequence's frames",
                )


def check_movie(manifest: Manifest, movie: Path) -> None:
    """One line, before anything is written, when ``--movie`` is the plate movie, a folder, or a file in a folder
    an output may not be (``check_output``)."""
    if movie.is_dir():
        raise InputError(movie, "is a folder", "give --movie a file name, e.g. edited.mp4")
    too_big = movie_size_problem(manifest.resolution)
    if too_big is not None:
        raise InputError(movie, too_big, MOVIE_SIZE_FIX)
    if manifest.clip["kind"] != C.CLIP_KINDS[0] and _same(movie, manifest.plate_path()):
        raise InputError(movie, "is the plate movie", "choose another --movie: nothing is written over the plate")
    check_output(manifest, movie.parent, "--movie folder")


__all__ = [
    "check_movie",
    "check_output",
    "protected_folders",
]
