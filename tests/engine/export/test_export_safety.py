"""What export (and the verbs that write into an export's run folder) do when another process holds the run folder,
when the run folder moves, when the disk fills up and when they are cancelled: one line, and nothing of the artist's
changed. Real child processes (``python -m engine``) where another process is the point."""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from engine import contract as C
from engine.errors import MB
from engine.io.images import write_png
from engine.terms.export_names import EDITS_DIR
from engine.terms.lock import RUN_LOCKED_FIX
from tests.engine.export.tiny_run import copy_root, export, fail_exr_writes_after, make_run
from tests.engine_cli import run_cli
from tests.folders import hold_lock, tree_digest
from tests.paths import ROOT

#: An atlas this large makes the export spend seconds on its atlases (a window to cancel it in) and write
#: megabytes (a size the disk-full message can be checked against).
BIG_ATLAS = 1024


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A tiny fitted run with one export, under ``root`` (``root/clip``, ``root/run``)."""
    root = tmp_path_factory.mktemp("export_safety") / "root"
    make_run(root)
    export(root / "run")
    return root


@pytest.fixture
def root(base, tmp_path):
    """A private copy of the base root (the tests change it)."""
    return copy_root(base, tmp_path / "root")


def _engine(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "engine", *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout
    )


def _lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


def _manifest(root: Path, version: str = "v001") -> Path:
    return root / "run" / C.EXPORTS_DIR / version / C.MANIFEST_NAME


def _paint(root: Path) -> Path:
    paint = np.zeros((32, 48, 4), np.float32)
    paint[8:20, 12:28] = (0.9, 0.1, 0.1, 1.0)
    return write_png(root / "paint.png", paint, 8)


@pytest.mark.slow
def test_writers_refuse_a_run_folder_another_process_holds(root):
    """A fit (here a child holding the lock as `fit`) owns the run folder: export (a real second process),
    project-frame and preview into the export are refused in one line naming the holder, exit 2, and change
    nothing; once the holder is gone they work."""
    run = root / "run"
    before = tree_digest(run)
    holder = hold_lock(run)
    try:
        out = _engine("export", str(run), "--atlas-size", "32", "--no-bar")
        lines = _lines(out.stderr)
        assert out.returncode == C.EXIT_BAD_INPUT and len(lines) == 1, out.stderr
        assert f"in use by fit (pid {holder.pid} on " in lines[0] and RUN_LOCKED_FIX in lines[0], lines[0]
        for argv in (
            ["project-frame", str(_manifest(root)), "--frame", "1", "--edit", str(_paint(root))],
            ["preview", str(_manifest(root)), "--no-movies"],
        ):
            code, lines = run_cli(*argv)
            assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and f"pid {holder.pid}" in lines[0], (argv, lines)
        assert tree_digest(run) == before
    finally:
        holder.kill()
        holder.wait()
    assert _engine("export", str(run), "--atlas-size", "32", "--no-bar").returncode == C.EXIT_OK
    assert (run / C.EXPORTS_DIR / "v002" / C.MANIFEST_NAME).exists()


def test_a_run_folder_moved_with_its_plate_renders_identically(root, tmp_path):
    """The manifest records every path relative to itself: the run folder and its plate copied to another root,
    the original gone, render gives the same bytes, and project-frame lands in the moved run's edit layers."""
    data = json.loads(_manifest(root).read_text())
    recorded = [data["run_dir"], data["clip"]["source"], *data["clip"]["frame_files"], *data["clip"]["masks"]]
    recorded += [layer["edit_layer"] for layer in data["layers"]]
    assert not [p for p in recorded if os.path.isabs(p)], recorded
    assert _engine("render", str(_manifest(root)), "--out", str(tmp_path / "before"), "--no-bar").returncode == 0

    moved = tmp_path / "elsewhere" / "shot"
    moved.parent.mkdir()
    shutil.move(root, moved)
    out = _engine("render", str(_manifest(moved)), "--out", str(tmp_path / "after"), "--no-bar")
    assert out.returncode == C.EXIT_OK, out.stderr
    assert tree_digest(tmp_path / "after") == tree_digest(tmp_path / "before") != {}
    code, lines = run_cli("project-frame", str(_manifest(moved)), "--frame", "1", "--edit", str(_paint(moved)))
    assert code == C.EXIT_OK and all(str(moved / "run" / EDITS_DIR) in line for line in lines[:1]), lines


@pytest.mark.slow
def test_sigterm_during_export_exits_3_and_leaves_nothing(root):
    """SIGTERM while a real export computes its atlases: exit 3, one line, no staging, the earlier export and the
    edit layers byte-identical; the same command again finishes."""
    run = root / "run"
    exports, edits = run / C.EXPORTS_DIR, run / EDITS_DIR
    before = (tree_digest(exports), tree_digest(edits))
    argv = [sys.executable, "-m", "engine", "export", str(run), "--atlas-size", str(BIG_ATLAS), "--no-bar"]
    proc = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None and not list(exports.glob(".v002*")):
        time.sleep(0.01)
    assert list(exports.glob(".v002*")), "the export never started staging"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == C.EXIT_CANCELLED, err
    lines = _lines(err)
    assert len(lines) == 1 and lines[0].startswith("cancelled: export stopped by SIGTERM"), err
    assert sorted(p.name for p in exports.iterdir()) == ["v001"]
    assert (tree_digest(exports), tree_digest(edits)) == before
    again = _engine("export", str(run), "--atlas-size", "32", "--no-bar")
    assert again.returncode == C.EXIT_OK and (exports / "v002" / C.MANIFEST_NAME).exists(), again.stderr


def _fill_disk_after(monkeypatch, writes: int) -> None:
    """The export's EXR writer fails with ENOSPC once ``writes`` files were written, and the disk has 0 bytes free:
    the message's N MB is then everything the export needs."""
    import engine.io.atomic as atomic

    fail_exr_writes_after(monkeypatch, writes)
    monkeypatch.setattr(atomic, "free_bytes", lambda folder: 0)


@pytest.mark.slow
def test_disk_full_during_export_is_one_line_naming_what_it_needs(root, monkeypatch):
    """ENOSPC on the export's fourth EXR (two atlases and a pass written): exit 2, one line "disk full: free N MB
    at RUN_DIR", N within a factor 2 of what the whole export takes; no staging, earlier export and edit layers
    byte-identical."""
    run = root / "run"
    whole = export(run, atlas_size=BIG_ATLAS).parent
    size = sum(p.stat().st_size for p in whole.rglob("*") if p.is_file())
    shutil.rmtree(whole)
    before = (tree_digest(run / C.EXPORTS_DIR), tree_digest(run / EDITS_DIR))
    _fill_disk_after(monkeypatch, 3)
    code, lines = run_cli("export", str(run), "--atlas-size", str(BIG_ATLAS), "--no-bar")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1, lines
    assert lines[0].startswith("error: disk full: free ") and f" MB at {run} — " in lines[0], lines[0]
    free_mb = int(lines[0].split("free ")[1].split(" MB")[0])
    print(f"\nexport needs {size / MB:.2f} MB; the message says free {free_mb} MB")
    assert math.ceil(size / 2 / MB) <= free_mb <= math.ceil(2 * size / MB), (size, free_mb)
    assert (tree_digest(run / C.EXPORTS_DIR), tree_digest(run / EDITS_DIR)) == before
    assert not [p for p in (run / C.EXPORTS_DIR).iterdir() if p.name.startswith(".")]


def test_disk_full_during_a_first_export_removes_what_it_created(tmp_path, monkeypatch):
    """A run's first export fails on a full disk: no exports/ folder, no edit layers, nothing partial."""
    _, _, run = make_run(tmp_path)
    _fill_disk_after(monkeypatch, 2)
    code, lines = run_cli("export", str(run), "--atlas-size", "32", "--no-bar")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and "disk full" in lines[0], lines
    assert not (run / C.EXPORTS_DIR).exists() and not (run / EDITS_DIR).exists()
