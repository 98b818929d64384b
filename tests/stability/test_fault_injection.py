"""Fault injection: real ``python -m engine`` processes killed with SIGKILL at random points of a fit, an export,
a render and a project-frame, on a run that holds an export and painted edit layers.

SIGKILL gives the process no chance to clean up, so this is what a crash, an out-of-memory kill or a pulled
plug leaves. After every kill the test asserts what the robustness promise says (docs/robustness.md):

- the run folder loads (config, clip record, the checkpoint when there is one);
- the earlier export and every edit layer are byte-identical to before (SHA-256), and any export or rendered
  frame that is visible is complete;
- ``fit --resume`` (or the same command again) finishes, and its results equal an uninterrupted run's.

The kill time of each run is drawn from a seeded generator over the measured duration of the command, so a
failure is reproducible by its seed. ``NEURAL_ATLAS_FAULT_SEEDS`` (default 3) sets the number of kills per
command; docs/robustness.md gives the figures of a larger run.
"""

from __future__ import annotations

import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from engine import contract as C
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.edit.render_record import RECORD_NAME
from engine.export.manifest import Manifest
from engine.fit.run_folder import RunFolder
from engine.io.images import read_exr, read_image, write_png
from engine.terms.export_names import EDITS_DIR
from tests.engine_cli import run_cli
from tests.folders import tree_digest
from tests.paths import ROOT

SPEC = SceneSpec(width=48, height=32, frames=4, fg_size=(16, 12), fg_start=(10.0, 8.0))
STEPS = 80
FIT_SETS = [
    f"steps={STEPS}",
    "batch=256",
    "eval_every=10",
    "eval_pixels=500",
    "bootstrap_steps=20",
    "global_rigidity_steps=10",
    "checkpoint_seconds=0.2",
]
SEEDS = int(os.environ.get("NEURAL_ATLAS_FAULT_SEEDS", "3"))
#: Paint made on plate frame 1: an opaque square (compositing it twice gives the same layer, so a re-run after a
#: kill that landed after the write converges to the same result).
PAINT_BOX = (slice(8, 20), slice(12, 28))


def _sets(extra: list[str] | None = None) -> list[str]:
    return [a for s in [*FIT_SETS, *(extra or [])] for a in ("--set", s)]


def _engine(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "engine", *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout
    )


def _kill_after(args: list[str], delay: float) -> int:
    """Start ``python -m engine *args``, SIGKILL it after ``delay`` seconds (unless it ended); its return code."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "engine", *args], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        proc.wait(timeout=delay)
    except subprocess.TimeoutExpired:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    return proc.returncode


def _timed(args: list[str]) -> float:
    t0 = time.perf_counter()
    out = _engine(*args)
    assert out.returncode == C.EXIT_OK, out.stderr
    return time.perf_counter() - t0


class Base:
    """A fitted, exported and painted run, the paint made on a frame, and the reference results."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.frames, self.masks = write_scene(make_scene(SPEC), root / "clip")
        self.run = root / "run"
        fit_args = [str(self.frames), "--mask", str(self.masks), "--out", str(self.run), "--preset", "draft"]
        assert run_cli("fit", *fit_args, "--no-bar", *_sets())[0] == C.EXIT_OK
        assert run_cli("export", str(self.run), "--atlas-size", "64", "--no-bar")[0] == C.EXIT_OK
        self.manifest = self.run / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME
        # the artist's paint on the background layer's edit layer
        m = Manifest(self.manifest)
        edit = m.edit_path(m.layers[0])
        pixels, _ = read_image(edit)
        pixels = pixels.astype(np.float32) / 255.0 if pixels.dtype == np.uint8 else pixels.astype(np.float32)
        pixels[4:12, 4:12] = (0.2, 0.9, 0.1, 1.0)
        write_png(edit, pixels, 8)
        paint = np.zeros((SPEC.height, SPEC.width, 4), np.float32)
        paint[PAINT_BOX] = (0.9, 0.1, 0.1, 1.0)
        self.paint = root / "paint.png"
        write_png(self.paint, paint, 8)


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return Base(tmp_path_factory.mktemp("faults_base"))


def _copy_run(base: Base, dest: Path) -> Path:
    shutil.copytree(base.run, dest)
    return dest


def _manifest_of(run: Path) -> Path:
    return run / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME


def _assert_run_loads(run: Path) -> None:
    folder = RunFolder(run)
    folder.read_config()
    folder.read_clip()
    if folder.checkpoint.exists():
        import torch

        folder.load_checkpoint(torch.device("cpu"))


def _assert_exports_complete(run: Path) -> None:
    """Every visible export is whole: its manifest loads and every frame's pass file is there and readable."""
    for export in sorted((run / C.EXPORTS_DIR).iterdir()):
        if export.name.startswith("."):
            continue
        m = Manifest(export / C.MANIFEST_NAME)
        for frame in m.frames:
            read_exr(m.pass_path(frame))


def _startup_seconds() -> float:
    """Seconds a child takes to import the engine and torch: kills are drawn after most of it, on the work."""
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-c", "import engine.fit.trainer, engine.export.exporter, engine.edit.render"],
        cwd=ROOT,
        check=True,
    )
    return time.perf_counter() - t0


STARTUP: list[float] = []


def _delays(name: str, duration: float) -> list[float]:
    """``SEEDS`` kill times for a command that takes ``duration`` seconds, from its name's seeded generator:
    uniform from 80% of the import time to the end."""
    if not STARTUP:
        STARTUP.append(_startup_seconds())
    start = min(0.8 * STARTUP[0], 0.5 * duration)
    rng = random.Random(f"{name}-{SEEDS}")
    return [rng.uniform(start, duration) for _ in range(SEEDS)]


@pytest.mark.slow
def test_sigkill_during_a_fit_then_resume_or_rerun_finishes(base, tmp_path):
    def args(run: Path) -> list[str]:
        return ["fit", str(base.frames), "--mask", str(base.masks), "--out", str(run), "--preset", "draft"]

    duration = _timed([*args(tmp_path / "timed"), "--no-bar", *_sets()])
    for i, delay in enumerate(_delays("fit", duration)):
        run = tmp_path / f"run{i}"
        _kill_after([*args(run), "--no-bar", *_sets()], delay)
        if RunFolder(run).checkpoint.exists():
            _assert_run_loads(run)
            out = _engine("fit", "--resume", "--out", str(run), "--no-bar")
        else:  # killed before its first checkpoint: the same command starts over
            out = _engine(*args(run), "--no-bar", *_sets())
        assert out.returncode == C.EXIT_OK, (delay, out.stderr)
        metrics = RunFolder(run).read_metrics()
        assert metrics is not None and metrics["steps"] == STEPS, delay
        _assert_run_loads(run)


@pytest.mark.slow
def test_sigkill_while_continuing_a_painted_run_keeps_exports_and_edits(base, tmp_path):
    probe = _copy_run(base, tmp_path / "timed")
    longer = _sets([f"steps={STEPS + 60}"])
    duration = _timed(["fit", "--resume", "--out", str(probe), "--no-bar", *longer])
    for i, delay in enumerate(_delays("resume", duration)):
        run = _copy_run(base, tmp_path / f"run{i}")
        exports, edits = tree_digest(run / C.EXPORTS_DIR), tree_digest(run / EDITS_DIR)
        _kill_after(["fit", "--resume", "--out", str(run), "--no-bar", *longer], delay)
        _assert_run_loads(run)
        assert tree_digest(run / C.EXPORTS_DIR) == exports and tree_digest(run / EDITS_DIR) == edits, delay
        out = _engine("fit", "--resume", "--out", str(run), "--no-bar", *longer)
        assert out.returncode == C.EXIT_OK, (delay, out.stderr)
        assert tree_digest(run / C.EXPORTS_DIR) == exports and tree_digest(run / EDITS_DIR) == edits, delay


@pytest.mark.slow
def test_sigkill_during_an_export_keeps_earlier_exports_and_edits(base, tmp_path):
    probe = _copy_run(base, tmp_path / "timed")
    duration = _timed(["export", str(probe), "--atlas-size", "64", "--no-bar"])
    for i, delay in enumerate(_delays("export", duration)):
        run = _copy_run(base, tmp_path / f"run{i}")
        exports, edits = tree_digest(run / C.EXPORTS_DIR / "v001"), tree_digest(run / EDITS_DIR)
        _kill_after(["export", str(run), "--atlas-size", "64", "--no-bar"], delay)
        _assert_run_loads(run)
        _assert_exports_complete(run)
        assert tree_digest(run / C.EXPORTS_DIR / "v001") == exports and tree_digest(run / EDITS_DIR) == edits, delay
        out = _engine("export", str(run), "--atlas-size", "64", "--no-bar")
        assert out.returncode == C.EXIT_OK, (delay, out.stderr)
        _assert_exports_complete(run)
        assert tree_digest(run / C.EXPORTS_DIR / "v001") == exports and tree_digest(run / EDITS_DIR) == edits, delay


@pytest.mark.slow
def test_sigkill_during_a_render_leaves_whole_frames_and_a_rerun_matches(base, tmp_path):
    reference = tmp_path / "reference"
    duration = _timed(["render", str(base.manifest), "--out", str(reference), "--no-bar"])
    expected = {p.name: read_exr(p) for p in sorted(reference.glob("*.exr"))}
    assert expected
    run_before = tree_digest(base.run)
    for i, delay in enumerate(_delays("render", duration)):
        out_dir = tmp_path / f"render{i}"
        _kill_after(["render", str(base.manifest), "--out", str(out_dir), "--no-bar"], delay)
        for frame in out_dir.glob("[!.]*.exr") if out_dir.exists() else []:
            got = read_exr(frame)  # a visible frame is whole (temp files are hidden: .name.XXXX.tmp.exr)
            assert all(np.array_equal(got[c], expected[frame.name][c]) for c in got), (delay, frame)
        assert tree_digest(base.run) == run_before, delay
        out = _engine("render", str(base.manifest), "--out", str(out_dir), "--no-bar")
        assert out.returncode == C.EXIT_OK, (delay, out.stderr)
        # the re-run clears what the killed render left (hidden temp files, its staging): only the frames and the
        # render's record remain
        assert sorted(p.name for p in out_dir.iterdir()) == sorted([RECORD_NAME, *expected]), delay
        for name, channels in expected.items():
            got = read_exr(out_dir / name)
            assert all(np.array_equal(got[c], channels[c]) for c in channels), (delay, name)


@pytest.mark.slow
def test_sigkill_during_project_frame_keeps_every_edit_layer_whole(base, tmp_path):
    probe = _copy_run(base, tmp_path / "timed")
    args = ["--frame", "1", "--edit", str(base.paint)]
    duration = _timed(["project-frame", str(_manifest_of(probe)), *args])
    painted = {
        name: digest for name, digest in tree_digest(probe / EDITS_DIR).items() if not name.startswith("history")
    }
    for i, delay in enumerate(_delays("project-frame", duration)):
        run = _copy_run(base, tmp_path / f"run{i}")
        before = {n: d for n, d in tree_digest(run / EDITS_DIR).items() if not n.startswith("history")}
        exports = tree_digest(run / C.EXPORTS_DIR)
        _kill_after(["project-frame", str(_manifest_of(run)), *args], delay)
        now = {n: d for n, d in tree_digest(run / EDITS_DIR).items() if not n.startswith("history")}
        for name, digest in now.items():  # each edit layer is the old one or the new one, never a torn file
            assert digest in (before.get(name), painted.get(name)), (delay, name)
        assert tree_digest(run / C.EXPORTS_DIR) == exports, delay
        out = _engine("project-frame", str(_manifest_of(run)), *args)
        assert out.returncode == C.EXIT_OK, (delay, out.stderr)
        after = tree_digest(run / EDITS_DIR)
        if now == before:  # killed before it changed a layer: the re-run is the uninterrupted result
            assert {n: d for n, d in after.items() if not n.startswith("history")} == painted, delay
        history = {d for n, d in after.items() if n.startswith("history")}
        for name, digest in before.items():  # every layer it changed is kept, byte for byte, in history/
            if after[name] != digest:
                assert digest in history, (delay, name)
