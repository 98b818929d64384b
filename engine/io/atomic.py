"""Atomic file writes: a temp file in the destination folder, then a rename.

A kill or a full disk never leaves a half-written file under the real name. Torch-free, so the export,
render and project-frame writers and the checkpoints share one mechanism. The temp name keeps the real
suffix (``.name.XXXX.tmp.exr``): image writers pick their format from it.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path


def _current_umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write(path: Path, write: Callable[[str], None], fsync: bool = True) -> Path:
    """Call ``write(tmp_path)``, optionally fsync the result, and rename it to ``path``.

    The result gets the permissions a plain ``open(path, "w")`` would (0666 less the umask), not the
    temp file's private 0600: a manifest or pass written on a render node must stay readable by the
    artist's workstation and the rest of the team.
    """
    path = Path(path)
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
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_bytes(path: Path, data: bytes) -> None:
    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            f.write(data)

    atomic_write(path, write)


def atomic_write_text(path: Path, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_text"]
