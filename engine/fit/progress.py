"""Progress of a command: JSON lines on stdout (``contract.progress_line``, what the add-on reads) and the same
lines in the run's log file."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, TextIO

from engine import contract as C


class Reporter:
    """Writes each progress event as one JSON line to ``stream`` (default: stdout) and to ``log_path``."""

    def __init__(self, log_path: Path | None = None, stream: TextIO | None = None) -> None:
        self.stream: TextIO | None = stream or sys.stdout
        self.log_path = log_path

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
            with open(self.log_path, "a", encoding="utf-8") as f:
                f.write(line + "\n")


__all__ = ["Reporter"]
