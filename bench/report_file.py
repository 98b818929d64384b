"""The ``--json OUT`` file of the scoring tools (``paint-tracks``, ``flow-tracks``, ``sharpness``) and the tracks
file they read: one tagged JSON record per run, written atomically, and never over a file the tool did not write."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from bench.tracking import Tracks, load_tracks
from engine.errors import InputError
from engine.io.atomic import atomic_write_text

#: Every report carries {"neural_atlas_bench_report": REPORT_VERSION, "tool": name, ...}.
REPORT_TAG = "neural_atlas_bench_report"
REPORT_VERSION = 1


def _report_tool(path: Path) -> str | None:
    """The tool that wrote ``path`` (None: not a report of ours, or unreadable)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if isinstance(data, dict) and data.get(REPORT_TAG) == REPORT_VERSION:
        tool = data.get("tool")
        return tool if isinstance(tool, str) else None
    return None


def write_report(path: str | Path, tool: str, record: dict[str, Any]) -> Path:
    """Write ``record`` as ``tool``'s report at ``path``. A file already there is replaced only when it is an earlier
    report of the same tool: anything else the user made stays as it is (a one-line input error)."""
    out = Path(path).expanduser()
    if out.is_dir():
        raise InputError(out, "is a folder", "give --json a file name, e.g. --json scores.json")
    if out.exists() and _report_tool(out) != tool:
        raise InputError(out, f"exists and is not a {tool} report", "choose another --json file (nothing was written)")
    body = {REPORT_TAG: REPORT_VERSION, "tool": tool, **record}
    atomic_write_text(out, json.dumps(body, indent=1, allow_nan=False))
    return out


def read_tracks(path: str | Path) -> Tracks:
    """``load_tracks`` with a missing or foreign file as one line naming it."""
    src = Path(path).expanduser()
    if not src.is_file():
        raise InputError(src, "tracks file does not exist", "pass a tracks_tapvid.npz (TAP-Vid layout) with --tracks")
    try:
        return load_tracks(src)
    except (OSError, KeyError, ValueError) as exc:
        problem = f"is not a TAP-Vid tracks file ({' '.join(str(exc).split())[:80]})"
        raise InputError(src, problem, "pass a tracks_tapvid.npz with tracks_xy, occluded, query_points_txy") from None


def to_plate_scale(tracks: Tracks, size: tuple[int, int]) -> np.ndarray:
    """[2]: multiplies the tracks' pixels into a ``size`` (W, H) image's (1, 1 when the tracks were made on it)."""
    return np.asarray(size, np.float64) / np.asarray(tracks.image_size, np.float64)


__all__ = ["REPORT_TAG", "REPORT_VERSION", "read_tracks", "to_plate_scale", "write_report"]
