"""Folders as the robustness tests compare and make them: a digest of every file below a folder (what must stay
byte-identical), a folder whose name is not UTF-8, and a real process holding a run folder's lock."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

from engine.terms.lock import RUN_LOCK
from tests.paths import ROOT

#: A process that holds a run folder's lock (``contract.run_lock``, standard library only: any interpreter of the
#: checkout runs it, a Blender's included) until it is killed or its time is up.
HOLD_LOCK = """\
import sys, time
from engine import contract as C
with C.run_lock(sys.argv[1], sys.argv[2]):
    print("held", flush=True)
    time.sleep(float(sys.argv[3]))
"""


def hold_lock(run: Path, what: str = "fit", seconds: float = 120.0) -> subprocess.Popen:
    """Start a real child process that holds ``run``'s lock as ``what``; returns once it holds it (the caller
    kills it)."""
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD_LOCK, str(run), what, str(seconds)], cwd=ROOT, stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


def tree_digest(folder: Path) -> dict[str, str]:
    """SHA-256 of every file below ``folder`` (hidden ones included), by relative path; {} when it does not exist.
    The run folder's lock file is left out: it is the OS's bookkeeping, not the artist's work."""
    if not folder.exists():
        return {}
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != RUN_LOCK
    }


def visible_digest(folder: Path) -> dict[str, str]:
    """``tree_digest`` of the files a file browser shows (a render's hidden record left out: two exports of one fit
    render the same frames, each recording its own manifest)."""
    return {name: digest for name, digest in tree_digest(folder).items() if not name.startswith(".")}


def visible_names(folder: Path) -> list[str]:
    """The names of ``folder``'s entries a file browser shows (hidden ones, such as a render's record, left out),
    sorted."""
    return sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))


def non_utf8_folder(parent: Path, name: bytes) -> Path:
    """A new folder below ``parent`` whose name holds bytes that are not UTF-8 (a Latin-1 name on Linux: Python
    holds it as surrogate escapes); skips the calling test where the file system refuses such names."""
    path = Path(os.fsdecode(os.path.join(os.fsencode(parent), name)))
    try:
        path.mkdir()
    except (OSError, UnicodeError) as exc:
        pytest.skip(f"this file system takes only UTF-8 names ({exc})")
    return path
