"""Progress of a command: JSON lines on stdout (``contract.progress_line``, what the add-on reads) and the same
lines in the run's log file."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, TextIO

from engine import contract as C
from engine.fit.eta import JobClock
from engine.io.atomic import append_text


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
        line = C.progress_line(event, **fields)
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


__all__ = ["Reporter", "logged_fraction"]
