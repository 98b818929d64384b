"""Progress of a command: JSON lines on stdout (``terms.protocol.progress_line``, what the add-on reads) and the same
lines in the run's log file."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

from .. import contract as C
from ..io.atomic import append_text
from ..terms.protocol import progress_line
from .eta import JobClock


class Reporter:
    """Writes each progress event as one JSON line to ``stream`` (default: stdout) and to ``log_path``."""

    def __init__(self, log_path: Path | None = None, stream: TextIO | None = None) -> None:
        self.stream: TextIO | None = stream or sys.stdout
        self.log_path = log_path
        #: the whole job's clock: what ``job_event`` and ``job_fields`` report
        self.job = JobClock()

    @classmethod
    def null(cls) -> Reporter:
        """A reporter that writes nowhere: a measurement tool preparing a clip for itself."""
        reporter = cls()
        reporter.stream = None
        return reporter

    def emit(self, event: str, **fields: Any) -> None:
        if event == C.EVENT_DONE:  # the command's last message: its whole job is done, whatever share it left
            fields = {"job_fraction": 1.0, "job_eta": 0.0, **fields}
        line = progress_line(event, **fields)
        if self.stream is not None:
            print(line, file=self.stream, flush=True)
        if self.log_path is not None:
            append_text(self.log_path, line + "\n")  # refuses a link: the log is the one file appended to

    def job_fields(self) -> dict[str, Any]:
        """The whole job's fraction and seconds left, as the ``progress`` and ``job`` messages carry them."""
        left = self.job.left()
        return {"job_fraction": round(self.job.fraction(), 4), "job_eta": None if left is None else round(left, 1)}

    def job_event(self, stage: str, done: int, total: int, stage_eta: float | None) -> None:
        """One ``job`` message: the stage's count and seconds left, and the whole job's (``contract.EVENT_JOB``)."""
        self.emit(
            C.EVENT_JOB,
            stage=stage,
            done=done,
            total=total,
            stage_eta=None if stage_eta is None else round(stage_eta, 1),
            **self.job_fields(),
        )


def logged_fraction(log_path: Path, step: int, total: int) -> float | None:
    """The whole-job fraction a fit's log last showed at or before training step ``step`` of ``total`` (None:
    none logged, or logged for another number of steps): where a resumed fit's bar continues from."""
    found = None
    try:
        with open(log_path, encoding="utf-8", errors="replace") as f:
            for line in f:
                msg = C.parse_progress_line(line)
                if msg is None or msg.get("job_fraction") is None:
                    continue
                training = msg["event"] == C.EVENT_PROGRESS or msg.get("stage") == "train"
                at = msg.get("step", msg.get("done"))
                if training and msg.get("total") == total and isinstance(at, int) and at <= step:
                    found = float(msg["job_fraction"])
    except OSError:
        return None
    return found


class LineTap:
    """A text stream in front of ``stream``: each complete line written is handed to ``on_line``, and what that
    returns (the line itself, the line and more, or nothing) goes to ``stream``. How a verb's output is also said
    another way (OpenJD's progress lines, ``-v``) or held back (``-q``) without the verbs knowing."""

    def __init__(self, stream: TextIO, on_line: Callable[[str], str]) -> None:
        self.stream = stream
        self.on_line = on_line
        self._pending = ""

    def write(self, text: str) -> int:
        self._pending += text
        *lines, self._pending = self._pending.split("\n")
        for line in lines:
            self.stream.write(self.on_line(line + "\n"))
        return len(text)

    def flush(self) -> None:
        self.stream.flush()

    def close(self) -> None:
        """Hand on a last line without its newline; the stream itself stays open (it is the process's)."""
        if self._pending:
            self.stream.write(self.on_line(self._pending))
            self._pending = ""
        self.stream.flush()

    def __getattr__(self, name: str) -> Any:  # encoding, isatty, fileno ...: the stream's own
        return getattr(self.stream, name)


#: What ``-q`` keeps on stderr: the lines that need attention (a failure's one line, warnings, a cancellation) and
#: an engine error's traceback from its first line on.
QUIET_KEEPS: tuple[str, ...] = ("error:", "warning:", "cancelled:")
_TRACEBACK = "Traceback (most recent call last):"


def quiet_lines() -> Callable[[str], str]:
    """``LineTap``'s ``on_line`` for ``-q`` on stderr: notes, per-file lines, summaries and bars are left out."""
    in_traceback = False

    def keep(line: str) -> str:
        nonlocal in_traceback
        in_traceback = in_traceback or line.startswith(_TRACEBACK)
        return line if in_traceback or line.startswith(QUIET_KEEPS) else ""

    return keep


def stage_text(msg: dict[str, Any], fraction: float | None) -> str | None:
    """A ``stage`` message as ``-v`` says it on stderr: ``[ 12%] flow: optical flow ...`` (the whole job's percent
    where known); None for the other messages."""
    if msg["event"] != C.EVENT_STAGE:
        return None
    where = "     " if fraction is None else f"{100 * fraction:3.0f}%"
    message = " ".join(str(msg.get("message", "")).split())
    return f"[{where}] {msg.get('stage', '')}: {message}\n"


def verbose_lines(stderr: TextIO) -> Callable[[str], str]:
    """``LineTap``'s ``on_line`` for ``-v`` on stdout: stdout unchanged, each stage also on ``stderr``."""
    fraction: float | None = None

    def echo(line: str) -> str:
        nonlocal fraction
        msg = C.parse_progress_line(line)
        if msg is not None:
            if isinstance(msg.get("job_fraction"), (int, float)):
                fraction = float(msg["job_fraction"])
            text = stage_text(msg, fraction)
            if text is not None:
                stderr.write(text)
                stderr.flush()
        return line

    return echo


#: The longest ``openjd_status`` message (a stage's message cut there: one short line on the farm's monitor).
OPENJD_STATUS_MAX = 200


class OpenJDProgress:
    """``LineTap``'s ``on_line`` on stdout inside an Open Job Description task (``terms.protocol.OPENJD_PROGRESS_ENV``):
    each progress message also as the messages the runner reads from stdout, ``openjd_progress: <0..100>`` (the
    whole job's fraction; a command's own steps where it sends none; never decreasing, one decimal, printed when it
    moves) and ``openjd_status: <the stage's message>``; ``finished`` is the 100 of a verb that succeeded."""

    def __init__(self) -> None:
        self.shown = -1.0
        self.has_job_fraction = False

    def __call__(self, line: str) -> str:
        msg = C.parse_progress_line(line)
        if msg is None:
            return line
        said = []
        percent = self._percent(msg)
        if percent is not None and round(percent, 1) > self.shown:
            self.shown = round(percent, 1)
            said.append(f"openjd_progress: {self.shown}")
        if msg["event"] == C.EVENT_STAGE:
            status = " ".join(str(msg.get("message") or msg.get("stage", "")).split())
            said.append(f"openjd_status: {status[:OPENJD_STATUS_MAX]}")
        ending = "" if line.endswith("\n") or not said else "\n"
        return line + ending + "".join(f"{text}\n" for text in said)

    def _percent(self, msg: dict[str, Any]) -> float | None:
        fraction = msg.get("job_fraction")
        if isinstance(fraction, (int, float)) and not isinstance(fraction, bool):
            self.has_job_fraction = True
            return 100.0 * min(1.0, max(0.0, float(fraction)))
        step, total = msg.get("step"), msg.get("total")
        if msg["event"] != C.EVENT_PROGRESS or self.has_job_fraction:
            return None
        if isinstance(step, int) and isinstance(total, int) and total > 0:
            return 100.0 * min(1.0, max(0.0, step / total))
        return None

    def finished(self) -> str:
        """What a verb that succeeded prints last: its task is done, whatever its messages reached."""
        self.shown = 100.0
        return "openjd_progress: 100.0\n"


__all__ = [
    "OPENJD_STATUS_MAX",
    "LineTap",
    "OpenJDProgress",
    "Reporter",
    "logged_fraction",
    "quiet_lines",
    "stage_text",
    "verbose_lines",
]
