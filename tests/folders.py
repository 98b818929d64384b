"""Folders as the robustness tests compare and make them: a digest of every file below a folder (what must stay
byte-identical), a folder whose name is not UTF-8, and JSON values of any shape for the loaders' fuzz tests."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest
from hypothesis import strategies as st

from engine import contract as C


def tree_digest(folder: Path) -> dict[str, str]:
    """SHA-256 of every file below ``folder`` (hidden ones included), by relative path; {} when it does not exist.
    The run folder's lock file is left out: it is the OS's bookkeeping, not the artist's work."""
    if not folder.exists():
        return {}
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != C.RUN_LOCK
    }


def non_utf8_folder(parent: Path, name: bytes) -> Path:
    """A new folder below ``parent`` whose name holds bytes that are not UTF-8 (a Latin-1 name on Linux: Python
    holds it as surrogate escapes); skips the calling test where the file system refuses such names."""
    path = Path(os.fsdecode(os.path.join(os.fsencode(parent), name)))
    try:
        path.mkdir()
    except (OSError, UnicodeError) as exc:
        pytest.skip(f"this file system takes only UTF-8 names ({exc})")
    return path


#: A JSON value of any shape: what a hand-edited or foreign file may hold.
JSON_VALUES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**70), max_value=2**70)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=12),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=12), inner, max_size=4),
    max_leaves=12,
)
