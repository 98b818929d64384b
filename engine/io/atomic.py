"""Atomic file writes: a temp file in the destination folder, then a rename; a full disk as one line; publishing a
staged set of files (``move_into_place`` under ``signals_held``): all of it or none.

A kill or a full disk never leaves a half-written file under the real name. Torch-free, so the export,
render and project-frame writers and the checkpoints share one mechanism. The temp name keeps the real
suffix (``.name.XXXX.tmp.exr``): image writers pick their format from it.

Links: the rename replaces whatever entry has the name, a symbolic or hard link included, and never writes the
file a link points to, so no write follows a link out of its folder. The one write in place, an append
(``append_text``: the fit's log), refuses a link instead.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from ..errors import DiskFullError, InputError
from ..terms.lock import IN_PLACE_UNSAFE_FIX, open_in_place

#: OS errors that mean "the disk is full" (no space, quota, file too large).
DISK_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})
#: A write that failed for another reason (torch.save and OpenEXR raise RuntimeError, not OSError) counts as a
#: full disk when what is left free after cleaning up is no more than what the write had reached plus this.
DISK_FULL_SLACK = 1024 * 1024


_UMASK_LOCK = threading.Lock()


def _current_umask() -> int:
    """The process's umask. Linux states it in /proc/self/status; elsewhere it can only be read by setting it and
    back, which is process-wide, so that is done under a lock (files are written from a second thread too:
    ``io.write_ahead``)."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    with _UMASK_LOCK:
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def free_bytes(folder: str | Path) -> int | None:
    """Bytes free to this user at ``folder`` (or the nearest folder above it that exists); None if unknown."""
    probe = Path(folder)
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    try:
        return shutil.disk_usage(probe).free
    except OSError:
        return None


def disk_full_error(
    exc: BaseException, folder: str | Path, written: int = 0, need: int | None = None
) -> DiskFullError | None:
    """The one-line ``DiskFullError`` that ``exc`` (raised while writing into ``folder``, after ``written`` bytes)
    stands for, or None when it is not a full disk. ``need``: the bytes the write needs, when known (else what
    was written plus the slack), so the message can say how much to free."""
    if isinstance(exc, DiskFullError):
        return exc
    free = free_bytes(folder)
    if isinstance(exc, OSError) and exc.errno in DISK_ERRNOS:
        full = True
    elif isinstance(exc, (OSError, RuntimeError)):
        full = free is not None and free <= written + DISK_FULL_SLACK
    else:
        return None
    if not full:
        return None
    need = need if need is not None else written + DISK_FULL_SLACK
    return DiskFullError(folder, max(need - (free or 0), DISK_FULL_SLACK))


@contextlib.contextmanager
def disk_full_as_one_line(folder: str | Path, need: int | None = None) -> Iterator[None]:
    """Writes inside the block that fail because ``folder``'s disk is full raise ``DiskFullError`` (one line)."""
    try:
        yield
    except (OSError, RuntimeError) as exc:
        full = disk_full_error(exc, folder, need=need)
        if full is None:
            raise
        raise full from None


def atomic_write(path: Path, write: Callable[[str], None], fsync: bool = True, need: int | None = None) -> Path:
    """Call ``write(tmp_path)``, optionally fsync the result, and rename it to ``path``.

    The result gets the permissions a plain ``open(path, "w")`` would (0666 less the umask), not the
    temp file's private 0600: a manifest or pass written on a render node must stay readable by the
    artist's workstation and the rest of the team. A write that fails because the disk is full (whatever the
    writer raises: torch.save and OpenEXR raise RuntimeError) leaves no temp file and raises ``DiskFullError``;
    ``need`` (bytes, when the caller knows) sizes its "free N MB".
    """
    path = Path(path)
    with disk_full_as_one_line(path.parent, need):
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
        os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_current_umask())
        if fsync:
            with open(tmp, "rb+") as f:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        written = Path(tmp).stat().st_size if Path(tmp).exists() else 0
        Path(tmp).unlink(missing_ok=True)
        full = disk_full_error(exc, path.parent, written, need)
        if full is not None:
            raise full from None
        raise
    return path


#: What a write that ran out of disk raises: the OS's error, a library's RuntimeError (OpenEXR, torch), or the
#: one-line DiskFullError an atomic write already made of it.
DISK_ERRORS = (OSError, RuntimeError, DiskFullError)


def as_disk_full(exc: BaseException, folder: Path, need: int | None = None) -> DiskFullError | None:
    """``exc``, raised while writing an output whose partial files are removed by now, as the one-line "disk full:
    free N MB at ``folder``", where ``need`` is what the whole output takes (so N is what to free); None when it
    is not a full disk."""
    if isinstance(exc, DiskFullError):
        exc = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    return disk_full_error(exc, folder, need=need)


def move_into_place(staged: Path, path: Path) -> None:
    """Rename a staged file onto its final name; across file systems (a folder linked elsewhere) it is copied to a
    temporary file beside ``path`` and renamed, so ``path`` is never seen half-written either way."""
    try:
        os.replace(staged, path)
    except OSError as exc:
        if exc.errno != errno.EXDEV:
            raise

        def copy(tmp: str) -> None:
            shutil.copyfile(staged, tmp)

        atomic_write(path, copy)
        staged.unlink()


#: The signals that cancel a verb (``engine.cli``), held back while a finished set of files is published.
HELD_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM that arrive inside the block take effect right after it, so the renames that publish a
    finished export, render, mask set or edit happen all or none. Python-level (the handlers are swapped for a
    recorder, not the OS mask): Python runs a handler in the main thread whichever thread the OS delivers the
    signal to. Outside the main thread handlers cannot be swapped, and the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []

    def hold(signum: int, _frame: Any) -> None:
        caught.append(signum)

    old = {signum: signal.signal(signum, hold) for signum in HELD_SIGNALS}
    try:
        yield
    finally:
        for signum, handler in old.items():
            signal.signal(signum, handler)
        for pending in dict.fromkeys(caught):
            signal.raise_signal(pending)


class LinkedFileError(InputError):
    """A file the engine writes in place (appends to) is a symbolic or hard link, a folder or not a plain file: one
    line, nothing written (``terms.lock.open_in_place``)."""

    def __init__(self, path: str, what: str) -> None:
        super().__init__(path, f"is {what}", IN_PLACE_UNSAFE_FIX)


def append_text(path: Path, text: str) -> None:
    """Append ``text`` to ``path`` (created if missing). An append cannot go through a temp file and a rename, so it
    is the one write that could follow a link: a symbolic link, a hard link or anything but a plain file at ``path``
    is refused (``LinkedFileError``) rather than written through."""
    fd = open_in_place(os.fspath(path), os.O_WRONLY | os.O_APPEND | os.O_CREAT, LinkedFileError)
    with os.fdopen(fd, "a", encoding="utf-8") as f:
        f.write(text)


def atomic_write_bytes(path: Path, data: bytes) -> None:
    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            f.write(data)

    atomic_write(path, write)


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


__all__ = [
    "DISK_ERRNOS",
    "DISK_ERRORS",
    "LinkedFileError",
    "append_text",
    "as_disk_full",
    "atomic_write",
    "atomic_write_bytes",
    "atomic_write_text",
    "disk_full_as_one_line",
    "disk_full_error",
    "free_bytes",
    "move_into_place",
    "signals_held",
]
