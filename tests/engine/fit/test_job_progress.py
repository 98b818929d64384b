"""Progress tells the truth about the whole job (``contract.EVENT_JOB`` and the ``job_*`` fields of ``progress``):
messages arrive during the flow, training, evaluation and export, not only at the live-PSNR steps; the whole
job's fraction never goes back; a resumed fit starts where its checkpoint is, not at 0; the whole-job ETA covers
the stages after the running one (evaluation and export). Real ``python -m engine`` processes on a tiny clip."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from engine import contract as C
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.fit.eta import PRE_TRAIN_SHARE, JobClock
from engine.fit.fit_inputs import FitInputs
from engine.terms.protocol import EVENT_CANCELLED
from tests.engine_cli import progress_until, start_engine
from tests.paths import ROOT

SPEC = SceneSpec(width=48, height=32, frames=5, fg_size=(16, 12), fg_start=(10.0, 8.0))
STEPS = 150
SETS = [f"steps={STEPS}", "batch=256", "eval_every=10", "eval_pixels=4000", "bootstrap_steps=10",
        "global_rigidity_steps=5", "checkpoint_seconds=0.2"]  # fmt: skip


def _argv(frames: Path, masks: Path, run: Path) -> list[str]:
    sets = [a for s in SETS for a in ("--set", s)]
    return ["fit", str(frames), "--mask", str(masks), "--out", str(run), "--preset", "draft", "--no-bar", *sets]


def _events(text: str) -> list[dict]:
    return [m for m in map(C.parse_progress_line, text.splitlines()) if m]


def _fractions(events: list[dict]) -> list[float]:
    return [e["job_fraction"] for e in events if "job_fraction" in e]


def _engine(*args: str) -> tuple[list[dict], float]:
    started = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "engine", *args], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert out.returncode == C.EXIT_OK, out.stderr
    return _events(out.stdout), time.perf_counter() - started


@pytest.mark.slow
def test_fit_resume_and_export_report_the_whole_job(tmp_path):
    frames, masks = write_scene(make_scene(SPEC), tmp_path / "clip")
    run = tmp_path / "run"

    # 1. a new fit, stopped mid-training
    proc = start_engine(_argv(frames, masks, run))
    first = progress_until(proc, lambda ev: ev[-1]["event"] == C.EVENT_PROGRESS and ev[-1]["step"] >= STEPS // 2)
    proc.send_signal(signal.SIGTERM)
    rest, err = proc.communicate(timeout=300)
    first += _events(rest)
    assert proc.returncode == C.EXIT_CANCELLED, err
    jobs = [e for e in first if e["event"] == C.EVENT_JOB]
    flow = [e for e in jobs if e["stage"] == "flow"]
    # the flow reports each pair, before training starts; its share of the bar is PRE_TRAIN_SHARE (no rate yet)
    assert [e["done"] for e in flow] == list(range(1, SPEC.frames)) and {e["total"] for e in flow} == {SPEC.frames - 1}
    assert first.index(flow[-1]) < next(i for i, e in enumerate(first) if e["event"] == C.EVENT_PROGRESS)
    assert flow[-1]["job_fraction"] == pytest.approx(PRE_TRAIN_SHARE) and flow[-1]["job_eta"] is None
    fractions = _fractions(first)
    assert fractions == sorted(fractions) and PRE_TRAIN_SHARE <= fractions[-1] < 1.0
    trained = [e for e in first if e["event"] == C.EVENT_PROGRESS]
    assert all(
        {"step", "total", "psnr", "elapsed", "eta", "losses", "job_fraction", "job_eta"} <= set(e) for e in trained
    )
    # the whole job's ETA is more than training's: evaluation and export come after it
    late = [e for e in trained if e["eta"] is not None and e["job_eta"] is not None]
    assert late and all(e["job_eta"] > e["eta"] for e in late)
    stopped = next(e["step"] for e in first if e["event"] == EVENT_CANCELLED)
    at_stop = fractions[-1]

    # 2. resumed: the bar starts at the checkpoint's share, and the ETA is known at once (the checkpoint's rate)
    resumed, _ = _events_of(run)
    start = next(e for e in resumed if e["event"] == C.EVENT_JOB and e["stage"] == "train")
    assert start["done"] == stopped
    shown = start["job_fraction"]
    print(f"whole-job fraction: {at_stop:.3f} when stopped at step {stopped}/{STEPS}, {shown:.3f} on resume")
    # where the stopped fit's bar was (its log says), not 0 (nor a value re-estimated from this process's timings)
    assert start["job_fraction"] >= at_stop >= PRE_TRAIN_SHARE
    assert start["job_eta"] is not None and start["job_eta"] > start["stage_eta"] > 0
    fractions = _fractions(resumed)
    assert fractions == sorted(fractions)
    evaluate = [e for e in resumed if e["event"] == C.EVENT_JOB and e["stage"] == "evaluate"]
    assert [e["done"] for e in evaluate] == [0, 1]
    assert evaluate[0]["stage_eta"] is not None and evaluate[0]["job_eta"] > evaluate[0]["stage_eta"]
    export_estimate = evaluate[1]["job_eta"]  # all that is left of the whole job once evaluated: the export
    assert export_estimate > 0 and evaluate[1]["job_fraction"] < 1.0

    # 3. the export reports each frame: its own job, to 1.0
    exported, seconds = _engine("export", str(run))
    frames_done = [e for e in exported if e["event"] == C.EVENT_JOB and e["stage"] == "export"]
    assert [e["done"] for e in frames_done] == list(range(1, SPEC.frames + 1))
    assert _fractions(frames_done) == sorted(_fractions(frames_done)) and frames_done[-1]["job_fraction"] == 1.0
    assert frames_done[-1]["job_eta"] == 0.0
    print(f"export: estimated {export_estimate:.1f} s by the fit, took {seconds:.1f} s (with the engine's start-up)")


def _events_of(run: Path) -> tuple[list[dict], float]:
    return _engine("fit", "--resume", "--out", str(run), "--no-bar")


def test_job_clock_fraction_and_eta():
    clock = JobClock()
    clock.eval_pixels, clock.export_pixels, clock.atlas_texels = 1000, 1000, 0
    assert clock.flow(2.0, 1, 4) == pytest.approx(6.0)  # 2 s a pair, 3 pairs left
    assert clock.left() is None and clock.fraction() == pytest.approx(PRE_TRAIN_SHARE / 4)
    clock.flow(8.0, 4, 4)
    clock.pixel_rate(0.01, 1000)  # 1e-5 s a pixel
    clock.train(0.0, None)
    assert clock.left() is None and clock.fraction() == pytest.approx(PRE_TRAIN_SHARE)
    clock.train(10.0, 90.0)
    left = clock.left()
    assert left is not None and left > 90.0  # training's 90 s, and the evaluation and the export after it
    assert clock.fraction() == pytest.approx((8.0 + 10.0) / (8.0 + 10.0 + left))
    clock.train(10.0, 900.0)  # a slower rate measured: the bar holds, it does not go back
    assert clock.fraction() == pytest.approx((8.0 + 10.0) / (8.0 + 10.0 + left))
    clock.train(100.0, 0.0)
    clock.evaluated(0.5)
    assert clock.left() == clock.export_left and 0.9 < clock.fraction() < 1.0
    assert json.dumps(clock.left())  # a plain number for the progress line


def test_estimate_reports_each_preset(tmp_path):
    """``estimate`` (``--json``: for the add-on's Estimate Time) sends the flow's pairs and one ``job`` message as
    each preset starts and at the end: the bar moves during the minutes it may take."""
    import io

    from engine.fit.estimate import estimate
    from engine.fit.progress import Reporter

    frames, masks = write_scene(make_scene(SPEC), tmp_path / "clip")
    out = io.StringIO()
    inputs = FitInputs(frames, [masks])
    result = estimate(inputs, presets=["draft", "balanced"], calib_seconds=0.05, reporter=Reporter(stream=out))
    events = [e for e in _events(out.getvalue()) if e["event"] == C.EVENT_JOB]
    assert [e["stage"] for e in events][: SPEC.frames - 1] == ["flow"] * (SPEC.frames - 1)
    timed = [e for e in events if e["stage"] == "estimate"]
    assert [e["done"] for e in timed] == [0, 1, 2] and {e["total"] for e in timed} == {2}
    assert _fractions(events) == sorted(_fractions(events)) and timed[-1]["job_fraction"] == 1.0
    assert timed[0]["job_eta"] is None and timed[1]["job_eta"] is not None and timed[-1]["job_eta"] == 0.0
    assert [r["preset"] for r in result["presets"]] == ["draft", "balanced"]
