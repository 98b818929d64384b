"""The run folder's lock (``contract.run_lock``): one writer at a time, across processes, released by the OS.

A second process is refused at once with one line naming the holder; a holder killed with SIGKILL (no chance to
clean up) leaves nothing that blocks the next writer; within one process the lock is re-entrant (a verb that
calls another verb on the same folder). The lock file is written in place (truncated, the holder written), so a
symbolic link, a hard link, a folder or a pipe at its name is refused in one line and nothing outside the run folder
changes.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from engine import contract as C
from engine.terms.lock import IN_PLACE_UNSAFE_FIX, RUN_LOCK, RUN_LOCKED_FIX, RunLockUnsafe
from engine.terms.run_folder import RUN_CLIP, RUN_CONFIG
from tests.engine_cli import run_cli
from tests.folders import hold_lock
from tests.paths import ROOT
from tests.untouched import digest_outside


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
    assert RUN_LOCKED_FIX in message
    assert info.value.holder["pid"] == child.pid


def test_a_holder_killed_with_sigkill_releases_the_lock(holder):
    run, child = holder
    os.kill(child.pid, signal.SIGKILL)
    child.wait()
    with C.run_lock(run, "export"):
        assert (run / RUN_LOCK).exists()


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


# --- a lock file that is not the run folder's own plain file ----------------------------------------------------
#: What a file outside the run folder holds before a writer meets a link to it (and must hold after).
PRECIOUS = b"the artist's notes, outside the run folder\n"


def _outside(tmp_path: Path) -> Path:
    target = tmp_path / "elsewhere" / "notes.txt"
    target.parent.mkdir()
    target.write_bytes(PRECIOUS)
    return target


def _refused(run: Path, what: str) -> str:
    with pytest.raises(RunLockUnsafe) as info, C.run_lock(run, "export"):
        pytest.fail("the lock was taken through a link")
    message = str(info.value)
    assert message == f"{run / RUN_LOCK}: the run folder's lock file is {what} — {IN_PLACE_UNSAFE_FIX}"
    assert isinstance(info.value, C.RunLocked)  # every writer's one-line refusal of a locked folder catches it
    return message


def test_a_lock_file_symlinked_out_of_the_run_folder_is_refused_and_its_target_is_untouched(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / RUN_LOCK).symlink_to(_outside(tmp_path))
    before = digest_outside(tmp_path, run)
    _refused(run, "a symbolic link")
    assert digest_outside(tmp_path, run) == before
    assert (tmp_path / "elsewhere" / "notes.txt").read_bytes() == PRECIOUS


def test_a_dangling_lock_link_is_refused_and_its_target_is_not_created(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    target = tmp_path / "elsewhere" / "new.txt"
    (run / RUN_LOCK).symlink_to(target)
    _refused(run, "a symbolic link")
    assert not target.parent.exists()
    assert os.path.islink(run / RUN_LOCK)


def test_a_lock_file_hard_linked_to_a_file_outside_is_refused_and_the_file_is_untouched(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    target = _outside(tmp_path)
    os.link(target, run / RUN_LOCK)
    before = digest_outside(tmp_path, run)
    _refused(run, "a hard link (2 names for one file)")
    assert digest_outside(tmp_path, run) == before and target.read_bytes() == PRECIOUS


def test_a_lock_name_taken_by_a_folder_or_a_pipe_is_refused_in_one_line(tmp_path):
    folder_run, pipe_run = tmp_path / "a", tmp_path / "b"
    (folder_run / RUN_LOCK).mkdir(parents=True)
    pipe_run.mkdir()
    os.mkfifo(pipe_run / RUN_LOCK)  # without O_NONBLOCK the open would hang here
    _refused(folder_run, "a folder")
    _refused(pipe_run, "not a plain file")


def test_export_with_its_lock_linked_out_exits_2_in_one_line_and_writes_nothing(tmp_path):
    """Through the CLI, as every locked verb refuses: the lock is taken before anything is read or written (the
    run's files here are empty: the refusal comes first)."""
    run = tmp_path / "run"
    run.mkdir()
    for name in (RUN_CONFIG, RUN_CLIP, C.RUN_CHECKPOINT):
        (run / name).write_bytes(b"")
    (run / RUN_LOCK).symlink_to(_outside(tmp_path))
    before, inside = digest_outside(tmp_path), digest_outside(run)
    code, err = run_cli("export", run, "--no-bar")
    assert (code, err) == (C.EXIT_BAD_INPUT, [f"error: {run / RUN_LOCK}: the run folder's lock file is a symbolic "
                                               f"link — {IN_PLACE_UNSAFE_FIX}"])  # fmt: skip
    assert digest_outside(tmp_path) == before and digest_outside(run) == inside  # not even exports/ was made


def test_a_plain_lock_file_left_by_an_earlier_writer_is_taken_as_before(tmp_path):
    run = tmp_path / "run"
    with C.run_lock(run, "fit"):
        pass
    with C.run_lock(run, "export"):
        assert json.loads((run / RUN_LOCK).read_bytes()[1:])["what"] == "export"
