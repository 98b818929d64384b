"""Progress protocol: what the engine prints is what the add-on parses."""

from __future__ import annotations

import json

import pytest

from engine import contract as C


def test_progress_line_round_trip():
    line = C.progress_line(C.EVENT_PROGRESS, step=10, total=100, psnr=21.5, elapsed=3.2, eta=28.8, losses={"rgb": 0.1})
    assert "\n" not in line
    msg = C.parse_progress_line(line + "\n")
    assert msg == {
        C.PROGRESS_TAG: C.SCHEMA_VERSION,
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
        json.dumps({C.PROGRESS_TAG: 999, "event": "progress"}),
        json.dumps({C.PROGRESS_TAG: 1, "event": "nope"}),
        "[1, 2]",
    ],
)
def test_foreign_lines_are_ignored(line):
    assert C.parse_progress_line(line) is None


def test_unknown_event_is_refused():
    with pytest.raises(ValueError):
        C.progress_line("exploded")


def test_requirements_are_pinned_where_it_matters():
    reqs = dict(r.split("==", 1) if "==" in r else (r, "") for r in C.ENGINE_REQUIREMENTS)
    assert reqs["torch"] == "2.13.0"
    assert any(r.startswith("numpy") and "<2" in r for r in C.ENGINE_REQUIREMENTS)
    assert any(r.startswith("openimageio==3.0") for r in C.ENGINE_REQUIREMENTS)
