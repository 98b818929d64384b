"""How long each preset will take on this machine and this clip, and what it is expected to reach.

A short calibration times a few real training steps of every preset on the prepared clip, in each of the
two cost regimes of a fit (while the global-rigidity term is on, which costs two more mapping passes per
layer, and after), and multiplies by the preset's step budget; flow and evaluation are timed too. Expected
PSNR comes from ``BENCHMARK_TABLE``: complete fits of each preset on a reference clip, not this clip
(``expected_psnr.json`` beside this module; docs/accuracy-vs-time.md says how they were measured).

Every preset asked for gets a row. One that cannot fit this clip (the paper's architecture has exactly one
foreground layer: a clip given no ``--mask``, or several, cannot be fitted with it) is not timed; its row says why
in ``unavailable`` (``None`` in the rows of presets that apply), in the text table and in ``--json``, where the
add-on's reader shows it.
"""

from __future__ import annotations

import json
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch

from .. import contract as C
from ..config import PRESETS, FitConfig, apply_overrides, preset_config
from ..data.video import frame_pixels
from ..io.images import display_path
from ..terms.versions import SCHEMA_VERSION
from .device import select_device, synchronize, torch_threads
from .eta import PRE_TRAIN_SHARE
from .evaluation import EVAL_CHUNK
from .fit_inputs import FitInputs
from .prepare import prepare_clip
from .progress import Reporter
from .trainer import Trainer

#: The measured PSNR of each preset (data, with where it was measured): what ``estimate`` shows as expected.
EXPECTED_PSNR_FILE = Path(__file__).with_name("expected_psnr.json")
#: preset -> {"psnr": dB or None (not measured), "clip": the clip it was measured on, "note": one line}
BENCHMARK_TABLE: dict[str, dict[str, Any]] = json.loads(EXPECTED_PSNR_FILE.read_text(encoding="utf-8"))["presets"]
#: Pixels reconstructed untimed before the render is timed (warm-up: allocator, kernels).
RENDER_WARMUP_PIXELS = 256
#: Timed steps per regime: at least this many, and at least ``calib_seconds`` of them (one paper-model
#: step is already seconds long).
MIN_TIMED_STEPS = 1
#: The foreground layers the paper's architecture has (one background, one foreground: ``model.paper_model``).
PAPER_FOREGROUND_LAYERS = 1
#: What the text table shows in the columns of a preset that was not timed.
NOT_TIMED = "–"


@dataclass
class PresetEstimate:
    """One preset's row; the timings are None when the preset cannot fit this clip (``unavailable`` says why)."""

    preset: str
    model: str
    steps: int
    batch: int
    seconds_per_step_early: float | None  # while global rigidity is on (the first global_rigidity_steps)
    seconds_per_step_late: float | None
    train_seconds: float | None
    eval_seconds: float | None  # the live PSNR every eval_every steps and the final full-frame evaluation
    total_seconds: float | None  # preparation (flow) + train + eval
    minutes: float | None
    expected_psnr: float | None
    expected_psnr_note: str
    unavailable: str | None = None
    """Why this preset cannot fit this clip (one line); None when it can."""


def preset_unavailable(cfg: FitConfig, foreground_layers: int) -> str | None:
    """Why ``cfg`` cannot fit a clip of ``foreground_layers`` foreground layers (one line), or None when it can:
    the paper's architecture has exactly ``PAPER_FOREGROUND_LAYERS``."""
    if cfg.model == "paper" and foreground_layers != PAPER_FOREGROUND_LAYERS:
        given = "no --mask" if foreground_layers == 0 else f"{foreground_layers} --mask folders"
        return (
            f"the paper model fits exactly {PAPER_FOREGROUND_LAYERS} foreground layer and this clip has "
            f"{foreground_layers} ({given}): estimate it with exactly one --mask"
        )
    return None


def _unavailable_row(cfg: FitConfig, why: str) -> PresetEstimate:
    return PresetEstimate(
        preset=cfg.preset,
        model=cfg.model,
        steps=cfg.steps,
        batch=cfg.batch,
        seconds_per_step_early=None,
        seconds_per_step_late=None,
        train_seconds=None,
        eval_seconds=None,
        total_seconds=None,
        minutes=None,
        expected_psnr=None,
        expected_psnr_note="not estimated",
        unavailable=why,
    )


def _time_steps(trainer: Trainer, step: int, calib_seconds: float) -> float:
    """Seconds per optimisation step with the loss weights of ``step``."""
    trainer.optimise(step)  # warm-up: allocator, kernels
    n, t0 = 0, time.perf_counter()
    while n < MIN_TIMED_STEPS or time.perf_counter() - t0 < calib_seconds:
        trainer.optimise(step)
        n += 1
    synchronize(trainer.device)
    return (time.perf_counter() - t0) / n


@torch.no_grad()
def _time_render(model: Any, size: tuple[int, int], device: torch.device) -> float:
    """Seconds to reconstruct one pixel (timed on one evaluation chunk)."""
    xy, tt = frame_pixels(size, 0, device)
    xy, tt = xy[:EVAL_CHUNK], tt[:EVAL_CHUNK]
    model.reconstruct(xy[:RENDER_WARMUP_PIXELS], tt[:RENDER_WARMUP_PIXELS])
    t0 = time.perf_counter()
    model.reconstruct(xy, tt)
    return (time.perf_counter() - t0) / xy.shape[0]


def estimate(
    inputs: FitInputs,
    presets: list[str] | None = None,
    work_dir: str | Path | None = None,
    calib_seconds: float = 2.0,
    device_name: str = "auto",
    overrides: dict[str, str] | None = None,
    threads: int | None = None,
    reporter: Reporter | None = None,
) -> dict[str, Any]:
    """Estimate every preset's fit time on ``inputs`` (the clip, its masks and frames). ``work_dir`` holds the flow
    cache in a run folder's layout (``work_dir/flow_cache``): pass the future run folder and ``fit`` reuses the flow.
    ``reporter``: where the progress goes (``job`` messages: the flow's pairs, then each preset timed; default:
    nowhere)."""
    with torch_threads(threads):
        return _estimate(
            inputs,
            presets or list(PRESETS),
            work_dir,
            calib_seconds,
            device_name,
            overrides or {},
            reporter or Reporter.null(),
        )


def _estimate(
    inputs: FitInputs,
    presets: list[str],
    work_dir: str | Path | None,
    calib_seconds: float,
    device_name: str,
    overrides: dict[str, str],
    reporter: Reporter,
) -> dict[str, Any]:
    device = select_device(device_name)
    cfgs = [apply_overrides(preset_config(p), overrides or {}) for p in presets]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(work_dir) if work_dir else Path(tmp)
        t0 = time.perf_counter()
        prepared = prepare_clip(inputs, cfgs[0], work, reporter)
        prepare_seconds = time.perf_counter() - t0
    timing = _PresetProgress(reporter, len(cfgs))
    video = prepared.tensors(cfgs[0], device)
    t_count, h, w = video.shape
    rows = []
    for cfg in cfgs:
        timing.next()
        why = preset_unavailable(cfg, prepared.num_foreground)
        if why is not None:
            rows.append(_unavailable_row(cfg, why))
            continue
        # the trainer `fit` would build: the scene analysis decides components (a tripod shot costs less)
        trainer = Trainer(cfg, prepared, prepared.analyse(cfg), device, video=video)
        early_steps = min(cfg.global_rigidity_steps, cfg.steps)
        early = _time_steps(trainer, 0, calib_seconds) if early_steps > 0 else 0.0
        late_step = max(cfg.global_rigidity_steps, 0)
        late = _time_steps(trainer, late_step, calib_seconds) if cfg.steps > early_steps else early
        train = early_steps * early + (cfg.steps - early_steps) * late
        per_px = _time_render(trainer.model, prepared.size, device)
        live = (cfg.steps // max(cfg.eval_every, 1)) * cfg.eval_pixels * per_px
        final = t_count * h * w * per_px
        total = prepare_seconds + train + live + final
        bench = BENCHMARK_TABLE.get(cfg.preset, {"psnr": None, "note": "no benchmark for this preset"})
        rows.append(
            PresetEstimate(
                preset=cfg.preset,
                model=cfg.model,
                steps=cfg.steps,
                batch=cfg.step_batch(t_count),
                seconds_per_step_early=round(early, 4),
                seconds_per_step_late=round(late, 4),
                train_seconds=round(train, 1),
                eval_seconds=round(live + final, 1),
                total_seconds=round(total, 1),
                minutes=round(total / 60.0, 1),
                expected_psnr=bench["psnr"],
                expected_psnr_note=bench["note"],
            )
        )
    timing.next()
    return {
        C.ESTIMATE_TAG: SCHEMA_VERSION,
        "clip": display_path(prepared.info.source),
        "frames": int(t_count),
        "working_size": [w, h],
        "device": device.type,
        "torch_threads": torch.get_num_threads(),
        "prepare_seconds": round(prepare_seconds, 1),
        "calib_seconds": calib_seconds,
        "presets": [asdict(r) for r in rows],
    }


class _PresetProgress:
    """The estimate's ``job`` messages while it times the presets: one as each preset starts and one at the end,
    the time left at the mean seconds of the presets timed so far. Reading the clip and its flow (the flow's own
    messages) are the first ``eta.PRE_TRAIN_SHARE`` of the bar."""

    def __init__(self, reporter: Reporter, total: int) -> None:
        self.reporter, self.total, self.done = reporter, total, -1
        self.started = time.perf_counter()

    def next(self) -> None:
        self.done += 1
        left = (time.perf_counter() - self.started) / self.done * (self.total - self.done) if self.done else None
        fraction = PRE_TRAIN_SHARE + (1.0 - PRE_TRAIN_SHARE) * self.done / max(self.total, 1)
        eta = None if left is None else round(left, 1)
        self.reporter.emit(
            C.EVENT_JOB,
            stage="estimate",
            done=self.done,
            total=self.total,
            stage_eta=eta,
            job_fraction=round(fraction, 4),
            job_eta=eta,
        )


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 90 * 60:
        return f"{seconds / 60:.1f} min"
    if seconds < 48 * 3600:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} days"


def format_estimate(result: dict[str, Any]) -> str:
    w, h = result["working_size"]
    lines = [
        f"{result['clip']}: {result['frames']} frames at {w}x{h} on {result['device']} "
        f"({result['torch_threads']} threads); preparation (flow) {result['prepare_seconds']:.0f} s",
        "| preset | model | steps | s/step (early / late) | estimated time | minutes | expected PSNR |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in result["presets"]:
        if r.get("unavailable"):
            lines.append(
                f"| {r['preset']} | {r['model']} | {r['steps']} | {NOT_TIMED} | not available: {r['unavailable']} | "
                f"{NOT_TIMED} | {NOT_TIMED} |"
            )
            continue
        psnr = (
            f"{r['expected_psnr']:.2f} dB ({r['expected_psnr_note']})"
            if r["expected_psnr"]
            else r["expected_psnr_note"]
        )
        lines.append(
            f"| {r['preset']} | {r['model']} | {r['steps']} | {r['seconds_per_step_early']:.3f} / "
            f"{r['seconds_per_step_late']:.3f} | {_duration(r['total_seconds'])} | {r['minutes']:.1f} | {psnr} |"
        )
    return "\n".join(lines)


__all__ = ["BENCHMARK_TABLE", "PresetEstimate", "estimate", "format_estimate", "preset_unavailable"]
