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


def engine_python(verb: str, needs: str) -> str:
    """The real engine's interpreter for end-to-end tests (NEURAL_ATLAS_TEST_ENGINE_PYTHON, else this
    checkout's .venv); the test is skipped when it cannot import ``needs`` or has no ``verb``."""
    import subprocess

    import pytest

    root = Path(__file__).resolve().parents[2]
    py = os.environ.get("NEURAL_ATLAS_TEST_ENGINE_PYTHON") or str(root / ".venv" / "bin" / "python")
    if not os.path.exists(py):
        pytest.skip(f"no engine Python at {py}")
    probe = subprocess.run(
        [py, "-c", f"import {needs}, engine.cli as c; c.build_parser().parse_args([{verb!r}, '-h'])"],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=120,
    )
    if "usage:" not in probe.stdout:
        pytest.skip(f"engine at {py} cannot run {verb} ({needs}): {probe.stderr.strip()[-200:]}")
    return py
