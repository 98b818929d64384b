"""What made the frames in a render's output folder (``OUT/.neural_atlas_render.json``), so frames of two renders
never mix there.

Chunks of one render (``render --frames``, one farm task each) write into the same folder, each committing its own
frames. A chunk of another export, of the same export with the artist's paint changed between chunks, or with
another format, name or filter would add its frames beside theirs without a word, and the folder would hold a clip
that no one render makes. So the folder records what its frames were rendered from (the manifest's content, not its
path, which differs between farm workers that mount the run folder at different places; the edit layers' pixels)
and how (format, names, filter, depth): a whole render commits its record with its frames (it replaces every one
of them: the artist renders again after painting more), the first chunk creates it, and a chunk must find its own
there, or is refused in one line before it writes a frame. A chunk creates it exclusively (a hard link of a
finished temporary file: two chunks starting together agree on one record, or the second is refused).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError

#: The record's file in the output folder (hidden: frame readers and the folder checks skip it).
RECORD_NAME = ".neural_atlas_render.json"
#: Bumped when the record's fields change; a folder recorded by another version is refused like another render.
RECORD_VERSION = 1
#: The fix every refusal gives.
RECORD_FIX = "render into a new --out, or empty this one first"


def _digest(data: bytes | memoryview) -> str:
    return hashlib.sha256(data).hexdigest()


def render_record(manifest_path: Path, edits: Sequence[np.ndarray | None], settings: dict[str, Any]) -> dict[str, Any]:
    """The record of a render of the manifest at ``manifest_path`` with the loaded ``edits`` (one per layer; None:
    no edit) and its output ``settings`` (format, names, filter, depth)."""
    return {
        "version": RECORD_VERSION,
        "manifest_sha256": _digest(manifest_path.read_bytes()),
        "edits_sha256": [None if e is None else _digest(np.ascontiguousarray(e).data.cast("B")) for e in edits],
        **settings,
    }


def _difference(held: dict[str, Any], wanted: dict[str, Any]) -> str | None:
    """The first field two records differ in, in words; None when they are the same."""
    words = {
        "manifest_sha256": "another export",
        "edits_sha256": "other paint in the edit layers",
        "version": "another version of the engine",
    }
    for key in sorted(set(held) | set(wanted), key=lambda k: (k not in words, k)):
        if held.get(key) != wanted.get(key):
            return words.get(key, f"another {key} ({held.get(key)!r})")
    return None


def claim_folder(out: Path, record: dict[str, Any]) -> bool:
    """Record ``record`` in ``out`` (an existing folder) unless it holds a record already; True when this call
    created it. A record of another render there is one line (``InputError``) naming what differs; the same record
    is a chunk of the same render, welcome."""
    path = out / RECORD_NAME
    text = json.dumps(record, indent=2, sort_keys=True)
    fd, tmp = tempfile.mkstemp(prefix=f"{RECORD_NAME}.", suffix=".tmp", dir=out)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        try:
            os.link(tmp, path)  # exclusive: fails when a record is there
            return True
        except FileExistsError:
            pass
    finally:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
    try:
        held = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        held = {}
    differs = _difference(held if isinstance(held, dict) else {}, record)
    if differs is not None:
        raise InputError(out, f"holds frames rendered from {differs}", RECORD_FIX)
    return False


def write_record(path: Path, record: dict[str, Any]) -> None:
    """``record`` written to ``path`` (a whole render stages it with its frames: committed with them, it replaces
    the folder's record, as its frames replace theirs)."""
    path.write_text(json.dumps(record, indent=2, sort_keys=True), encoding="utf-8")


__all__ = ["RECORD_FIX", "RECORD_NAME", "RECORD_VERSION", "claim_folder", "render_record", "write_record"]
