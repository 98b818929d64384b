"""The command line as a user and the add-on meet it: help, one-line errors with exit code 2,
cancel with a checkpoint (SIGTERM) and resume to the same end, and refusal to overwrite a fit."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import pytest

from engine import contract as C
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.terms.protocol import EVENT_CANCELLED
from tests.paths import ROOT

SMALL = SceneSpec(width=96, height=64, frames=6, fg_size=(28, 20), fg_start=(20.0, 20.0))


#: The limit of a long engine run in these tests: a hang guard, far above what a loaded machine needs.
RESUME_HANG_S = 1800


def run_engine(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "engine", *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout
    )


@pytest.fixture(scope="module")
def small_clip(tmp_path_factory):
    return write_scene(make_scene(SMALL), tmp_path_factory.mktemp("clip"))


def test_help_reads_well():
    out = run_engine("fit", "--help")
    assert out.returncode == 0
    for word in ("--mask", "--preset", "draft", "balanced", "final", "paper", "--resume", "--set", "exit codes"):
        assert word in out.stdout
    assert run_engine("--version").stdout.startswith("neural-atlas engine")


def _one_line_error(out: subprocess.CompletedProcess, *needles: str) -> None:
    assert out.returncode == C.EXIT_BAD_INPUT, out.stderr
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), out.stderr
    for n in needles:
        assert n in lines[0]


def test_missing_clip_is_one_line_naming_it(tmp_path):
    missing = tmp_path / "no_such_frames"
    _one_line_error(run_engine("fit", str(missing), "--out", str(tmp_path / "run")), "no_such_frames")
    assert not (tmp_path / "run").exists()


@pytest.mark.slow
def test_unknown_preset_and_key_suggest(tmp_path, small_clip):
    frames, masks = small_clip
    out = run_engine("fit", str(frames), "--mask", str(masks), "--out", str(tmp_path / "r"), "--preset", "drat")
    _one_line_error(out, "did you mean 'draft'")
    out = run_engine("fit", str(frames), "--out", str(tmp_path / "r"), "--set", "batchsize=3")
    _one_line_error(out, "did you mean 'batch'")


def _fit_args(frames, masks, run, *extra):
    return [
        "fit",
        str(frames),
        "--mask",
        str(masks),
        "--out",
        str(run),
        "--preset",
        "draft",
        "--no-bar",
        "--set",
        "batch=500",
        "--set",
        "eval_every=5",
        "--set",
        "bootstrap_steps=20",
        "--set",
        "global_rigidity_steps=10",
        *extra,
    ]


@pytest.mark.slow
def test_sigterm_checkpoints_and_resume_finishes(tmp_path, small_clip):
    frames, masks = small_clip
    run = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "engine", *_fit_args(frames, masks, run, "--set", "steps=400")],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    events = []
    for line in proc.stdout:
        msg = C.parse_progress_line(line)
        if msg:
            events.append(msg)
            if msg["event"] == C.EVENT_PROGRESS and msg["step"] >= 20:
                os.kill(proc.pid, signal.SIGTERM)
                break
    rest = proc.stdout.read()
    proc.wait(timeout=120)
    events += [m for m in map(C.parse_progress_line, rest.splitlines()) if m]
    assert proc.returncode == C.EXIT_CANCELLED, proc.stderr.read()
    cancelled = [e for e in events if e["event"] == EVENT_CANCELLED]
    assert cancelled and (run / C.RUN_CHECKPOINT).exists()
    stopped_at = cancelled[0]["step"]
    assert 20 <= stopped_at < 400
    progress = [e for e in events if e["event"] == C.EVENT_PROGRESS]
    assert all({"step", "total", "psnr", "elapsed", "eta", "losses"} <= set(e) for e in progress)

    # a second fit into the same folder without --resume is refused, and the checkpoint is untouched
    before = (run / C.RUN_CHECKPOINT).read_bytes()
    _one_line_error(run_engine(*_fit_args(frames, masks, run, "--set", "steps=400")), "--resume")
    assert (run / C.RUN_CHECKPOINT).read_bytes() == before

    # the rest of the 400 steps: about 40 s on an idle 2-core machine, 7.5 min at a load average of 13; the limit
    # only guards against a hang, so it is sized for the loaded machine
    out = run_engine("fit", "--resume", "--out", str(run), "--no-bar", timeout=RESUME_HANG_S)
    assert out.returncode == 0, out.stderr
    steps = [m["step"] for m in map(C.parse_progress_line, out.stdout.splitlines()) if m and m["event"] == "progress"]
    assert steps and steps[0] > stopped_at and steps[-1] == 400
    metrics = json.loads((run / C.RUN_METRICS).read_text())
    assert metrics["steps"] == 400 and metrics["psnr"] > 20.0


@pytest.mark.slow
def test_resume_refuses_a_changed_clip(tmp_path):
    clip = tmp_path / "clip"
    frames, masks = write_scene(make_scene(SMALL), clip)
    run = tmp_path / "run"
    assert run_engine(*_fit_args(frames, masks, run, "--set", "steps=10")).returncode == 0
    changed = make_scene(SceneSpec(**{**SMALL.__dict__, "seed": 5}))
    write_scene(changed, clip)
    _one_line_error(run_engine("fit", "--resume", "--out", str(run)), "changed")
