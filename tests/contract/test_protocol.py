"""Progress protocol: what the engine prints is what the add-on parses."""

from __future__ import annotations

import json

import pytest

from engine import contract as C
from engine.terms.protocol import PROGRESS_TAG, progress_line
from engine.terms.versions import SCHEMA_VERSION


def test_progress_line_round_trip():
    line = progress_line(C.EVENT_PROGRESS, step=10, total=100, psnr=21.5, elapsed=3.2, eta=28.8, losses={"rgb": 0.1})
    assert "\n" not in line
    msg = C.parse_progress_line(line + "\n")
    assert msg == {
        PROGRESS_TAG: SCHEMA_VERSION,
        "event": "progress",
        "step": 10,
        "total": 100,
        "psnr": 21.5,
        "elapsed": 3.2,
        "eta": 28.8,
        "losses": {"rgb": 0.1},
    }


@pytest.mark.parametrize(
    "line",
    [
        "",
        "  1%|█  | 10/1000 [00:01<01:40]",
        "{not json",
        json.dumps({"event": "progress"}),
        json.dumps({PROGRESS_TAG: 999, "event": "progress"}),
        json.dumps({PROGRESS_TAG: 1, "event": "nope"}),
        "[1, 2]",
    ],
)
def test_foreign_lines_are_ignored(line):
    assert C.parse_progress_line(line) is None


def test_unknown_event_is_refused():
    with pytest.raises(ValueError):
        progress_line("exploded")


def test_the_constraints_pin_torch_and_the_ranges_keep_numpy_1_and_openimageio_3_0():
    """torch exactly (an unpinned torch pulls a multi-GB CUDA build onto machines without a GPU); numpy 1.x for bpy
    4.5/5.0; OpenImageIO 3.0.x, as 3.1 needs numpy 2. Read from the files the add-on and run.sh install."""
    pins = dict(line.split("==", 1) for line in C.requirement_lines(C.CONSTRAINTS_FILE))
    assert pins["torch"] == "2.13.0"
    assert "numpy>=1.26,<2" in C.ENGINE_REQUIREMENTS
    assert "openimageio>=3.0,<3.1" in C.ENGINE_REQUIREMENTS
    assert C.CONSTRAINTS_PATH.is_file() and C.CONSTRAINTS_PATH.parent.name == "engine"
