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
