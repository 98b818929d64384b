"""Accuracy against time: fit several presets on several clips in one process and record, per run, a curve
of training seconds against full-frame PSNR, mapping consistency and atlas-based point tracking.

The training clock counts only optimisation steps (and the model's own calibration, as ``fit`` does);
evaluation runs at fixed points of that clock on a fixed frame subset shared by every run, so curves are
comparable. Runs are interleaved in short slices by default, so machine noise hits every preset alike.
Writes ``bench.json`` (rewritten after every evaluation, so a killed bench keeps its curves) and ``bench.png``.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import platform
import resource
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from engine import contract as C
from engine.bench.tracking import (
    TAPVID_EVAL_SIZE,
    Tracks,
    anchor_spread,
    atlas_tracks,
    chained_flow_tracks,
    load_tracks,
    mapping_consistency,
    scored_positions,
    scores_by_gap,
    tapvid_scores,
)
from engine.config import FitConfig, apply_overrides, preset_config
from engine.data.video import VideoTensors
from engine.errors import InputError
from engine.fit.device import select_device, torch_threads
from engine.fit.prepare import PreparedClip, prepare_clip
from engine.fit.run_folder import RunFolder
from engine.fit.trainer import Trainer, render_frame
from engine.io.atomic import atomic_write_text
from engine.io.clip import read_masks
from engine.model.losses import psnr_from_mse

#: Version of bench.json (the tag key is BENCH_TAG).
BENCH_VERSION = 1
BENCH_TAG = "neural_atlas_bench"
BENCH_JSON = "bench.json"
BENCH_PNG = "bench.png"
TRACKS_FILE = "tracks_tapvid.npz"
#: Fractions of a run's steps at which the fit's ETA is recorded (compared with the actual remaining time).
ETA_FRACTIONS: tuple[float, ...] = (0.1, 0.25, 0.5)
#: The first evaluation is at this fraction of the budget (then geometric up to the budget: dense early on).
FIRST_EVAL_FRACTION = 1.0 / 32.0
#: A run's loss is checked for NaN/Inf every this many steps (a diverged run stops; it is recorded as failed).
FINITE_CHECK_EVERY = 100
#: Seconds ``git`` may take to name the checkout's commit for the record.
GIT_TIMEOUT_S = 10
#: Config fields that decide the prepared clip (frames, flow, mask prior); every preset of a bench shares it.
SHARED_FIELDS: tuple[str, ...] = (
    "long_edge",
    "flow_preset",
    "flow_threshold_px",
    "mask_prior_margin_px",
    "mask_snap_px",
)
#: A pixel is foreground (``fg_iou``) where the foreground layers' opacity weights sum to at least this.
FG_ALPHA_THRESHOLD = 0.5


@dataclass
class BenchClip:
    name: str
    frames: Path
    masks: list[Path]
    tracks: Path | None
    #: Precise masks the decomposition is scored against (``fg_iou``); empty: not scored.
    score_masks: list[Path] = field(default_factory=list)


def resolve_clip(
    path: str | Path,
    masks: list[str | Path] | None = None,
    tracks: str | Path | None = None,
    score_masks: list[str | Path] | None = None,
) -> BenchClip:
    """A clip given as ``<clip>/`` with ``frames/``, ``masks/`` and maybe ``tracks_tapvid.npz`` inside (a clip
    folder), or as a frame folder whose masks come from ``masks`` (tracks then default to
    ``tracks_tapvid.npz`` beside the frame folder). The decomposition is scored against ``score_masks``, by
    default against a clip folder's own ``masks/`` (also when the fit is given other masks)."""
    p = Path(path).expanduser().resolve()
    if not p.is_dir():
        raise InputError(p, "is not a folder", "pass a frame folder, or a clip folder holding frames/ and masks/")
    if (p / "frames").is_dir():
        frames, name, home = p / "frames", p.name, p
        mask_dirs = [Path(m) for m in masks] if masks else ([p / "masks"] if (p / "masks").is_dir() else [])
    else:
        frames, home = p, p.parent
        name = p.parent.name if p.name == "frames" else p.name
        mask_dirs = [Path(m) for m in masks or []]
    if tracks is None and (home / TRACKS_FILE).is_file():
        tracks = home / TRACKS_FILE
    if score_masks:
        score = [Path(m) for m in score_masks]
    else:
        score = [p / "masks"] if (p / "frames").is_dir() and (p / "masks").is_dir() else []
    return BenchClip(name, frames, mask_dirs, Path(tracks) if tracks else None, score)


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
    for f in SHARED_FIELDS:
        if len({getattr(c, f) for c in cfgs}) > 1:
            raise InputError(None, f"presets differ in {f}", f"set {f} for every preset (--set {f}=...)")
    return cfgs


# --- per-clip state shared by its runs ------------------------------------------------------------------


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
    prepared = prepare_clip(spec.frames, list(spec.masks), cfg, work, None)
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
        state.baseline = _track_scores(pred, tracks)
    return state


def _track_scores(pred_native: np.ndarray, tracks: Tracks) -> dict:
    qt = np.rint(tracks.query_txy[:, 0]).astype(int)
    native = tapvid_scores(pred_native, tracks.xy, tracks.occluded, qt)
    w, h = tracks.image_size
    s256 = tapvid_scores(
        pred_native, tracks.xy, tracks.occluded, qt, scale=(TAPVID_EVAL_SIZE[0] / w, TAPVID_EVAL_SIZE[1] / h)
    )
    out = {**native, "coords": "native", "delta_avg_256": s256["delta_avg"]}
    out["per_point"] = _per_point(pred_native, tracks)
    out["by_gap"] = scores_by_gap(pred_native, tracks.xy, tracks.occluded, qt)
    if tracks.on_mask is not None:  # where an atlas falls short: on the masked object or in the background
        out["by_query_mask"] = {
            name: tapvid_scores(pred_native[sel], tracks.xy[sel], tracks.occluded[sel], qt[sel])
            for name, sel in (("on_mask", tracks.on_mask), ("off_mask", ~tracks.on_mask))
        }
    return out


def _per_point(pred_native: np.ndarray, tracks: Tracks) -> list[dict]:
    """Each track's own score, in the file's order: an aggregate hides which points fall short, and a few
    points on something a layer cannot follow (seen through a window, driving through the background) can
    decide a clip. ``delta_avg`` weighted by ``scored_points`` gives the aggregate back."""
    qt = np.rint(tracks.query_txy[:, 0]).astype(int)
    err = np.linalg.norm(np.asarray(pred_native, np.float64) - tracks.xy, axis=-1)
    scored = scored_positions(tracks.occluded, qt)
    out = []
    for i in range(len(qt)):
        s = tapvid_scores(pred_native[i : i + 1], tracks.xy[i : i + 1], tracks.occluded[i : i + 1], qt[i : i + 1])
        out.append(
            {
                "delta_avg": s["delta_avg"],
                "scored_points": s["scored_points"],
                "median_px": round(float(np.median(err[i][scored[i]])), 3) if scored[i].any() else None,
            }
        )
    return out


# --- runs -------------------------------------------------------------------------------------------------


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


def _rss_mb() -> tuple[float, float]:
    """(current, peak) resident memory of this process in MB."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # KB on Linux
    try:
        with open("/proc/self/statm") as f:
            current = int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except OSError:
        current = float("nan")
    return round(current, 1), round(peak, 1)


def foreground(weights: np.ndarray) -> np.ndarray:
    """bool [H, W]: where the foreground layers together (every layer but the background, layer 0) hold at least
    FG_ALPHA_THRESHOLD of the pixel's opacity weights [H, W, L]."""
    return np.asarray(weights[..., 1:].sum(-1) >= FG_ALPHA_THRESHOLD)


@torch.no_grad()
def evaluate(run: Run, device: torch.device, stride: int) -> dict:
    """One curve point: PSNR over every pixel of the clip's eval frames, the decomposition's ``fg_iou`` (pooled
    over those frames: the ``foreground`` against the precise masks; None without them), mapping
    consistency, tracking."""
    t0 = time.perf_counter()
    clip = run.clip
    frames = clip.video.frames
    sq, n = 0.0, 0
    inter, union = 0, 0
    for t in clip.eval_frames:
        rec, wts = render_frame(run.trainer.model, t, clip.prepared.size, device)
        sq += float(((torch.from_numpy(rec).to(frames.device) - frames[t]) ** 2).sum())
        n += rec.size
        if clip.score_masks is not None:
            fg, gt = foreground(wts), clip.score_masks[t]
            inter += int((fg & gt).sum())
            union += int((fg | gt).sum())
    psnr = psnr_from_mse(sq / max(n, 1))
    fg_iou = None if clip.score_masks is None else (inter / union if union else 1.0)
    flow = clip.prepared.flow
    cons = mapping_consistency(run.trainer.model, flow.forward, flow.forward_ok, clip.eval_frames, device, stride)
    tracking = None
    if clip.tracks is not None and len(clip.query_t):
        pred, _ = atlas_tracks(
            run.trainer.model, clip.query_xy, clip.query_t, clip.track_frames, clip.prepared.size, device, stride
        )
        tracking = _track_scores(pred * clip.to_native, clip.tracks)
        tracking["anchor_spread"] = anchor_spread(run.trainer.model, clip.tracks, clip.to_native, device)
    if math.isfinite(psnr):
        run.best_psnr = max(run.best_psnr, psnr)
    rss, peak = _rss_mb()
    return {
        "train_seconds": round(run.trainer.train_seconds, 3),
        "step": run.trainer.step,
        "psnr": round(psnr, 4),
        "fg_iou": None if fg_iou is None else round(fg_iou, 4),
        "best_psnr": round(run.best_psnr, 4) if math.isfinite(run.best_psnr) else None,
        "consistency_texels": None if cons["mean_texels"] is None else round(cons["mean_texels"], 4),
        "consistency_pixels": cons["pixels"],
        "tracking": tracking,
        "eval_seconds": round(time.perf_counter() - t0, 3),
        "rss_mb": rss,
        "peak_rss_mb": peak,
    }


def _eval_schedule(budget: float, evals: int, extra: tuple[float, ...] = ()) -> list[float]:
    """Training-clock times of the evaluations: geometric from FIRST_EVAL_FRACTION of the budget to the budget,
    plus ``extra`` times within the budget (the targets' marks: a curve read at 600 s should be measured
    there, not interpolated between geometric points)."""
    times = [budget] if evals <= 1 else [float(x) for x in np.geomspace(budget * FIRST_EVAL_FRACTION, budget, evals)]
    times += [float(x) for x in extra if 0.0 < x < budget]
    return sorted(set(round(x, 6) for x in times))


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


def _machine() -> dict:
    cpu = platform.processor()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), cpu)
    except OSError:
        pass
    mem = None
    try:
        with open("/proc/meminfo") as f:
            mem = round(int(f.readline().split()[1]) / 2**20, 1)
    except (OSError, ValueError, IndexError):
        pass
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "ram_gb": mem,
        "platform": platform.platform(),
        "load_average_at_start": [round(x, 2) for x in os.getloadavg()],
    }


def _versions() -> dict:
    import cv2

    commit = None
    try:
        root = Path(__file__).resolve().parents[2]  # the checkout
        commit = (
            subprocess.run(
                ["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=GIT_TIMEOUT_S
            ).stdout.strip()
            or None
        )
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=GIT_TIMEOUT_S,
        ).stdout.strip()
        if commit and dirty:
            commit += "+dirty"
    except (OSError, subprocess.SubprocessError):
        pass
    return {
        "engine": C.ENGINE_VERSION,
        "git": commit,
        "python": platform.python_version(),
        "torch": torch.__version__,
        "numpy": np.__version__,
        "opencv": cv2.__version__,
    }


def run_bench(
    clips: list[BenchClip],
    presets: list[str],
    budget_seconds: float,
    out_dir: str | Path,
    overrides: dict[str, str] | None = None,
    evals: int = 6,
    eval_frames: int = 5,
    slice_seconds: float = 5.0,
    sequential: bool = False,
    device_name: str = "auto",
    stride: int = 4,
    command: list[str] | None = None,
    log: Any = None,
    plot: bool = True,
    threads: int | None = None,
    eval_at_start: bool = False,
    eval_at: tuple[float, ...] = (),
) -> dict:
    """Run every preset on every clip for ``budget_seconds`` of training each; returns the bench record
    (also written to ``out_dir/bench.json``, with the plot in ``out_dir/bench.png``). ``eval_at``: training
    seconds to evaluate at besides the geometric ``evals``."""
    log = log or sys.stderr
    with torch_threads(threads):
        return _run_bench(
            clips,
            presets,
            budget_seconds,
            Path(out_dir),
            overrides or {},
            evals,
            eval_frames,
            slice_seconds,
            sequential,
            device_name,
            stride,
            command,
            log,
            plot,
            eval_at_start,
            eval_at,
        )


def _run_bench(
    clips: list[BenchClip],
    presets: list[str],
    budget_seconds: float,
    out: Path,
    overrides: dict[str, str],
    evals: int,
    eval_frames: int,
    slice_seconds: float,
    sequential: bool,
    device_name: str,
    stride: int,
    command: list[str] | None,
    log: Any,
    plot: bool,
    eval_at_start: bool,
    eval_at: tuple[float, ...],
) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    device = select_device(device_name)
    cfgs = bench_configs(presets, overrides or {})
    schedule = _eval_schedule(budget_seconds, evals, eval_at)
    record: dict[str, Any] = {
        BENCH_TAG: BENCH_VERSION,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "command": command if command is not None else list(sys.argv),
        "machine": _machine(),
        "versions": _versions(),
        "settings": {
            "presets": presets,
            "budget_seconds": budget_seconds,
            "eval_times": [round(x, 3) for x in schedule],
            "eval_frames": eval_frames,
            "mode": "sequential" if sequential else "interleaved",
            "slice_seconds": slice_seconds,
            "overrides": overrides or {},
            "device": device.type,
            "stride": stride,
            "eval_at_start": eval_at_start,
            "clock": "training seconds: optimisation steps and model calibration; evaluation excluded",
        },
        "clips": [],
        "runs": [],
    }
    states = []
    for spec in clips:
        print(f"[bench] preparing {spec.name} (frames, masks, flow)", file=log, flush=True)
        states.append(_prepare(spec, cfgs[0], out / "work" / spec.name, eval_frames, device))
        base = states[-1].baseline
        if base is not None:
            print(f"[bench] {spec.name}: chained-flow baseline delta_avg {base['delta_avg']:.3f}", file=log)
    record["clips"] = [s.record() for s in states]
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

    def write() -> None:
        record["runs"] = [r.record() for r in runs]
        record["peak_rss_mb"] = _rss_mb()[1]
        atomic_write_text(out / BENCH_JSON, json.dumps(record, indent=1))

    active = list(runs)
    while active:
        for run in active[:1] if sequential else list(active):
            until = math.inf if sequential else run.trainer.train_seconds + slice_seconds
            _advance(run, min(until, run.eval_times[0] if run.eval_times else math.inf), budget_seconds)
            over = run.trainer.train_seconds >= budget_seconds or run.trainer.finished or run.failed is not None
            due = bool(run.eval_times) and run.trainer.train_seconds >= run.eval_times[0]
            if due or over:
                while run.eval_times and run.trainer.train_seconds >= run.eval_times[0]:
                    run.eval_times.pop(0)
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
                write()
            if over:
                run.done = True
                active.remove(run)
    write()
    if plot:
        plot_bench(record, out / BENCH_PNG)
    return record


def fit_eta_errors(run_dir: str | Path) -> list[dict]:
    """The ETA error of a finished ``fit``: for each progress line of its ``fit.log`` (the ETA it reported,
    see ``engine.fit.eta``), the predicted remaining training time against the actual
    one (``metrics.json``'s ``train_seconds`` minus the line's ``elapsed``). ``error`` = predicted / actual - 1.
    Training seconds exclude the live evaluation and checkpoints; a resumed fit is not supported."""
    run = RunFolder(run_dir)
    metrics = run.read_metrics()
    if metrics is None:
        raise InputError(run.metrics, "the fit has not finished", "let it finish (or resume it) first")
    total = metrics["train_seconds"]
    rows = []
    for line in run.log.read_text(encoding="utf-8").splitlines():
        msg = C.parse_progress_line(line)
        if not msg or msg["event"] != C.EVENT_PROGRESS or msg.get("eta") is None:
            continue
        actual = total - msg["elapsed"]
        if actual <= 0:
            continue
        rows.append(
            {
                "step": msg["step"],
                "fraction": round(msg["step"] / msg["total"], 4),
                "elapsed": msg["elapsed"],
                "eta_seconds": msg["eta"],
                "actual_seconds": round(actual, 2),
                "error": round(msg["eta"] / actual - 1.0, 4),
            }
        )
    return rows


def record_expected_psnr(preset: str, run_dir: str | Path, clip: str, note: str, path: Path | None = None) -> dict:
    """Write a finished fit's full-frame PSNR into ``engine/fit/expected_psnr.json`` as ``preset``'s expected PSNR
    (what ``estimate`` shows): the run must be a fit of that preset. Returns the row written."""
    from engine.fit.estimate import EXPECTED_PSNR_FILE

    run = RunFolder(run_dir)
    metrics = run.read_metrics()
    if metrics is None:
        raise InputError(run.metrics, "the fit has not finished", "let it finish (or resume it) first")
    if metrics["preset"] != preset:
        raise InputError(run.metrics, f"this is a {metrics['preset']} fit, not {preset}", "pass the right run")
    path = path or EXPECTED_PSNR_FILE
    data = json.loads(path.read_text(encoding="utf-8"))
    row = {"psnr": round(float(metrics["psnr"]), 2), "clip": clip, "note": note}
    data["presets"][preset] = row
    atomic_write_text(path, json.dumps(data, indent=2) + "\n")
    return row


# --- plot and summary -------------------------------------------------------------------------------------


def plot_bench(record: dict, path: str | Path) -> None:
    """PSNR, tracking delta_avg and consistency against training minutes: one row per clip, one line per preset."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    clips = record["clips"]
    fig, axes = plt.subplots(len(clips), 3, figsize=(15, 4 * len(clips)), squeeze=False)
    for row, clip in zip(axes, clips, strict=True):
        for run in (r for r in record["runs"] if r["clip"] == clip["name"]):
            pts = run["curve"]
            if not pts:
                continue
            minutes = [p["train_seconds"] / 60.0 for p in pts]
            label = f"{run['preset']} ({run['model']})"
            row[0].plot(minutes, [p["psnr"] for p in pts], marker="o", label=label)
            trk = [p["tracking"]["delta_avg"] if p["tracking"] else None for p in pts]
            if any(v is not None for v in trk):
                row[1].plot(minutes, [np.nan if v is None else v for v in trk], marker="o", label=label)
            cons = [np.nan if p["consistency_texels"] is None else p["consistency_texels"] for p in pts]
            row[2].plot(minutes, cons, marker="o", label=label)
        base = clip.get("tracking_baseline")
        if base and base.get("delta_avg") is not None:
            row[1].axhline(base["delta_avg"], color="k", linestyle="--", label="chained optical flow")
        name = clip["name"]
        row[0].set(title=f"{name}: PSNR on {len(clip['eval_frames'])} full frames", ylabel="dB")
        row[1].set(title=f"{name}: TAP-Vid delta_avg (native px)", ylim=(0, 1))
        row[2].set(title=f"{name}: mapping consistency", ylabel="texels (lower is better)")
        for ax in row:
            ax.set_xlabel("training minutes (evaluation excluded)")
            ax.grid(alpha=0.3)
            if ax.lines:
                ax.legend(fontsize=8)
    m = record["machine"]
    fig.suptitle(f"accuracy vs time: {m['cpu']}, {m['cores']} cores, {record['created']}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def summary_table(record: dict) -> str:
    lines = [
        "| clip | preset | steps | train s | s/step | PSNR (last / best) | fg IoU | consistency (texels) "
        "| delta_avg | flow delta_avg |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    base = {c["name"]: c.get("tracking_baseline") for c in record["clips"]}
    for r in record["runs"]:
        last = r["curve"][-1] if r["curve"] else None
        b = base.get(r["clip"])

        def fmt(v: Any, spec: str = ".3f") -> str:
            return "–" if v is None else format(v, spec)

        trk = last["tracking"]["delta_avg"] if last and last["tracking"] else None
        lines.append(
            f"| {r['clip']} | {r['preset']} | {r['steps']} | {r['train_seconds']:.0f} | {r['seconds_per_step']:.3f} | "
            f"{fmt(last and last['psnr'], '.2f')} / {fmt(last and last['best_psnr'], '.2f')} | "
            f"{fmt(last and last.get('fg_iou'))} | "
            f"{fmt(last and last['consistency_texels'], '.2f')} | {fmt(trk)} | {fmt(b and b['delta_avg'])} |"
        )
    return "\n".join(lines)


__all__ = [
    "BENCH_JSON",
    "BENCH_PNG",
    "BenchClip",
    "fit_eta_errors",
    "plot_bench",
    "record_expected_psnr",
    "resolve_clip",
    "run_bench",
    "summary_table",
]
