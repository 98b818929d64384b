"""README command 1's job: the embedded demo runs with nothing but the repository, and is idempotent."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.paths import ROOT

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
    # step 6: the .blend built by the add-on, rendered by Blender's compositor, equals the engine's render
    blend, blender_dir = tmp_path / "demo.blend", tmp_path / "blender"
    compare = json.loads((tmp_path / "blender_compare.json").read_text())
    assert blend.stat().st_size > 50_000 and compare["frames"] == 24
    assert "Blender" in first.stderr and "max abs error" in first.stderr
    from engine.edit.equations import load_edit
    from engine.edit.render import render_frames
    from engine.export.manifest import Manifest
    from engine.io.images import read_image

    m = Manifest(manifest)
    edits = [load_edit(tmp_path / "example_edits" / f"{layer['name']}.png") for layer in m.layers]
    errors = []
    for number, frame in render_frames(m, edits, [0, 11, 23], filter=compare["engine_filter"]):
        pixels, _ = read_image(blender_dir / f"edit.{number:05d}.exr")
        errors.append(float(np.abs(pixels[..., :3] - frame).max()))
        assert np.abs(pixels[..., :3] - frame).mean() < 1e-5  # every pixel: the decode differs everywhere
    print(f"demo: Blender {compare['blender']} vs engine render, {compare['engine_filter']}: {max(errors):.2e}")
    # 8-bit sRGB plate and edits: decoded by the same OCIO transform on both sides (0 with Nearest, docs/colour.md)
    assert max(errors) <= 1e-5 and abs(max(errors) - compare["max_abs_error"]) <= max(errors)
    stamps = {
        p: p.stat().st_mtime_ns
        for p in (tmp_path / "run" / "checkpoint.pt", manifest, edited[-1], blend, blender_dir / "edit.00023.exr")
    }
    frame0 = (tmp_path / "clip" / "frames" / "00000.png").stat().st_mtime_ns

    second = _demo(tmp_path)
    assert second.returncode == 0, second.stderr
    assert "already done" in second.stderr and "already rendered" in second.stderr
    assert "Blender render already done" in second.stderr
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps
    assert not (tmp_path / "run" / "exports" / "v002").exists()
    assert (tmp_path / "clip" / "frames" / "00000.png").stat().st_mtime_ns == frame0


def test_demo_without_blender_says_so(monkeypatch):
    """No bpy module and no `blender` binary: step 6 is skipped with a message, not a failure."""
    import importlib.util
    import shutil

    from engine import demo

    monkeypatch.delenv(demo.BLENDER_ENV, raising=False)
    monkeypatch.setattr(importlib.util, "find_spec", lambda name: None)
    monkeypatch.setattr(shutil, "which", lambda name: None)
    assert demo.blender_command() is None
    assert demo.blender_render(Path("m.json"), {}, Path("x.blend"), Path("r"), Path("r.json")) is None
    monkeypatch.setenv(demo.BLENDER_ENV, "/opt/blender-4.5/blender")
    argv, _ = demo.blender_command()
    assert argv[:3] == ["/opt/blender-4.5/blender", "-b", "--factory-startup"] and argv[-1] == "--"
    monkeypatch.setenv(demo.BLENDER_ENV, "/venvs/bpy5/bin/python")
    argv, _ = demo.blender_command()
    assert argv == ["/venvs/bpy5/bin/python", str(demo.HEADLESS_SCRIPT), "--"]
