"""Errors the user can act on.

Every failure caused by the user's input is an ``InputError`` whose message is ONE line that names the
file and says how to fix it; the CLI prints it and exits with ``contract.EXIT_BAD_INPUT``.
"""

from __future__ import annotations

from pathlib import Path


class InputError(Exception):
    """Bad input: a one-line message naming the offending file and the fix."""

    def __init__(self, path: str | Path | None, problem: str, fix: str) -> None:
        self.path = None if path is None else str(path)
        self.problem = problem
        self.fix = fix
        where = f"{self.path}: " if self.path else ""
        super().__init__(f"{where}{problem} — {fix}".replace("\n", " "))


#: Bytes in the megabyte of the disk-full message.
MB = 1024 * 1024


class DiskFullError(InputError):
    """The disk (or the quota) is full: ``disk full: free N MB at PATH``. Not a bug, so one line and exit 2;
    whatever was being written was removed, and earlier results are intact."""

    def __init__(self, path: str | Path, need_bytes: int) -> None:
        self.need_mb = max(1, -(-int(need_bytes) // MB))
        super().__init__(path, "disk full", "free space or choose another output folder, then run the command again")
        self.args = (
            f"disk full: free {self.need_mb} MB at {path} — nothing half-written was kept and earlier results are "
            "intact; run the command again",
        )

    def __str__(self) -> str:
        return str(self.args[0])


class FitDiverged(Exception):
    """The fit's loss, gradients or parameters stopped being finite: the message (one line) names the step, the
    likely cause and how to continue from the last good checkpoint (``terms.cli.EXIT_DIVERGED``)."""
