"""Accuracy against time: fit several presets on several clips in one process and record, per run, a curve
of training seconds against full-frame PSNR, mapping consistency and atlas-based point tracking.

The training clock counts only optimisation steps (and the model's own calibration, as ``fit`` does);
evaluation runs at fixed points of that clock on a fixed frame subset shared by every run, so curves are
comparable. Runs are interleaved in short slices by default, so machine noise hits every preset alike.
Writes ``bench.json`` (rewritten after every evaluation, so a killed bench keeps its curves) and ``bench.png``.

Here: the bench's inputs (clips, configs), its evaluation schedule and its loop. A clip's state and a run are
``bench.bench_runs``; a curve point ``bench.bench_evaluation``; the machine and versions of the record
``bench.bench_machine``; the plot and table ``bench.bench_summary``.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from bench.bench_clip import BenchClip
from bench.bench_evaluation import evaluate
from bench.bench_machine import machine, rss_mb, versions
from bench.bench_runs import ClipState, Run, _advance, _prepare
from bench.bench_summary import plot_bench
from engine.config import FitConfig, apply_overrides, preset_config
from engine.errors import InputError
from engine.fit.device import select_device, torch_threads
from engine.fit.trainer import Trainer
from engine.io.atomic import atomic_write_text

#: Version of bench.json (the tag key is BENCH_TAG).
BENCH_VERSION = 1
BENCH_TAG = "neural_atlas_bench"
BENCH_JSON = "bench.json"
BENCH_PNG = "bench.png"
#: The first evaluation is at this fraction of the budget (then geometric up to the budget: dense early on).
FIRST_EVAL_FRACTION = 1.0 / 32.0
#: Config fields that decide the prepared clip (frames, flow, mask prior); every preset of a bench shares it.
SHARED_FIELDS: tuple[str, ...] = (
    "long_edge",
    "flow_preset",
    "flow_threshold_px",
    "mask_prior_margin_px",
    "mask_snap_px",
)


def bench_configs(presets: list[str], overrides: dict[str, str]) -> list[FitConfig]:
    """Each preset's config; ``KEY`` overrides apply to every preset, ``PRESET.KEY`` to that preset only."""
    for key in overrides:
        prefix = key.split(".", 1)[0] if "." in key else None
        if prefix is not None and prefix not in presets:
            raise InputError(None, f"--set {key}: {prefix!r} is not one of the benched presets", "fix the prefix")
    common = {k: v for k, v in overrides.items() if "." not in k}
    cfgs = []
    for p in presets:
        own = {k.split(".", 1)[1]: v for k, v in overrides.items() if k.startswith(p + ".")}
        cfgs.append(apply_overrides(preset_config(p), {**common, **own}))
    differ = differing_shared_field(cfgs)
    if differ is not None:
        raise InputError(None, f"presets differ in {differ}", f"set {differ} for every preset (--set {differ}=...)")
    return cfgs


def differing_shared_field(cfgs: list[FitConfig]) -> str | None:
    """The first of ``SHARED_FIELDS`` (the prepared clip's) on which ``cfgs`` disagree; None if they share them."""
    return next((f for f in SHARED_FIELDS if len({getattr(c, f) for c in cfgs}) > 1), None)


def _eval_schedule(budget: float, evals: int, extra: tuple[float, ...] = ()) -> list[float]:
    """Training-clock times of the evaluations: geometric from FIRST_EVAL_FRACTION of the budget to the budget,
    plus ``extra`` times within the budget (the targets' marks: a curve read at 600 s should be measured
    there, not interpolated between geometric points)."""
    times = [budget] if evals <= 1 else [float(x) for x in np.geomspace(budget * FIRST_EVAL_FRACTION, budget, evals)]
    times += [float(x) for x in extra if 0.0 < x < budget]
    return sorted(set(round(x, 6) for x in times))


@dataclass(frozen=True)
class BenchPlan:
    """What a bench trains and how it measures: one value from the command line (``bench``, ``bench all-clips``)
    to every run. Each of ``presets`` trains for ``budget_seconds`` (or until its steps end), with ``overrides``
    (``KEY`` for every preset, ``PRESET.KEY`` for one: ``bench_configs``); it is evaluated ``evals`` times,
    geometrically over the budget, and at the ``eval_at`` training seconds (with ``eval_at_start`` also before its
    first step), on ``eval_frames`` frames, tracking from every ``stride``-th pixel. Runs take turns in slices of
    ``slice_seconds`` of training, or one after the other (``sequential``), on ``device_name`` with ``threads``
    torch threads (None: torch's choice)."""

    presets: tuple[str, ...]
    budget_seconds: float
    overrides: dict[str, str] = field(default_factory=dict)
    evals: int = 6
    eval_frames: int = 5
    eval_at_start: bool = False
    eval_at: tuple[float, ...] = ()
    stride: int = 4
    slice_seconds: float = 5.0
    sequential: bool = False
    device_name: str = "auto"
    threads: int | None = None


def run_bench(
    clips: list[BenchClip],
    plan: BenchPlan,
    out_dir: str | Path,
    command: list[str] | None = None,
    log: Any = None,
    plot: bool = True,
) -> dict:
    """Run ``plan`` on every clip; returns the bench record (also written to ``out_dir/bench.json``, with the plot
    in ``out_dir/bench.png``)."""
    with torch_threads(plan.threads):
        return _run_bench(clips, plan, Path(out_dir), command, log or sys.stderr, plot)


def _run_bench(
    clips: list[BenchClip], plan: BenchPlan, out: Path, command: list[str] | None, log: Any, plot: bool
) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    device = select_device(plan.device_name)
    cfgs = bench_configs(list(plan.presets), plan.overrides)
    schedule = _eval_schedule(plan.budget_seconds, plan.evals, plan.eval_at)
    record = _new_record(
        command,
        {
            "presets": list(plan.presets),
            "budget_seconds": plan.budget_seconds,
            "eval_times": [round(x, 3) for x in schedule],
            "eval_frames": plan.eval_frames,
            "mode": "sequential" if plan.sequential else "interleaved",
            "slice_seconds": plan.slice_seconds,
            "overrides": dict(plan.overrides),
            "device": device.type,
            "stride": plan.stride,
            "eval_at_start": plan.eval_at_start,
            "clock": "training seconds: optimisation steps and model calibration; evaluation excluded",
        },
    )
    states = _prepare_clips(clips, cfgs[0], out, plan.eval_frames, device, log)
    record["clips"] = [s.record() for s in states]
    runs = _start_runs(states, cfgs, schedule, device, plan.stride, plan.eval_at_start)

    def write() -> None:
        record["runs"] = [r.record() for r in runs]
        record["peak_rss_mb"] = rss_mb()[1]
        atomic_write_text(out / BENCH_JSON, json.dumps(record, indent=1))

    active, budget = list(runs), plan.budget_seconds
    while active:
        for run in active[:1] if plan.sequential else list(active):
            until = math.inf if plan.sequential else run.trainer.train_seconds + plan.slice_seconds
            _advance(run, min(until, run.eval_times[0] if run.eval_times else math.inf), budget)
            over = run.trainer.train_seconds >= budget or run.trainer.finished or run.failed is not None
            due = bool(run.eval_times) and run.trainer.train_seconds >= run.eval_times[0]
            if due or over:
                while run.eval_times and run.trainer.train_seconds >= run.eval_times[0]:
                    run.eval_times.pop(0)
                _evaluate_and_log(run, device, plan.stride, log)
                write()
            if over:
                run.done = True
                active.remove(run)
    write()
    if plot:
        plot_bench(record, out / BENCH_PNG)
    return record


def _new_record(command: list[str] | None, settings: dict[str, Any]) -> dict[str, Any]:
    """The bench record before its clips and runs: what ran, when, where, with which versions and settings."""
    return {
        BENCH_TAG: BENCH_VERSION,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "command": command if command is not None else list(sys.argv),
        "machine": machine(),
        "versions": versions(),
        "settings": settings,
        "clips": [],
        "runs": [],
    }


def _prepare_clips(
    clips: list[BenchClip], cfg: FitConfig, out: Path, eval_frames: int, device: torch.device, log: Any
) -> list[ClipState]:
    """Each clip prepared once (frames, masks, flow, its chained-flow baseline) for every preset's run on it."""
    states = []
    for spec in clips:
        print(f"[bench] preparing {spec.name} (frames, masks, flow)", file=log, flush=True)
        states.append(_prepare(spec, cfg, out / "work" / spec.name, eval_frames, device))
        base = states[-1].baseline
        if base is not None:
            print(f"[bench] {spec.name}: chained-flow baseline delta_avg {base['delta_avg']:.3f}", file=log)
    return states


def _start_runs(
    states: list[ClipState],
    cfgs: list[FitConfig],
    schedule: list[float],
    device: torch.device,
    stride: int,
    eval_at_start: bool,
) -> list[Run]:
    """Every preset on every clip, its trainer set up and calibrated as ``fit`` does, before the first step."""
    runs: list[Run] = []
    for state in states:
        for cfg in cfgs:
            prep = state.prepared
            trainer = Trainer(cfg, prep, prep.analyse(cfg), device, video=state.video)  # what `fit` would train
            trainer.calibrate()  # counted as training, as in fit
            run = Run(state, trainer, list(schedule), loop_start_seconds=trainer.train_seconds)
            runs.append(run)
            if eval_at_start:  # the initialised model (fast: motion from the flow), before any step
                run.curve.append(evaluate(run, device, stride))
    return runs


def _evaluate_and_log(run: Run, device: torch.device, stride: int, log: Any) -> None:
    """One curve point added to ``run``, and its line on the log."""
    point = evaluate(run, device, stride)
    run.curve.append(point)
    trk = point["tracking"]["delta_avg"] if point["tracking"] else None
    iou = "" if point["fg_iou"] is None else f"fg IoU {point['fg_iou']:.3f}, "
    print(
        f"[bench] {run.clip.spec.name} {run.trainer.cfg.preset}: {run.trainer.train_seconds:.1f} s, "
        f"step {run.trainer.step}, "
        f"PSNR {point['psnr']:.2f} dB, {iou}consistency {point['consistency_texels']} texels, "
        f"delta_avg {trk if trk is None else round(trk, 3)} (eval {point['eval_seconds']:.1f} s)",
        file=log,
        flush=True,
    )


__all__ = [
    "BENCH_JSON",
    "BENCH_PNG",
    "BenchPlan",
    "run_bench",
]
