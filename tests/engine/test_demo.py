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


def test_demo_fits_then_reuses(tmp_path):
    first = _demo(tmp_path)
    assert first.returncode == 0, first.stderr
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["steps"] == 150 and metrics["psnr"] > 21.0
    sheet = tmp_path / "contact_sheet.png"
    assert sheet.stat().st_size > 10_000
    assert "look: " in first.stderr.splitlines()[-1]
    ckpt = (tmp_path / "run" / "checkpoint.pt").stat().st_mtime_ns
    frame0 = (tmp_path / "clip" / "frames" / "00000.png").stat().st_mtime_ns

    second = _demo(tmp_path)
    assert second.returncode == 0, second.stderr
    assert "already done" in second.stderr
    assert (tmp_path / "run" / "checkpoint.pt").stat().st_mtime_ns == ckpt
    assert (tmp_path / "clip" / "frames" / "00000.png").stat().st_mtime_ns == frame0
