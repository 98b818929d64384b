"""The run folder's lock, held by every writer of a run folder (the engine's verbs and the add-on's Save Edits),
and the opening of a file written in place, never through a link."""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Iterator
from typing import Any

#: Every writer of a run folder (fit, export, project-frame, preview, the add-on's Save Edits) holds an exclusive
#: lock on RUN_DIR/RUN_LOCK for the whole write; the OS releases it when the process ends, however it ends. The
#: file holds the holder's {"pid", "host", "what", "since"} so a second writer's one-line refusal can name it.
RUN_LOCK = ".neural_atlas.lock"
#: The fix printed when a run folder is locked by another process.
RUN_LOCKED_FIX = "wait for it to finish (or stop it), then run this again"


class RunLocked(Exception):
    """Another process holds the run folder's lock: the message names the holder (one line)."""

    def __init__(self, folder: str, holder: dict[str, Any]) -> None:
        self.folder = folder
        self.holder = holder
        who = f"{holder.get('what', 'another process')} (pid {holder.get('pid', '?')} on {holder.get('host', '?')}"
        since = holder.get("since")
        who += f", since {since})" if since else ")"
        super().__init__(f"{folder}: this run folder is in use by {who} — {RUN_LOCKED_FIX}")


#: The fix printed when a file the engine writes in place (the lock, the fit's log) is a link or not a plain file.
IN_PLACE_UNSAFE_FIX = "delete it (the engine makes a new one): the engine never writes through a link"


def in_place_problem(st: os.stat_result) -> str | None:
    """Why a file opened to be written in place (not through a temp file and a rename) must not be written, or
    None: a hard link (truncating or appending would change the other name's file too, outside the run folder
    perhaps) or not a plain file (a pipe, a device). A symbolic link never gets this far: it is opened with
    O_NOFOLLOW."""
    import stat

    if not stat.S_ISREG(st.st_mode):
        return "not a plain file"
    if st.st_nlink > 1:
        return f"a hard link ({st.st_nlink} names for one file)"
    return None


#: Open flags of a file written in place: a symbolic link at the name fails (ELOOP) rather than being followed;
#: non-blocking so a pipe planted there cannot hang the open (no effect on a plain file).
IN_PLACE_FLAGS = getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)


def open_in_place(path: str, flags: int, unsafe: type[Exception], *args: Any) -> int:
    """``os.open(path, flags)`` for a file written in place, never through a link: a symbolic link, a hard link,
    a folder or anything but a plain file at ``path`` raises ``unsafe(*args, path, what_it_is)`` (one line) and
    nothing is written."""
    import errno

    try:
        fd = os.open(path, flags | IN_PLACE_FLAGS, 0o666)
    except OSError as exc:
        if os.path.islink(path) or exc.errno in (errno.ELOOP, errno.EMLINK):
            raise unsafe(*args, path, "a symbolic link") from None
        if os.path.isdir(path):
            raise unsafe(*args, path, "a folder") from None
        raise
    problem = in_place_problem(os.fstat(fd))
    if problem is not None:
        os.close(fd)
        raise unsafe(*args, path, problem)
    return fd


class RunLockUnsafe(RunLocked):
    """RUN_DIR/RUN_LOCK is a symbolic link, a hard link or not a plain file: writing the holder into it would
    truncate and write another file (outside the run folder, perhaps). A ``RunLocked``, so every writer that
    refuses a folder in use in one line (the CLI, exit 2; the add-on's operators) refuses this one the same way."""

    def __init__(self, folder: str, path: str, what: str) -> None:
        Exception.__init__(self, f"{path}: the run folder's lock file is {what} — {IN_PLACE_UNSAFE_FIX}")
        self.folder = folder
        self.holder: dict[str, Any] = {}


#: Run folders this process holds, and how many times (a verb that calls another verb re-enters its lock).
_HELD_LOCKS: dict[str, list[Any]] = {}


def _try_lock(fd: int) -> bool:
    if os.name == "nt":  # pragma: no cover - Windows
        import msvcrt

        try:
            os.lseek(fd, 0, os.SEEK_SET)
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)  # type: ignore[attr-defined]
        except OSError:
            return False
        return True
    import fcntl

    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


def _read_holder(path: str) -> dict[str, Any]:
    try:
        with open(path, "rb") as f:
            f.seek(1)  # byte 0 is the one Windows locks
            data = json.loads(f.read().decode("utf-8") or "{}")
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


@contextlib.contextmanager
def run_lock(folder: str | os.PathLike[str], what: str) -> Iterator[None]:
    """Hold RUN_DIR's exclusive lock for the ``with`` block (creating the folder); raises RunLocked at once when
    another process holds it. Re-entrant within one process. ``what`` names the holder in others' messages."""
    import datetime
    import socket

    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    key = os.path.realpath(folder)
    held = _HELD_LOCKS.get(key)
    if held is not None:
        held[1] += 1
        try:
            yield
        finally:
            held[1] -= 1
        return
    path = os.path.join(folder, RUN_LOCK)
    fd = open_in_place(path, os.O_RDWR | os.O_CREAT, RunLockUnsafe, folder)
    try:
        if not _try_lock(fd):
            raise RunLocked(folder, _read_holder(path))
        since = datetime.datetime.now().astimezone().isoformat(timespec="seconds")
        holder = {"pid": os.getpid(), "host": socket.gethostname(), "what": what, "since": since}
        os.ftruncate(fd, 1)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, b" " + json.dumps(holder).encode("utf-8"))
        _HELD_LOCKS[key] = [fd, 1]
        try:
            yield
        finally:
            del _HELD_LOCKS[key]
    finally:
        os.close(fd)  # closing the descriptor releases the lock


#: What ``engine.contract`` re-exports from this module (its own names, not its imports).
__all__ = [
    "IN_PLACE_FLAGS",
    "IN_PLACE_UNSAFE_FIX",
    "RUN_LOCK",
    "RUN_LOCKED_FIX",
    "RunLockUnsafe",
    "RunLocked",
    "in_place_problem",
    "open_in_place",
    "run_lock",
]
