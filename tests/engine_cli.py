"""The engine's CLI run in-process, as the robustness tests call it: the exit code and the stderr lines."""

from __future__ import annotations

import contextlib
import io
import os

from engine import cli


def run_cli(*args: str | os.PathLike[str]) -> tuple[int, list[str]]:
    """``python -m engine ARGS`` in this process: its exit code and its non-blank stderr lines (stdout, the
    progress lines and printed paths, is dropped)."""
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = cli.main([os.fspath(a) for a in args])
    return code, [line for line in err.getvalue().splitlines() if line.strip()]
