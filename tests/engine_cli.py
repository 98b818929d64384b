"""The engine's CLI as the tests call it: in-process (the exit code and the stderr lines), or as a real child
process whose progress lines are read until the test has seen what it waits for (then it signals the child)."""

from __future__ import annotations

import contextlib
import io
import os
import signal
import subprocess
import sys
from collections.abc import Callable
from typing import Any

from engine import cli
from engine import contract as C
from tests.paths import ROOT


def run_cli(*args: str | os.PathLike[str]) -> tuple[int, list[str]]:
    """``python -m engine ARGS`` in this process: its exit code and its non-blank stderr lines (stdout, the
    progress lines and printed paths, is dropped)."""
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = cli.main([os.fspath(a) for a in args])
    return code, [line for line in err.getvalue().splitlines() if line.strip()]


def start_engine(args: list[str]) -> subprocess.Popen[str]:
    """``python -m engine ARGS`` as a child process from the checkout, stdout and stderr piped as text.

    The child starts with SIGINT at its default action, as a command typed in a terminal does: a test suite started
    in the background (``cmd &``, ``nohup``) passes SIGINT on as ignored, and Python then leaves Ctrl-C ignored."""
    return subprocess.Popen(
        [sys.executable, "-m", "engine", *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def progress_until(
    proc: subprocess.Popen[str], stop_when: Callable[[list[dict[str, Any]]], bool]
) -> list[dict[str, Any]]:
    """Read the child's progress lines until ``stop_when(events)`` is true; returns the events read so far."""
    events: list[dict[str, Any]] = []
    assert proc.stdout is not None
    for line in proc.stdout:
        msg = C.parse_progress_line(line)
        if msg:
            events.append(msg)
            if stop_when(events):
                break
    return events
