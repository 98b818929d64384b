"""The wording of a refused clip: every bad input is one ``InputError`` line naming the file and the fix.

Frames and masks go through the same listing and decoding code; a ``Role`` carries the advice that differs between
them, so each message says "frame" or "mask" and the fix that applies. The helpers here keep lists of names and
frame numbers short enough for one line.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

_MAX_LISTED = 3  # files named in a message before "and N more"


# --- what is being read: frames or masks (decides the wording of errors) ------------------------------


@dataclass(frozen=True)
class Role:
    """Frames and masks go through the same readers; only the advice to the user differs."""

    noun: str
    corrupt_fix: str
    size_fix: str


FRAME = Role(
    noun="frame",
    corrupt_fix="re-export this frame (it is truncated or corrupt)",
    size_fix="export every frame of the clip at the same resolution",
)
MASK = Role(
    noun="mask",
    corrupt_fix="re-export this mask (it is truncated or corrupt)",
    size_fix="export the masks at the clip's resolution",
)


def frame_ranges(numbers: list[int]) -> str:
    """``1001..1003, 1005..1010``: ascending frame numbers as runs (what a message says of a plate's frames)."""
    runs = []
    for _, group in itertools.groupby(enumerate(numbers), key=lambda p: p[1] - p[0]):
        run = [n for _, n in group]
        runs.append(f"{run[0]}..{run[-1]}" if len(run) > 1 else f"{run[0]}")
    return ", ".join(runs)


def name_list(names: list[str]) -> str:
    shown = ", ".join(names[:_MAX_LISTED])
    return shown if len(names) <= _MAX_LISTED else f"{shown} and {len(names) - _MAX_LISTED} more"


def ext_list(exts: tuple[str, ...]) -> str:
    return "/".join(exts)


def one_line(message: object) -> str:
    text = " ".join(str(message).split())
    return text or "unknown error"
