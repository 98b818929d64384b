"""Shared helpers for the add-on tests (no bpy)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def fake_python(folder: Path) -> str:
    """An executable that behaves like `python -m engine ...` but runs fake_engine.py."""
    path = folder / "fake_python"
    path.write_text(
        f"#!{sys.executable}\n"
        "import runpy, sys\n"
        "args = sys.argv[1:]\n"
        "if args[:2] == ['-m', 'engine']:\n"
        "    args = args[2:]\n"
        f"sys.argv = [{str(HERE / 'fake_engine.py')!r}, *args]\n"
        f"runpy.run_path({str(HERE / 'fake_engine.py')!r}, run_name='__main__')\n"
    )
    os.chmod(path, 0o755)
    return str(path)
