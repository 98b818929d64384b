"""One bench clip's state, prepared once and shared by its runs (frames, flow, the evaluated frames, the tracks'
queries, the chained-flow baseline), and one run: a preset on a clip, trained slice by slice as ``fit`` trains
it, with its curve and its ETA records."""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from bench.bench_clip import BenchClip
from bench.tracking import Tracks, chained_flow_tracks, load_tracks, track_scores
from engine.config import FitConfig
from engine.data.video import VideoTensors
from engine.fit.fit_inputs import FitInputs
from engine.fit.prepare import PreparedClip, prepare_clip
from engine.fit.trainer import Trainer
from engine.io.clip import read_masks

#: Fractions of a run's steps at which the fit's ETA is recorded (compared with the actual remaining time).
ETA_FRACTIONS: tuple[float, ...] = (0.1, 0.25, 0.5)
#: A run's loss is checked for NaN/Inf every this many steps (a diverged run stops; it is recorded as failed).
FINITE_CHECK_EVERY = 100


@dataclass
class ClipState:
    spec: BenchClip
    prepared: PreparedClip
    video: VideoTensors
    eval_frames: list[int]
    tracks: Tracks | None
    track_frames: int
    query_xy: np.ndarray  # working pixels [N, 2]
    query_t: np.ndarray  # [N]
    to_native: np.ndarray  # [2]: working px -> tracks' px
    prepare_seconds: float
    baseline: dict | None = None
    score_masks: np.ndarray | None = None  # bool [T, H, W] at working size: the union of the precise masks

    def record(self) -> dict:
        info = self.prepared.info
        return {
            "name": self.spec.name,
            "source": info.source,
            "masks": self.prepared.mask_dirs,
            "mask_snap_px": [snap.offset_px for snap in self.prepared.mask_snaps],
            # per mask layer: the share of it the mask prior holds (under mask_hold_coverage it is held)
            "prior_coverage": [None if c is None else round(c, 3) for c in self.video.prior_coverage],
            "tracks": str(self.spec.tracks) if self.spec.tracks else None,
            "score_masks": [str(Path(m).resolve()) for m in self.spec.score_masks],
            "native_size": [info.width, info.height],
            "working_size": list(self.prepared.size),
            "frames": int(self.video.shape[0]),
            "eval_frames": self.eval_frames,
            "track_frames": self.track_frames,
            "track_queries": len(self.query_t),
            "prepare_seconds": round(self.prepare_seconds, 2),
            "tracking_baseline": self.baseline,
        }


def _prepare(spec: BenchClip, cfg: FitConfig, work: Path, eval_frames: int, device: torch.device) -> ClipState:
    t0 = time.perf_counter()
    prepared = prepare_clip(FitInputs(spec.frames, spec.masks), cfg, work)
    video = prepared.tensors(cfg, device)
    t_count = int(video.shape[0])
    count = t_count if eval_frames <= 0 else min(eval_frames, t_count)  # 0: every frame
    subset = sorted({round(float(x)) for x in np.linspace(0, t_count - 1, count)})
    tracks, qxy, qt, scale, n_tr = None, np.zeros((0, 2)), np.zeros(0, int), np.ones(2), 0
    if spec.tracks is not None:
        tracks = load_tracks(spec.tracks).cut(t_count)
        n_tr = tracks.num_frames
        scale = np.array(tracks.image_size, dtype=np.float64) / np.array(prepared.size, dtype=np.float64)
        qt = np.rint(tracks.query_txy[:, 0]).astype(int)
        qxy = tracks.query_txy[:, 1:3].astype(np.float64) / scale
    state = ClipState(spec, prepared, video, subset, tracks, n_tr, qxy, qt, scale, time.perf_counter() - t0)
    if spec.score_masks:
        state.score_masks = np.logical_or.reduce(
            [read_masks(m, prepared.info, prepared.size) for m in spec.score_masks]
        )
    if tracks is not None and len(qt):
        flow = prepared.flow
        pred = chained_flow_tracks(flow.forward, flow.backward, np.c_[qt, qxy], n_tr) * scale
        state.baseline = track_scores(pred, tracks)
    return state


@dataclass
class Run:
    """One preset on one clip: its trainer (``engine.fit.trainer.Trainer``, as ``fit`` trains) and its record."""

    clip: ClipState
    trainer: Trainer
    eval_times: list[float]
    loop_start_seconds: float = 0.0  # the model's calibration, before the first step
    done: bool = False
    failed: str | None = None
    curve: list[dict] = field(default_factory=list)
    eta: list[dict] = field(default_factory=list)
    best_psnr: float = -math.inf

    def record(self) -> dict:
        tr = self.trainer
        return {
            "clip": self.clip.spec.name,
            "preset": tr.cfg.preset,
            "model": tr.cfg.model,
            "batch": tr.cfg.batch,
            "steps_planned": tr.cfg.steps,
            "params": int(sum(p.numel() for p in tr.model.parameters())),
            "steps": tr.step,
            "train_seconds": round(tr.train_seconds, 3),
            "seconds_per_step": round((tr.train_seconds - self.loop_start_seconds) / max(tr.step, 1), 4),
            "finished_steps": tr.finished,
            "failed": self.failed,
            "curve": self.curve,
            "eta": self.eta,
            "config": json.loads(tr.cfg.to_json())["config"],
        }


def _advance(run: Run, until: float, budget: float) -> None:
    """Train ``run`` until its clock reaches ``until`` (or the budget, or its last step)."""
    trainer = run.trainer
    marks = {max(1, round(f * trainer.cfg.steps)): f for f in ETA_FRACTIONS}
    while trainer.train_seconds < min(until, budget) and not trainer.finished:
        loss, _ = trainer.train_step()
        if trainer.step in marks:
            # eta_seconds: what fit reports (engine.fit.eta.StepClock: per cost regime, first step left out);
            # eta_mean_seconds: the plain extrapolation (mean seconds per step so far times the steps left)
            elapsed = trainer.train_seconds - run.loop_start_seconds
            eta = trainer.eta()
            run.eta.append(
                {
                    "fraction": marks[trainer.step],
                    "step": trainer.step,
                    "train_seconds": round(trainer.train_seconds, 3),
                    "eta_seconds": None if eta is None else round(eta, 3),
                    "eta_mean_seconds": round(elapsed / trainer.step * (trainer.cfg.steps - trainer.step), 3),
                }
            )
        if trainer.step % FINITE_CHECK_EVERY == 0 and not torch.isfinite(loss.detach()):
            run.failed = f"loss became non-finite at step {trainer.step}"
            return
    if trainer.finished:
        for e in run.eta:
            actual = trainer.train_seconds - e["train_seconds"]
            e["actual_seconds"] = round(actual, 3)
            for key, err in (("eta_seconds", "error"), ("eta_mean_seconds", "error_mean")):
                e[err] = round(e[key] / actual - 1.0, 4) if actual > 0 and e[key] is not None else None
