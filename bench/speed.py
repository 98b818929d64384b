"""Seconds per training step of several presets on one clip, measured side by side in one process.

Machines here are noisy, so presets are interleaved in short blocks and the median block is reported;
ratios between presets are what to trust. (The full accuracy-vs-time benchmark builds on this.) A preset may carry
overrides, ``draft:mapping_hidden_fg=128``, so a candidate change is timed beside the preset it would change.
"""

from __future__ import annotations

import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from bench.bench import differing_shared_field
from engine.config import FitConfig, apply_overrides, parse_set_args, preset_config
from engine.errors import InputError
from engine.fit.device import select_device, synchronize
from engine.fit.fit_inputs import FitInputs
from engine.fit.prepare import prepare_clip
from engine.fit.trainer import Trainer

#: Untimed steps of each preset before the rounds (allocator, kernels).
WARMUP_STEPS = 2


#: Separates a preset from its overrides in a ``--presets`` entry: ``PRESET:KEY=VALUE[:KEY=VALUE...]``.
VARIANT_SEP = ":"


def variant_config(entry: str) -> FitConfig:
    """``PRESET`` or ``PRESET:KEY=VALUE[:KEY=VALUE...]`` as the config it names (a bad preset, key or value is one
    line, as for ``fit --set``)."""
    name, *sets = entry.split(VARIANT_SEP)
    cfg = preset_config(name)
    return apply_overrides(cfg, parse_set_args(sets)) if sets else cfg


@dataclass
class StepTiming:
    preset: str
    model: str
    batch: int
    seconds_per_step: float
    params: int


def measure_step_times(
    clip: str | Path,
    mask_dirs: list[str | Path],
    presets: list[str],
    work_dir: Path,
    steps: int = 10,
    rounds: int = 3,
    device_name: str = "auto",
    at_step: int = 0,
) -> list[StepTiming]:
    """Seconds per step of each preset's trainer (what ``fit`` would train, scene analysis included) with the loss
    weights of step ``at_step`` (0: every bootstrap term on; past ``global_rigidity_steps``: the late phase): the
    median of ``rounds`` blocks of ``steps`` steps, presets interleaved. ``presets`` entries may carry overrides
    (``variant_config``); they share one prepared clip, so they must agree on its flow and working size
    (``bench.SHARED_FIELDS``: a one-line error otherwise)."""
    cfgs = [variant_config(p) for p in presets]
    differ = differing_shared_field(cfgs)
    if differ is not None:
        raise InputError(None, f"the entries differ in {differ}", f"give every entry the same {differ}")
    device = select_device(device_name)
    prepared = prepare_clip(FitInputs(clip, mask_dirs), cfgs[0], work_dir)
    video = prepared.tensors(cfgs[0], device)
    trainers = [Trainer(cfg, prepared, prepared.analyse(cfg), device, video=video) for cfg in cfgs]
    times: list[list[float]] = [[] for _ in cfgs]

    def block(trainer: Trainer, n: int) -> float:
        t0 = time.perf_counter()
        for _ in range(n):
            trainer.optimise(at_step)
        synchronize(device)
        return (time.perf_counter() - t0) / n

    for trainer in trainers:
        block(trainer, WARMUP_STEPS)
    for r in range(rounds):
        order = list(enumerate(trainers))
        for i, trainer in order if r % 2 == 0 else reversed(order):
            times[i].append(block(trainer, steps))
            print(f"round {r + 1}/{rounds} {presets[i]}: {times[i][-1]:.3f} s/step", file=sys.stderr)
    return [
        StepTiming(
            name,
            t.cfg.model,
            t.cfg.batch,
            statistics.median(own),
            sum(p.numel() for p in t.model.parameters()),
        )
        for name, t, own in zip(presets, trainers, times, strict=True)
    ]


def format_table(rows: list[StepTiming]) -> str:
    ref = next((r for r in rows if r.model == "paper"), rows[0])
    lines = [
        "| preset | model | batch | s/step | samples/s | params | speed vs " + ref.preset + " |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        per_sample = (ref.seconds_per_step / ref.batch) / (r.seconds_per_step / r.batch)
        lines.append(
            f"| {r.preset} | {r.model} | {r.batch} | {r.seconds_per_step:.3f} | "
            f"{r.batch / r.seconds_per_step:,.0f} | {r.params / 1e6:.2f} M | {per_sample:.1f}x per sample |"
        )
    return "\n".join(lines)
