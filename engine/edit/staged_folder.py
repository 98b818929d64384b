"""Writing a set of files all or nothing: each is written into a hidden staging folder inside the output folder,
and all of them are moved into place together once every one is written (``StagedFolder``).

A failure, a full disk or a cancel removes the staging (and the output folder when the writer created it), so no
partial set of frames is ever left and earlier files in the output folder are untouched. One staging folder per
writing process (its id in the name), so chunks of one render may write into the same folder at once.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from types import TracebackType

from ..errors import InputError
from ..io.atomic import disk_full_error, signals_held
from ..terms.paths import is_within

#: Hidden staging folders inside an output folder, one per writing process (``.edit.partial-1234``).
STAGING_PREFIX = "."
STAGING_SUFFIX = ".partial-"


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def first_missing(folder: Path) -> Path | None:
    """The outermost folder of ``folder``'s path that does not exist yet (what creating it creates), or None."""
    missing = None
    probe = folder.absolute()
    while not probe.exists():
        missing = probe
        if probe.parent == probe:
            break
        probe = probe.parent
    return missing


class StagedFolder:
    """Files written into a hidden staging folder inside ``out`` and moved into ``out`` together once all of them
    are written (``commit``). Leaving the block without a commit (any failure, a full disk, a cancel) removes the
    staging, and ``out`` itself when this created it: nothing partial is left and earlier files are untouched."""

    def __init__(self, out: str | Path, what: str, option: str, shared: bool = False) -> None:
        """``what`` names the staging folder (one per writer of ``out`` at a time); ``shared``: other processes write
        into ``out`` too (a chunk of a render), so a failure never removes ``out`` even when this created it."""
        self.out = Path(out)
        self.what = what
        self.option = option
        self.shared = shared
        self.staging = self.out / f"{STAGING_PREFIX}{what}{STAGING_SUFFIX}{os.getpid()}"
        self.created: Path | None = None
        self.names: list[str] = []
        self.committed = False
        self.discarded_bytes = 0

    def __enter__(self) -> StagedFolder:
        if self.out.exists() and not self.out.is_dir():
            raise InputError(self.out, "is a file, not a folder", f"give {self.option} a folder (created when missing)")
        self.created = None if self.shared else first_missing(self.out)
        try:
            self.out.mkdir(parents=True, exist_ok=True)
            self._clear_stale()
            self.staging.mkdir()
        except OSError as exc:
            self.discard()
            full = disk_full_error(exc, self.out)
            if full is not None:
                raise full from None
            problem = f"cannot create the output folder ({exc.strerror or type(exc).__name__})"
            raise InputError(self.out, problem, f"choose a writable {self.option}") from None
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if not self.committed:
            self.discard()

    def _clear_stale(self) -> None:
        """Remove the staging folders that killed writers left here (their process is gone)."""
        prefix = f"{STAGING_PREFIX}{self.what}{STAGING_SUFFIX}"
        for entry in self.out.iterdir():
            pid = entry.name.removeprefix(prefix)
            if entry.name.startswith(prefix) and entry.is_dir() and pid.isdigit() and not _pid_alive(int(pid)):
                shutil.rmtree(entry, ignore_errors=True)

    def path(self, name: str) -> Path:
        """Where to write the output file ``name`` (in the staging folder until ``commit``)."""
        self.names.append(name)
        return self.staging / name

    def staged_bytes(self) -> int:
        """Bytes written into the staging folder so far."""
        return sum(p.stat().st_size for p in self.staging.iterdir() if p.is_file()) if self.staging.is_dir() else 0

    def commit(self) -> list[Path]:
        """Move every staged file into ``out`` (signals held: all or none); returns their final paths."""
        with signals_held():
            for name in self.names:
                os.replace(self.staging / name, self.out / name)
            shutil.rmtree(self.staging, ignore_errors=True)
            self.committed = True
        return [self.out / name for name in self.names]

    def discard(self) -> None:
        """Remove the staging (remembering how much it held) and ``out`` when this created it."""
        self.discarded_bytes = self.staged_bytes()
        shutil.rmtree(self.staging, ignore_errors=True)
        if self.created is not None:
            shutil.rmtree(self.created, ignore_errors=True)

    def names_output(self, path: str | Path) -> bool:
        """Whether ``path`` (where a write failed) is this output's: the staging folder, or ``out``."""
        return is_within(str(path), str(self.out))


__all__ = [
    "STAGING_PREFIX",
    "STAGING_SUFFIX",
    "StagedFolder",
    "first_missing",
]
