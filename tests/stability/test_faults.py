"""Faults during a fit, with a real child process (``python -m engine fit`` as an argv list):

- SIGTERM: the fit writes a checkpoint at the step it stopped, exits with code 3, and ``fit --resume``
  continues from exactly that step (nothing lost);
- SIGKILL (no chance to clean up): the last checkpoint on disk is intact and is the newest one announced
  (at most the ``checkpoint_seconds`` interval of work is lost), and ``fit --resume`` continues from it;
- SIGTERM outside the training loop, while the optical flow is computed or the finished fit is evaluated: exit
  3 and one line, no partial file (the flow cache and every run file are written atomically), and the same
  command (or ``--resume``) then finishes.

In both cases the resumed fit ends where an uninterrupted fit of the same config ends: the checkpoint holds
the model, the optimiser, the schedule and the sampler's random state, so the bound asserted is a
full-frame PSNR within ``SAME_QUALITY_DB`` of the uninterrupted fit (docs/robustness.md has the measurement).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
import torch

from engine import contract as C
from engine.config import apply_overrides, parse_set_args, preset_config
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.fit.fit_inputs import FitInputs
from engine.fit.run_folder import RunFolder
from engine.terms.protocol import EVENT_CANCELLED, EVENT_CHECKPOINT
from tests.engine.fit_helpers import quiet_fit
from tests.engine_cli import progress_until, start_engine
from tests.paths import ROOT

SPEC = SceneSpec(width=48, height=32, frames=4, fg_size=(16, 12), fg_start=(10.0, 8.0))
#: Long enough that the child is still mid-fit when the signal lands, even on a fast idle machine (the
#: kills happen before step STEPS // 2; the rest of the fit takes seconds, the signal milliseconds).
STEPS = 400
SETS = [
    f"steps={STEPS}",
    "batch=256",
    "eval_every=1",  # a progress line every step: the test knows exactly how far the child got
    "eval_pixels=500",
    "bootstrap_steps=20",
    "global_rigidity_steps=10",
    "checkpoint_seconds=0.2",
]
#: The resumed fit's full-frame PSNR is within this of an uninterrupted fit's.
SAME_QUALITY_DB = 0.05


def _args(frames: Path, masks: Path, run: Path) -> list[str]:
    sets = [a for s in SETS for a in ("--set", s)]
    return ["fit", str(frames), "--mask", str(masks), "--out", str(run), "--preset", "draft", "--no-bar", *sets]


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    return write_scene(make_scene(SPEC), tmp_path_factory.mktemp("faults") / "clip")


@pytest.fixture(scope="module")
def uninterrupted(clip, tmp_path_factory):
    frames, masks = clip
    cfg = apply_overrides(preset_config("draft"), parse_set_args(SETS))
    run = tmp_path_factory.mktemp("faults_ref") / "run"
    return quiet_fit(run, cfg, FitInputs(frames, [masks]))


def _resume(run: Path) -> tuple[int, dict, list[dict]]:
    out = subprocess.run(
        [sys.executable, "-m", "engine", "fit", "--resume", "--out", str(run), "--no-bar"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert out.returncode == C.EXIT_OK, out.stderr
    events = [m for m in map(C.parse_progress_line, out.stdout.splitlines()) if m]
    return out.returncode, json.loads((run / C.RUN_METRICS).read_text()), events


def _checkpoint_step(run: Path) -> int:
    return int(torch.load(run / C.RUN_CHECKPOINT, map_location="cpu", weights_only=True)["step"])


def _first_step(events: list[dict]) -> int:
    return min(e["step"] for e in events if e["event"] == C.EVENT_PROGRESS)


@pytest.mark.slow
def test_sigterm_checkpoints_where_it_stops_and_resume_reaches_the_same_quality(tmp_path, clip, uninterrupted):
    frames, masks = clip
    run = tmp_path / "run"
    proc = start_engine(_args(frames, masks, run))
    events = progress_until(proc, lambda ev: ev[-1]["event"] == C.EVENT_PROGRESS and ev[-1]["step"] >= 10)
    proc.send_signal(signal.SIGTERM)
    rest, err = proc.communicate(timeout=300)
    events += [m for m in map(C.parse_progress_line, rest.splitlines()) if m]
    assert proc.returncode == C.EXIT_CANCELLED, err
    cancelled = [e for e in events if e["event"] == EVENT_CANCELLED]
    assert len(cancelled) == 1 and 10 <= cancelled[0]["step"] < STEPS
    stopped = cancelled[0]["step"]
    last_done = max(e["step"] for e in events if e["event"] == C.EVENT_PROGRESS)
    assert _checkpoint_step(run) == stopped == last_done  # nothing lost

    _, metrics, resumed = _resume(run)
    print(f"\nSIGTERM at step {stopped}: resumed PSNR {metrics['psnr']!r}, uninterrupted {uninterrupted['psnr']!r}")
    assert _first_step(resumed) == stopped + 1
    assert metrics["steps"] == STEPS
    assert abs(metrics["psnr"] - uninterrupted["psnr"]) <= SAME_QUALITY_DB, (metrics["psnr"], uninterrupted["psnr"])


@pytest.mark.slow
def test_sigkill_loses_at_most_the_checkpoint_interval_and_resume_reaches_the_same_quality(
    tmp_path, clip, uninterrupted
):
    frames, masks = clip
    run = tmp_path / "run"
    proc = start_engine(_args(frames, masks, run))
    # wait for a periodic checkpoint (every checkpoint_seconds) and a few more steps, then kill without warning
    events = progress_until(
        proc,
        lambda ev: (
            (
                any(e["event"] == EVENT_CHECKPOINT for e in ev)
                and ev[-1]["event"] == C.EVENT_PROGRESS
                and ev[-1]["step"] >= [e["step"] for e in ev if e["event"] == EVENT_CHECKPOINT][-1] + 2
            )
            or ev[-1].get("step", 0) > STEPS // 2
        ),  # no periodic checkpoint by half-way: fail below, do not hang
    )
    assert events[-1]["step"] <= STEPS // 2, "no periodic checkpoint in the first half of the fit"
    os.kill(proc.pid, signal.SIGKILL)
    rest, _ = proc.communicate(timeout=60)  # whatever the child wrote before it died
    events += [m for m in map(C.parse_progress_line, rest.splitlines()) if m]
    assert proc.returncode == -signal.SIGKILL
    announced = [e["step"] for e in events if e["event"] == EVENT_CHECKPOINT][-1]
    reached = max(e["step"] for e in events if e["event"] == C.EVENT_PROGRESS)
    on_disk = _checkpoint_step(run)  # loads: the atomic write never leaves a torn checkpoint
    # the checkpoint on disk is the newest one announced (or a newer one the kill stopped it announcing):
    # the steps lost, reached - on_disk, are those since the last periodic checkpoint
    assert announced <= on_disk <= reached < STEPS
    assert not (run / C.RUN_METRICS).exists()

    _, metrics, resumed = _resume(run)
    print(
        f"\nSIGKILL at step {reached}, checkpoint {on_disk}: resumed PSNR {metrics['psnr']!r}, "
        f"uninterrupted {uninterrupted['psnr']!r}"
    )
    assert _first_step(resumed) == on_disk + 1
    assert metrics["steps"] == STEPS
    assert abs(metrics["psnr"] - uninterrupted["psnr"]) <= SAME_QUALITY_DB, (metrics["psnr"], uninterrupted["psnr"])


#: A clip whose optical flow takes a few seconds (DIS at 640x360, 23 pairs both ways: about 2.5 s on a 2-core
#: CPU), so a SIGTERM lands while it is computed.
FLOW_SPEC = SceneSpec(width=640, height=360, frames=24, fg_size=(120, 90), fg_start=(100.0, 80.0))
#: A clip whose full-frame evaluation takes a few seconds after a 2-step fit.
EVAL_SPEC = SceneSpec(width=256, height=144, frames=24, fg_size=(48, 36), fg_start=(40.0, 30.0))
QUICK_SETS = ["steps=2", "batch=256", "eval_pixels=500"]


def _quick_args(frames: Path, masks: Path, run: Path) -> list[str]:
    sets = [a for s in QUICK_SETS for a in ("--set", s)]
    return ["fit", str(frames), "--mask", str(masks), "--out", str(run), "--preset", "draft", "--no-bar", *sets]


def _at_stage(stage: str) -> Callable[[list[dict]], bool]:
    return lambda ev: ev[-1]["event"] == C.EVENT_STAGE and ev[-1]["stage"] == stage


def _mid_flow(events: list[dict]) -> bool:
    """The flow has done a pair and has pairs left: a signal now lands inside it on any machine (a fixed delay
    after the stage began would land after it on a machine fast enough)."""
    last = events[-1]
    return last["event"] == C.EVENT_JOB and last["stage"] == "flow" and 0 < last["done"] < last["total"]


def _sigterm_at(
    args: list[str], when: Callable[[list[dict]], bool], sig: signal.Signals = signal.SIGTERM
) -> tuple[subprocess.CompletedProcess, list[dict]]:
    """Run ``python -m engine ARGS``, send ``sig`` once ``when(events)`` holds; the exit, its events."""
    proc = start_engine(args)
    events = progress_until(proc, when)
    proc.send_signal(sig)
    rest, err = proc.communicate(timeout=300)
    events += [m for m in map(C.parse_progress_line, rest.splitlines()) if m]
    return subprocess.CompletedProcess(args, proc.returncode, rest, err), events


def _no_partial_files(run: Path) -> None:
    leftovers = [p for p in run.rglob("*") if ".tmp" in p.name]
    assert not leftovers, leftovers


def _cancelled_line(out: subprocess.CompletedProcess, sig: signal.Signals = signal.SIGTERM) -> str:
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert out.returncode == C.EXIT_CANCELLED and len(lines) == 1, (out.returncode, out.stderr)
    assert lines[0].startswith(f"cancelled: fit stopped by {sig.name} before it finished; nothing half-written"), lines
    return lines[0]


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_sigterm_while_the_flow_is_computed_leaves_nothing_partial_and_the_fit_runs_again(tmp_path, sig):
    """SIGTERM and SIGINT (Ctrl-C) alike: exit 3 and the one line, outside the training loop too."""
    frames, masks = write_scene(make_scene(FLOW_SPEC), tmp_path / "clip")
    run = tmp_path / "run"
    args = _quick_args(frames, masks, run)
    out, events = _sigterm_at(args, _mid_flow, sig)
    assert "run the same command again" in _cancelled_line(out, sig)
    assert not any(e["event"] == C.EVENT_STAGE and e["stage"] == "scene" for e in events), "flow had finished"
    _no_partial_files(run)
    assert not list(run.rglob("*.npz")), "a flow cache file was written before the flow was computed"
    assert RunFolder(run).fit_contents() == []  # nothing of a fit: the same command may start it

    again = subprocess.run([sys.executable, "-m", "engine", *args], cwd=ROOT, capture_output=True, text=True)
    assert again.returncode == C.EXIT_OK, again.stderr
    assert RunFolder(run).read_metrics()["steps"] == 2


@pytest.mark.slow
def test_sigterm_during_the_final_evaluation_keeps_the_checkpoint_and_resume_finishes(tmp_path):
    frames, masks = write_scene(make_scene(EVAL_SPEC), tmp_path / "clip")
    run = tmp_path / "run"
    out, events = _sigterm_at(_quick_args(frames, masks, run), _at_stage("evaluate"))
    assert f"continue with: python -m engine fit --resume --out {run}" in _cancelled_line(out)
    assert not any(e["event"] == C.EVENT_DONE for e in events), "the evaluation had finished"
    _no_partial_files(run)
    folder = RunFolder(run)  # the folder loads: every record, the finished checkpoint, no metrics yet
    assert folder.read_config().steps == 2 and folder.read_scene(folder.read_clip()).num_layers == 2
    assert folder.load_checkpoint(torch.device("cpu"))["step"] == 2 and folder.read_metrics() is None

    _, metrics, resumed = _resume(run)
    assert metrics["steps"] == 2 and not any(e["event"] == C.EVENT_PROGRESS for e in resumed)
