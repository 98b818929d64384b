"""README command 1's job: the embedded demo runs with nothing but the repository, and is idempotent."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow


def _demo(out: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "engine", "demo", "--out", str(out), "--set", "steps=150", "--set", "eval_every=50"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_demo_fits_exports_edits_renders_then_reuses(tmp_path):
    first = _demo(tmp_path)
    assert first.returncode == 0, first.stderr
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["steps"] == 150 and metrics["psnr"] > 21.0
    sheet = tmp_path / "contact_sheet.png"
    assert sheet.stat().st_size > 10_000 and (tmp_path / "fit_sheet.png").stat().st_size > 10_000
    assert "look: " in first.stderr.splitlines()[-1]
    manifest = tmp_path / "run" / "exports" / "v001" / "manifest.json"
    assert manifest.exists() and (manifest.parent / "preview" / "checkerboard.mp4").exists()
    edited = sorted((tmp_path / "edited").glob("edit.*.png"))
    assert len(edited) == 24 and (tmp_path / "edited.mp4").stat().st_size > 1000
    # the example edit changed the picture; the run's own edit layers (the artist's) stay empty
    import cv2
    import numpy as np

    plate = cv2.imread(str(tmp_path / "clip" / "frames" / "00005.png")).astype(float)
    frame = cv2.imread(str(tmp_path / "edited" / "edit.00005.png")).astype(float)
    assert np.abs(frame - plate).mean() > 5.0
    for layer in ("Background", "Foreground"):
        own = cv2.imread(str(tmp_path / "run" / "edits" / f"{layer}.png"), cv2.IMREAD_UNCHANGED)
        assert own.shape[2] == 4 and own.max() == 0
    stamps = {p: p.stat().st_mtime_ns for p in (tmp_path / "run" / "checkpoint.pt", manifest, edited[-1])}
    frame0 = (tmp_path / "clip" / "frames" / "00000.png").stat().st_mtime_ns

    second = _demo(tmp_path)
    assert second.returncode == 0, second.stderr
    assert "already done" in second.stderr and "already rendered" in second.stderr
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps
    assert not (tmp_path / "run" / "exports" / "v002").exists()
    assert (tmp_path / "clip" / "frames" / "00000.png").stat().st_mtime_ns == frame0
