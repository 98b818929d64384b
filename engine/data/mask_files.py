"""Mask files: a set of bool masks written as 8-bit 0/255 PNGs, one per frame, named like the frames.

A set of masks is written all or nothing (``write_mask_files``): assembled in a hidden folder beside its
destination and published at once, so a full disk, a cancel or a crash never leaves a partial set that a later
run (or ``fit --mask``) would take for a finished one, and running the command again writes the set. Existing
files are never replaced: an artist may have fixed them. Other per-frame image sets an artist checks and fixes (the
strokes of ``engine parts``) are written the same way (``write_file_set``).
"""

from __future__ import annotations

import errno
import os
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError
from ..io.atomic import disk_full_as_one_line, disk_full_error, signals_held
from ..io.clip_info import ClipInfo
from ..terms.run_folder import AUTO_PARTS_DIR, RUN_CLIP, RUN_CONFIG


def mask_file_names(info: ClipInfo) -> list[str]:
    """One PNG name per selected frame: the frame file's stem for a sequence, the frame number for a movie."""
    if info.frame_files:
        return [f"{Path(f).stem}.png" for f in info.frame_files]
    return [f"{n:05d}.png" for n in info.frame_numbers]


def output_folder(info: ClipInfo, out: str | Path, what: str = "mask") -> Path:
    """``out`` resolved (a link is followed: the files land where it points); a one-line error when it is a file, the
    clip's own frame folder, reached by any path, pattern or link (files named like the frames, beside them, would be
    read as frames), or a fit's run folder."""
    folder = Path(out).expanduser().resolve()
    if folder.exists() and not folder.is_dir():
        raise InputError(folder, "is a file, not a folder", f"pass a folder for the {what}s with --out")
    if info.kind == "sequence" and folder in {Path(f).resolve().parent for f in info.frame_files}:
        raise InputError(
            folder, "is the clip's own frame folder", f"write the {what}s to a folder of their own with --out"
        )
    if any((folder / name).exists() for name in (RUN_CLIP, RUN_CONFIG)):
        raise InputError(
            folder,
            "is a fit's run folder: its own files would mix with the fit's",
            f"write the {what}s to a folder of their own with --out (a fit's strokes go to its {AUTO_PARTS_DIR}/)",
        )
    return folder


def mask_folder(info: ClipInfo, out: str | Path, whole_set: bool = False) -> tuple[Path, list[str]]:
    """The folder the masks of ``info`` go to and their file names; a one-line error when the folder is a file,
    the clip's own frame folder, or already holds one of the names (masks are never overwritten) but, with
    ``whole_set``, for every one of them (the caller compares them with the set it would write)."""
    folder = output_folder(info, out)
    names = mask_file_names(info)
    clash = [n for n in names if (folder / n).exists()]
    if clash and not (whole_set and len(clash) == len(names)):
        raise already_holds(folder, clash)
    return folder, names


def holds_the_same(folder: Path, names: list[str], masks: np.ndarray) -> bool:
    """Whether ``folder`` holds every mask of the set, each file byte for byte what ``write_mask_files`` writes."""
    for name, mask in zip(names, masks, strict=True):
        try:
            if (folder / name).read_bytes() != _encode_mask(mask, name):
                return False
        except OSError:
            return False
    return True


#: The hidden folder a set of masks is assembled in, beside its destination (same file system, so publishing is a
#: rename): ``.<folder name>.<random>`` plus this suffix. Readers skip hidden entries; a process killed outright
#: (SIGKILL, power loss) may leave one behind, which nothing reads.
STAGING_SUFFIX = ".partial"
#: 0/255 mask values.
MASK_ON = 255


def _encode_mask(mask: np.ndarray, name: str) -> bytes:
    """One bool mask [H, W] as the bytes of an 8-bit greyscale 0/255 PNG."""
    ok, data = cv2.imencode(".png", mask.astype(np.uint8) * MASK_ON)
    if not ok:
        raise RuntimeError(f"cannot encode the mask {name} as PNG")
    return data.tobytes()


def _write_synced(path: Path, data: bytes) -> None:
    """``data`` into a new file at ``path``, on the disk before the set is published."""
    with open(path, "xb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def already_holds(folder: Path, clash: list[str], what: str = "mask") -> InputError:
    """Masks (or other ``what`` files) are never overwritten: the one line for a destination that holds some of the
    names."""
    return InputError(
        folder,
        f"already holds {clash[0]}" + (f" and {len(clash) - 1} more of the {what} names" if len(clash) > 1 else ""),
        f"{what}s are never overwritten (an artist may have fixed them): choose a new --out or delete them",
    )


def _link_new(source: Path, target: Path) -> None:
    """Give ``source`` the name ``target``, never replacing a file there (FileExistsError if one is): a hard link
    where the file system has them (race-free), else a rename after checking."""
    try:
        os.link(source, target)
    except FileExistsError:
        raise
    except OSError:  # no hard links here (FAT, some network shares)
        if target.exists():
            raise FileExistsError(errno.EEXIST, "exists", str(target)) from None
        os.rename(source, target)


def _publish(staging: Path, folder: Path, names: list[str], what: str) -> None:
    """Move the finished set from ``staging`` to ``folder``, all at once.

    A missing or empty ``folder`` is replaced by the staging folder in one rename (atomic). A folder that holds
    other files gets the set file by file, each linked under a name no file holds; a name taken meanwhile undoes
    the links made and is a one-line refusal. Cancels wait until the set is complete.
    """
    with signals_held():
        try:
            os.rename(staging, folder)
            return
        except OSError as exc:
            if exc.errno not in (errno.EEXIST, errno.ENOTEMPTY):
                raise
        linked: list[Path] = []
        try:
            for name in names:
                _link_new(staging / name, folder / name)
                linked.append(folder / name)
        except FileExistsError:
            for path in linked:
                path.unlink(missing_ok=True)
            raise already_holds(folder, [n for n in names if (folder / n).exists()], what) from None
        shutil.rmtree(staging, ignore_errors=True)


def _staging_folder(folder: Path, need: int, what: str) -> Path:
    """A new hidden folder beside ``folder`` (created with its parents); a full disk or a folder that cannot be
    created there is one line."""
    try:
        with disk_full_as_one_line(folder, need):
            folder.parent.mkdir(parents=True, exist_ok=True)
            return Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=STAGING_SUFFIX, dir=folder.parent))
    except (PermissionError, NotADirectoryError, FileExistsError) as exc:
        raise InputError(
            folder,
            f"cannot create the {what} folder here ({exc.strerror})",
            "choose a folder you can write to with --out",
        ) from None


def write_mask_files(folder: Path, names: list[str], masks: np.ndarray) -> list[str]:
    """Bool masks [T, H, W] (the clip's resolution) as 8-bit 0/255 PNGs ``folder/names[t]``, all or nothing
    (``write_file_set``); the paths written."""
    return write_file_set(folder, {name: _encode_mask(m, name) for name, m in zip(names, masks, strict=True)})


def write_file_set(folder: Path, files: dict[str, bytes], what: str = "mask") -> list[str]:
    """Encoded files (name -> bytes) into ``folder``, all or nothing; the paths written. ``what`` the files are
    names them in the one-line refusals.

    The set is written and synced into a hidden staging folder beside ``folder`` (``STAGING_SUFFIX``), then
    published (``_publish``). Any failure or cancel (a BaseException: SIGTERM raises one) removes the staging
    folder, so ``folder`` holds the whole set or nothing of it; a full disk is one line, ``disk full: free N MB
    at FOLDER`` (``DiskFullError``). Existing files are never replaced.
    """
    folder = Path(folder)
    names = list(files)
    need = sum(len(data) for data in files.values())
    staging = _staging_folder(folder, need, what)
    try:
        os.chmod(staging, 0o777 & ~_umask())  # the folder the artist gets: a plain mkdir's permissions, not 0700
        for name, data in files.items():
            _write_synced(staging / name, data)
        _publish(staging, folder, names, what)
    except BaseException as exc:
        shutil.rmtree(staging, ignore_errors=True)
        full = disk_full_error(exc, folder, need=need)
        if full is not None:
            raise full from None
        raise
    return [str(folder / name) for name in names]
