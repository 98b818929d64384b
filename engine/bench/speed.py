"""Seconds per training step of several presets on one clip, measured side by side in one process.

Machines here are noisy, so presets are interleaved in short blocks and the median block is reported;
ratios between presets are what to trust. (The full accuracy-vs-time benchmark builds on this.)
"""

from __future__ import annotations

import io
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from engine.config import preset_config
from engine.data.video import build_video_tensors, sample_batch
from engine.fit.trainer import Reporter, build_model, make_optimizer, prepare_clip, select_device
from engine.model.objective import compute_losses


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
) -> list[StepTiming]:
    device = select_device(device_name)
    cfgs = [preset_config(p) for p in presets]
    prepared = prepare_clip(clip, mask_dirs, cfgs[0], work_dir, None, Reporter(None, io.StringIO()))
    video = build_video_tensors(prepared.frames, prepared.masks, prepared.flow, cfgs[0].mask_prior_margin_px, device)
    runs = []
    for cfg in cfgs:
        model = build_model(cfg, prepared).to(device)
        runs.append((cfg, model, make_optimizer(model, cfg, device), torch.Generator().manual_seed(cfg.seed)))
    times: dict[str, list[float]] = {c.preset: [] for c in cfgs}

    def block(cfg, model, optim, gen, n: int) -> float:
        t0 = time.perf_counter()
        for _ in range(n):
            ix, iy, t = sample_batch(video, cfg.batch, cfg.object_sample_share, gen, device)
            loss, _ = compute_losses(model, video, cfg, 0, ix, iy, t)  # step 0: every bootstrap term is on
            optim.zero_grad(set_to_none=True)
            loss.backward()
            optim.step()
        if device.type == "cuda":
            torch.cuda.synchronize()
        return (time.perf_counter() - t0) / n

    for run in runs:
        block(*run, 2)  # warm-up: allocator, kernels
    for r in range(rounds):
        for run in runs if r % 2 == 0 else reversed(runs):
            times[run[0].preset].append(block(*run, steps))
            print(f"round {r + 1}/{rounds} {run[0].preset}: {times[run[0].preset][-1]:.3f} s/step", file=sys.stderr)
    return [
        StepTiming(
            cfg.preset,
            cfg.model,
            cfg.batch,
            statistics.median(times[cfg.preset]),
            sum(p.numel() for p in model.parameters()),
        )
        for cfg, model, _, _ in runs
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
