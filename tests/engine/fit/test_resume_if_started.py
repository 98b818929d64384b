"""``fit ... --resume-if-started``: a farm retries a fit task with the very same arguments. The first run starts the
fit; stopped by SIGTERM (exit 3, a checkpoint), the same command continues it from the checkpoint's step (not step
0) to the end; once finished, the same command does nothing and exits 0 at once; a different fit's arguments are one
line. Real ``python -m engine`` processes."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from engine import contract as C
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.fit import run_files, trainer
from engine.terms.cli import FIT_RESUME_IF_STARTED_FLAG
from engine.terms.protocol import EVENT_CANCELLED
from tests.engine_cli import progress_until, run_cli, start_engine
from tests.folders import tree_digest
from tests.paths import ROOT

SPEC = SceneSpec(width=48, height=32, frames=4, fg_size=(16, 12), fg_start=(10.0, 8.0))
#: Long enough that the child is still mid-fit when the signal lands (see tests/stability/test_faults.py).
STEPS = 150
SETS = [f"steps={STEPS}", "batch=256", "eval_every=1", "eval_pixels=500", "bootstrap_steps=20",
        "global_rigidity_steps=10", "checkpoint_seconds=0.2"]  # fmt: skip


def _argv(frames: Path, masks: Path, run: Path, *extra: str) -> list[str]:
    sets = [a for s in SETS for a in ("--set", s)]
    return ["fit", str(frames), "--mask", str(masks), "--out", str(run), "--preset", "draft", "--no-bar", *sets,
            FIT_RESUME_IF_STARTED_FLAG, *extra]  # fmt: skip


def _events(text: str) -> list[dict]:
    return [m for m in map(C.parse_progress_line, text.splitlines()) if m]


def _no_fit(*args: object, **kwargs: object) -> None:
    raise AssertionError("a finished fit was trained again")


@pytest.mark.slow
def test_a_retried_fit_starts_continues_and_then_does_nothing(tmp_path, monkeypatch):
    frames, masks = write_scene(make_scene(SPEC), tmp_path / "clip")
    run = tmp_path / "run"
    argv = _argv(frames, masks, run)

    # 1. it starts; the farm preempts it mid-fit
    proc = start_engine(argv)
    events = progress_until(proc, lambda ev: ev[-1]["event"] == C.EVENT_PROGRESS and ev[-1]["step"] >= 5)
    proc.send_signal(signal.SIGTERM)
    rest, err = proc.communicate(timeout=300)
    events += _events(rest)
    assert proc.returncode == C.EXIT_CANCELLED, err
    assert min(e["step"] for e in events if e["event"] == C.EVENT_PROGRESS) == 1  # a new fit, from step 0
    stopped = [e["step"] for e in events if e["event"] == EVENT_CANCELLED]
    assert len(stopped) == 1 and 5 <= stopped[0] < STEPS
    saved = torch.load(run / C.RUN_CHECKPOINT, map_location="cpu", weights_only=True)["step"]
    assert saved == stopped[0] and not (run / C.RUN_METRICS).exists()

    # 2. the same command continues it from the checkpoint's step to the end
    out = subprocess.run([sys.executable, "-m", "engine", *argv], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert out.returncode == C.EXIT_OK, out.stderr
    resumed = [e["step"] for e in _events(out.stdout) if e["event"] == C.EVENT_PROGRESS]
    assert resumed[0] == saved + 1 and resumed[-1] == STEPS
    metrics = run_files.validate_run_file(C.RUN_METRICS, json.loads((run / C.RUN_METRICS).read_text()))
    assert metrics["steps"] == STEPS

    # 3. the same command once more: nothing to do, at once (no training starts: how fast that is depends on the
    # machine's load), nothing changed
    before = tree_digest(run)
    with monkeypatch.context() as m:
        m.setattr(trainer, "fit", _no_fit)
        code, lines = run_cli(*argv)
    assert code == C.EXIT_OK and len(lines) == 1 and lines[0].startswith("already fitted"), lines
    assert tree_digest(run) == before

    # another fit's arguments are one line, and change nothing
    for extra in (("--set", "w_rgb=7"), ("--frames", "1-3")):
        code, lines = run_cli(*argv, *extra)
        assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and lines[0].startswith("error: "), (extra, lines)
    code, lines = run_cli(*[a if a != "draft" else "balanced" for a in argv])
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and "preset" in lines[0], lines
    code, lines = run_cli(*argv, "--resume")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and FIT_RESUME_IF_STARTED_FLAG in lines[0], lines
    assert tree_digest(run) == before
