"""The run folder's lock (``contract.run_lock``): one writer at a time, across processes, released by the OS.

A second process is refused at once with one line naming the holder; a holder killed with SIGKILL (no chance to
clean up) leaves nothing that blocks the next writer; within one process the lock is re-entrant (a verb that
calls another verb on the same folder).
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys

import pytest

from engine import contract as C
from tests.folders import hold_lock
from tests.paths import ROOT


@pytest.fixture
def holder(tmp_path):
    """A real child process holding ``tmp_path/run``'s lock."""
    run = tmp_path / "run"
    child = hold_lock(run)
    try:
        yield run, child
    finally:
        child.kill()
        child.wait()


def test_a_second_process_is_refused_in_one_line_naming_the_holder(holder):
    run, child = holder
    with pytest.raises(C.RunLocked) as info, C.run_lock(run, "export"):
        pass
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{run}: this run folder is in use by fit (pid {child.pid} on {socket.gethostname()}")
    assert C.RUN_LOCKED_FIX in message
    assert info.value.holder["pid"] == child.pid


def test_a_holder_killed_with_sigkill_releases_the_lock(holder):
    run, child = holder
    os.kill(child.pid, signal.SIGKILL)
    child.wait()
    with C.run_lock(run, "export"):
        assert (run / C.RUN_LOCK).exists()


def test_the_lock_is_reentrant_within_a_process_and_released_after(tmp_path):
    run = tmp_path / "run"
    with C.run_lock(run, "fit"), C.run_lock(run, "export"):
        pass
    probe = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys; from engine import contract as C\nwith C.run_lock(sys.argv[1], 'x'): pass",
            str(run),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert probe.returncode == 0, probe.stderr
