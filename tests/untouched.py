"""What a test asserts was not touched: every entry below a root but the run and output folders the command may
write, links recorded as links (their text, never followed) and their targets hashed where they lie, so a write
through a link out of the run folder shows as a changed file."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path


def digest_outside(root: Path, *allowed: Path) -> dict[str, str]:
    """Each entry below ``root`` that is not below one of ``allowed`` (compared as spelled, links not resolved):
    a file by its SHA-256 and mode, a symbolic link by its text, a folder by its mode."""
    keep = [os.path.abspath(a) for a in allowed]

    def inside(path: str) -> bool:
        return any(path == a or path.startswith(a + os.sep) for a in keep)

    out: dict[str, str] = {}
    for folder, dirs, files in os.walk(root, followlinks=False):
        for name in sorted(dirs + files):
            path = os.path.join(folder, name)
            if inside(os.path.abspath(path)):
                continue
            rel = os.path.relpath(path, root)
            st = os.lstat(path)
            if os.path.islink(path):
                out[rel] = f"link -> {os.readlink(path)}"
            elif os.path.isdir(path):
                out[rel] = f"folder {st.st_mode:o}"
            else:
                out[rel] = f"{hashlib.sha256(Path(path).read_bytes()).hexdigest()} {st.st_mode:o}"
        dirs[:] = [d for d in dirs if not inside(os.path.abspath(os.path.join(folder, d)))]
    return out
