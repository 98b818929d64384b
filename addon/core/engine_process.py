"""Run one engine command out of process and follow its JSON progress lines. No bpy here.

The engine is a child process started from an argv list (never a shell string). Two reader threads copy
its stdout and stderr into the log file; stdout lines that are progress messages (``engine.contract``)
are queued for the caller, which drains them with ``step()`` — from a modal timer in the UI, or in
``run_blocking`` for the blocking path (the pattern of Blender's own extension manager, bl_pkg).
``cancel()`` sends SIGTERM (the engine writes a checkpoint and exits with EXIT_CANCELLED) and kills after a
grace period. Whatever the child does — a bad argv, a crash, a signal — the caller gets a ``JobResult``, never
an exception.
"""

from __future__ import annotations

import atexit
import os
import queue
import subprocess
import threading
import time
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from ...engine import contract as C  # type: ignore[import-not-found]
from .progress import JobState

#: Seconds between SIGTERM and SIGKILL when cancelling (the engine needs a moment to write a checkpoint).
CANCEL_GRACE_SECONDS = 30.0
#: Seconds between two polls of a running job, in the UI's modal timer and in the blocking loop.
POLL_SECONDS = 0.1
#: Seconds to wait for the reader threads once the process has exited.
READER_JOIN_SECONDS = 5.0

STATUS_RUNNING = "running"
STATUS_OK = "ok"
STATUS_CANCELLED = "cancelled"
STATUS_BAD_INPUT = "bad_input"
STATUS_FAILED = "failed"


#: running jobs; at interpreter exit (Blender quits) they are asked to stop, since they run in their own
#: session and would otherwise fit on, orphaned
_LIVE: weakref.WeakSet[EngineJob] = weakref.WeakSet()


@atexit.register
def _stop_live_jobs() -> None:
    for job in list(_LIVE):
        job.cancel()


@dataclass
class JobResult:
    status: str
    returncode: int | None
    message: str
    log_path: str
    manifest: str | None = None
    metrics: dict[str, Any] | None = None


class EngineJob:
    """One engine process: start, poll, cancel, wait. Not thread-safe for several callers."""

    def __init__(self, argv: list[str], log_path: str, env: dict[str, str] | None = None, cwd: str | None = None):
        if isinstance(argv, str) or not all(isinstance(a, str) for a in argv):
            raise TypeError("argv must be a list of strings (never a shell string)")
        self.argv = list(argv)
        self.log_path = os.path.abspath(log_path)
        self.env = env
        self.cwd = cwd
        self.state = JobState()
        self._proc: subprocess.Popen[str] | None = None
        self._queue: queue.Queue[dict[str, Any]] = queue.Queue()
        self._threads: list[threading.Thread] = []
        self._log_lock = threading.Lock()
        self._log: Any = None
        self._cancel_requested = False
        self._cancel_time: float | None = None
        self._launch_error: str | None = None
        self._result: JobResult | None = None
        #: the progress messages the last ``step()`` drained
        self.messages: list[dict[str, Any]] = []

    # --- lifecycle -----------------------------------------------------------------------------------------
    def start(self) -> EngineJob:
        os.makedirs(os.path.dirname(self.log_path) or ".", exist_ok=True)
        self._log = open(self.log_path, "a", encoding="utf-8")  # noqa: SIM115 (closed in _finish)
        self._write_log(f"$ {' '.join(self.argv)}\n")
        try:
            self._proc = subprocess.Popen(
                self.argv,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
                encoding="utf-8",
                errors="replace",
                bufsize=1,
                env=self.env,
                cwd=self.cwd,
                start_new_session=True,  # a Ctrl-C in Blender's terminal must not kill the fit behind its back
            )
        except OSError as exc:
            self._launch_error = f"cannot start the engine ({self.argv[0]}): {exc.strerror or exc}"
            self._write_log(self._launch_error + "\n")
            return self
        _LIVE.add(self)
        for stream, is_stdout in ((self._proc.stdout, True), (self._proc.stderr, False)):
            t = threading.Thread(target=self._reader, args=(stream, is_stdout), daemon=True)
            t.start()
            self._threads.append(t)
        return self

    @property
    def running(self) -> bool:
        return self._proc is not None and self._result is None and self._proc.poll() is None

    def poll(self) -> list[dict[str, Any]]:
        """Drain the queued progress messages (applying them to ``state``)."""
        out = []
        while True:
            try:
                msg = self._queue.get_nowait()
            except queue.Empty:
                break
            self.state.apply(msg)
            out.append(msg)
        overdue = self._cancel_time is not None and time.monotonic() - self._cancel_time > CANCEL_GRACE_SECONDS
        if overdue and self._proc is not None and self.running:
            self._proc.kill()
        return out

    def step(self) -> bool:
        """Poll once; True while the process runs (its messages so far are in ``messages``)."""
        finished = self.done()  # before draining: once done, this drain reads everything the process wrote
        self.messages = self.poll()
        return not finished

    def cancel(self) -> None:
        """Ask the engine to stop (SIGTERM: it writes a checkpoint); SIGKILL after the grace period."""
        self._cancel_requested = True
        if self._proc is not None and self.running and self._cancel_time is None:
            self._cancel_time = time.monotonic()
            self._write_log("cancel requested: SIGTERM\n")
            self._proc.terminate()

    def done(self) -> bool:
        """True once the process has exited and its output is fully read."""
        if self._result is not None or self._launch_error is not None:
            return True
        if self._proc is None or self._proc.poll() is None:
            return False
        return not any(t.is_alive() for t in self._threads)

    def result(self) -> JobResult:
        """The outcome; call once ``done()`` (or after ``wait``)."""
        if self._result is None:
            self.poll()
            self._result = self._finish()
        return self._result

    def wait(
        self, timeout: float | None = None, on_message: Callable[[dict[str, Any]], None] | None = None
    ) -> JobResult:
        """The blocking path for one process (``run_blocking``); ``on_message`` sees every progress message."""

        def forward() -> None:
            for msg in self.messages:
                if on_message is not None:
                    on_message(msg)

        run_blocking(self, timeout, forward)
        return self.result()

    # --- internals -----------------------------------------------------------------------------------------
    def _write_log(self, text: str) -> None:
        with self._log_lock:
            if self._log is not None and not self._log.closed:
                self._log.write(text)
                self._log.flush()

    def _reader(self, stream: Any, is_stdout: bool) -> None:
        for line in stream:
            self._write_log(line if line.endswith("\n") else line + "\n")
            text = line.rstrip("\n")
            if is_stdout:
                msg = C.parse_progress_line(text)
                if msg is not None:
                    self._queue.put(msg)
                elif text.strip():
                    self.state.last_stdout = text.strip()
            else:
                self.state.note_stderr(text)
        stream.close()

    def _finish(self) -> JobResult:
        st = self.state
        if self._launch_error is not None:
            result = JobResult(STATUS_FAILED, None, self._launch_error, self.log_path)
        else:
            assert self._proc is not None
            rc = self._proc.wait()
            for t in self._threads:
                t.join(timeout=READER_JOIN_SECONDS)
            self._write_log(f"[exit code {rc}]\n")
            manifest = st.manifest
            if manifest is None and st.last_stdout.endswith(C.MANIFEST_NAME):
                manifest = st.last_stdout  # export: the last stdout line is the manifest's path
            result = JobResult(self._status(rc), rc, self._message(rc), self.log_path, manifest, st.metrics)
        with self._log_lock:
            if self._log is not None:
                self._log.close()
        return result

    def _status(self, rc: int) -> str:
        if rc == C.EXIT_OK:
            return STATUS_OK
        if rc == C.EXIT_CANCELLED or (self._cancel_requested and rc < 0):
            return STATUS_CANCELLED
        if rc == C.EXIT_BAD_INPUT:
            return STATUS_BAD_INPUT
        return STATUS_FAILED

    def _message(self, rc: int) -> str:
        st = self.state
        tail = st.stderr_tail
        if rc == C.EXIT_OK:
            return "done"
        if rc == C.EXIT_CANCELLED or (self._cancel_requested and rc < 0):
            where = f" at step {st.step}" if st.step else ""
            return f"cancelled{where}; Resume continues from the checkpoint"
        if rc == C.EXIT_BAD_INPUT:
            errors = [ln for ln in tail if ln.startswith("error:")]
            return (errors[-1] if errors else (tail[-1] if tail else "bad input")).removeprefix("error: ")
        if st.error:
            return f"engine error: {st.error}"
        if rc < 0:
            return f"the engine was killed by signal {-rc}"
        last = tail[-1] if tail else "no output"
        return f"the engine failed (exit code {rc}): {last}"


class Steppable(Protocol):
    """What ``run_blocking`` (and the add-on's modal operator) drive: an ``EngineJob`` or a ``jobs.Job``."""

    def step(self) -> bool: ...

    def cancel(self) -> None: ...


def run_blocking(
    job: Steppable,
    timeout: float | None = None,
    on_step: Callable[[], None] | None = None,
    interval: float = POLL_SECONDS,
) -> None:
    """The blocking path (background mode, scripts, tests): ``step()`` until it returns False, calling ``on_step``
    after each step; past ``timeout`` seconds the job is cancelled once (and still stepped to its end)."""
    deadline = None if timeout is None else time.monotonic() + timeout
    while True:
        more = job.step()
        if on_step is not None:
            on_step()
        if not more:
            return
        if deadline is not None and time.monotonic() > deadline:
            job.cancel()
            deadline = None
        time.sleep(interval)
