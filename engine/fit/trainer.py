"""The fit: prepare the clip (frames, masks, flow), build a model, optimise, checkpoint, evaluate.

Owns the loop, the optimiser, the schedule, checkpoints, signals and progress (nerfstudio's trainer role).
Progress goes to stdout as JSON lines (``contract.progress_line``) and to stderr as a tqdm bar.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from engine import contract as C
from engine.config import FitConfig
from engine.data.flow import DISFlow, FlowField, compute_flow
from engine.data.scene_analysis import SceneAnalysis, analyse_scene, read_scene_file, write_scene_file
from engine.data.scribbles import propagate_labels, read_scribbles, scribble_layers
from engine.data.video import VideoTensors, build_video_tensors, frame_pixels, sample_batch, sample_pixels
from engine.errors import InputError
from engine.fit.checkpoint import atomic_write_text, load_checkpoint, save_checkpoint
from engine.fit.eta import StepClock
from engine.io.clip import ClipInfo, open_clip, read_frames, read_masks, working_size
from engine.io.colour import linear_to_srgb
from engine.model.atlas_model import AtlasModel, FastModel, motion_regions
from engine.model.losses import psnr_from_mse
from engine.model.motion_init import LayerMotion, estimate_layer_motion
from engine.model.objective import compute_losses
from engine.model.paper_model import PaperModel

#: Pixels per forward chunk when evaluating whole frames (bounds memory of the evaluation).
EVAL_CHUNK = 65536


def select_device(name: str = "auto") -> torch.device:
    """CUDA, then MPS, then CPU for ``auto``; an explicit device that is absent is a one-line error."""
    if name == "auto":
        if torch.cuda.is_available():
            return torch.device("cuda")
        if getattr(torch.backends, "mps", None) and torch.backends.mps.is_available():
            return torch.device("mps")
        return torch.device("cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise InputError(None, "--device cuda: no CUDA device is available", "use --device auto or cpu")
    if name == "mps" and not (getattr(torch.backends, "mps", None) and torch.backends.mps.is_available()):
        raise InputError(None, "--device mps: MPS is not available", "use --device auto or cpu")
    if name not in ("cpu", "cuda", "mps"):
        raise InputError(None, f"unknown device {name!r}", "use auto, cpu, cuda or mps")
    return torch.device(name)


class Reporter:
    """JSON progress lines on stdout (for the add-on) and a human log file."""

    def __init__(self, log_path: Path | None, stream: Any = None) -> None:
        self.stream = stream or sys.stdout
        self.log_path = log_path

    def emit(self, event: str, **fields: Any) -> None:
        line = C.progress_line(event, **fields)
        print(line, file=self.stream, flush=True)
        if self.log_path is not None:
            with open(self.log_path, "a", encoding="utf-8") as f:
                f.write(line + "\n")


@dataclass
class PreparedClip:
    info: ClipInfo
    size: tuple[int, int]
    frames: np.ndarray  # float32 [T, H, W, 3], working resolution, fitting values in [0, 1]-ish
    masks: np.ndarray  # bool [F, T, H, W]
    mask_dirs: list[str]
    flow: FlowField
    fingerprint: str
    scribbles: np.ndarray | None = None  # int8 [T, H, W]: 0-based foreground layer, -1 = no scribble
    scribble_dir: str | None = None

    @property
    def mask_layers(self) -> tuple[tuple[int, ...], ...] | None:
        """Model layers each mask covers (None: one layer per mask); scribbles split the one mask."""
        if self.scribbles is None:
            return None
        return (tuple(range(1, 1 + scribble_layers(self.scribbles))),)

    @property
    def num_foreground(self) -> int:
        return self.masks.shape[0] if self.scribbles is None else scribble_layers(self.scribbles)


def to_fitting_values(frames: np.ndarray, colorspace: str) -> tuple[np.ndarray, list[int]]:
    """Frames as the values the model fits: display-encoded, finite. Returns the frames with NaN/Inf."""
    bad = [int(i) for i in np.nonzero(~np.isfinite(frames).reshape(len(frames), -1).all(1))[0]]
    out = np.nan_to_num(frames, nan=0.0, posinf=1.0, neginf=0.0)
    if colorspace == "linear":
        out = linear_to_srgb(np.clip(out, 0.0, None))
    return out.astype(np.float32), bad


def prepare_clip(
    clip: str | Path,
    mask_dirs: list[str | Path],
    cfg: FitConfig,
    run_dir: Path,
    frame_range: tuple[int, int] | None,
    reporter: Reporter,
    expect_fingerprint: str | None = None,
    scribble_dir: str | Path | None = None,
) -> PreparedClip:
    """Read, validate and sanitise the clip and masks, and compute (or load) its flow.

    ``expect_fingerprint`` (a resume): a clip whose frames changed is refused before its flow is computed,
    so the refusal is quick and writes nothing into the run folder.
    """
    info = open_clip(clip, frame_range)
    size = working_size(info.width, info.height, cfg.long_edge)
    reporter.emit(C.EVENT_STAGE, stage="read", message=f"reading {info.num_frames} frames at {size[0]}x{size[1]}")
    frames, bad = to_fitting_values(read_frames(info, size), info.colorspace)
    if bad:
        print(f"warning: NaN/Inf pixels replaced in frames {bad} of {info.source}", file=sys.stderr)
    masks = (
        np.stack([read_masks(m, info, size) for m in mask_dirs])
        if mask_dirs
        else np.zeros((0, len(frames), size[1], size[0]), dtype=bool)
    )
    scribbles = None
    if scribble_dir is not None:
        if len(mask_dirs) != 1:
            raise InputError(
                scribble_dir,
                f"scribbles split one object, but {len(mask_dirs)} mask folders were given",
                "pass exactly one --mask (the whole object) with --scribbles",
            )
        scribbles = read_scribbles(scribble_dir, info, size)
        if scribble_layers(scribbles) < 2:
            raise InputError(
                scribble_dir,
                "the scribbles use only the first colour (red), so they split nothing",
                "scribble the object's other part in green",
            )
    fingerprint = hashlib.sha256(memoryview(np.ascontiguousarray(frames)).cast("B")).hexdigest()[:32]
    if expect_fingerprint is not None and fingerprint != expect_fingerprint:
        raise InputError(
            info.source, "the clip changed since this run started", "fit it into a new --out instead of --resume"
        )
    if len(frames) < 2:  # a single frame has no flow: nothing is computed, nothing cached
        h, w = frames.shape[1:3]
        empty = np.zeros((0, h, w, 2), np.float32)
        ok = np.zeros((0, h, w), bool)
        flow = FlowField(empty, empty.copy(), ok, ok.copy(), DISFlow(cfg.flow_preset).name, cfg.flow_threshold_px)
    else:
        reporter.emit(C.EVENT_STAGE, stage="flow", message="optical flow (cached per clip content)")
        flow = compute_flow(
            frames.clip(0.0, 1.0),
            DISFlow(cfg.flow_preset),
            cache_dir=run_dir / C.FLOW_CACHE_DIR,
            threshold_px=cfg.flow_threshold_px,
        )
    return PreparedClip(
        info,
        size,
        frames,
        masks,
        [str(Path(m).resolve()) for m in mask_dirs],
        flow,
        fingerprint,
        scribbles,
        None if scribble_dir is None else str(Path(scribble_dir).resolve()),
    )


def build_model(
    cfg: FitConfig, clip: PreparedClip, scene: SceneAnalysis | None = None, saved_motions: list | None = None
) -> AtlasModel:
    """The model ``scene`` calls for (engine.data.scene_analysis); None = every component
    (runs from before the analysis).

    ``saved_motions`` (a checkpoint's ``motions``): the layers' starting motion and atlas boxes exactly as the
    fit built them, so a run reloads into the same shapes and scales whatever the engine version or the flow
    backend computes today."""
    t = clip.frames.shape[0]
    if cfg.model == "paper":
        model: AtlasModel = PaperModel(cfg, clip.size, t, num_layers=1 + clip.num_foreground)
        model.active_terms = None if scene is None else scene.term_set
        return model
    if cfg.model != "fast":
        raise InputError(None, f"unknown model {cfg.model!r}", "use --set model=fast or model=paper")
    flow = clip.flow if t > 1 else None
    background = C.BG_MOTION_DEFORMABLE if scene is None else scene.background_motion
    if saved_motions is not None:
        return _fast_model(cfg, clip, scene, background, [motion_from_state(m) for m in saved_motions])
    motions = []
    if clip.masks.shape[0]:
        bg_region, fg_regions = motion_regions(clip.masks)
    else:
        bg_region, fg_regions = None, []
    # a static camera's background is the identity: the flow's noise must not tilt it
    fit_bg = cfg.init_motion and background != C.BG_MOTION_STATIC
    motions.append(estimate_layer_motion(flow, bg_region, clip.size, fit_bg))
    if clip.scribbles is not None:
        # each part moves like its scribbles (carried to every frame by the flow); its atlas spans the object
        carried = propagate_labels(clip.scribbles, flow, clip.masks[0])
        for k in range(clip.num_foreground):
            region = carried == k
            motions.append(
                estimate_layer_motion(
                    flow, region, clip.size, cfg.init_motion, margin=cfg.atlas_margin_fg, extent_masks=fg_regions[0]
                )
            )
    else:
        # motion from the eroded mask (flow at object boundaries is unreliable), atlas box from the whole mask
        # (an eroded box cut the rim off small objects: a 30 px object lost 6 px on every side)
        for region, full in zip(fg_regions, clip.masks, strict=True):
            motions.append(
                estimate_layer_motion(
                    flow,
                    region,
                    clip.size,
                    cfg.init_motion,
                    margin=cfg.atlas_margin_fg,
                    extent_masks=full if cfg.atlas_box_full_mask else None,
                )
            )
    return _fast_model(cfg, clip, scene, background, motions)


def _fast_model(
    cfg: FitConfig, clip: PreparedClip, scene: SceneAnalysis | None, background: str, motions: list[LayerMotion]
) -> FastModel:
    t = clip.frames.shape[0]
    alpha_network = True if scene is None else (scene.alpha_network or len(motions) > 1)
    model = FastModel(cfg, clip.size, t, motions, background=background, alpha_network=alpha_network)
    model.active_terms = None if scene is None else scene.term_set
    return model


@torch.no_grad()
def evaluate_pixels(
    model: AtlasModel, video: VideoTensors, ix: torch.Tensor, iy: torch.Tensor, t: torch.Tensor
) -> float:
    """Mean squared error of the reconstruction at the given pixels."""
    total, count = 0.0, 0
    for s in range(0, ix.shape[0], EVAL_CHUNK):
        sl = slice(s, s + EVAL_CHUNK)
        xy = torch.stack((ix[sl], iy[sl]), -1).float() + 0.5
        rec, _ = model.reconstruct(xy, t[sl])
        total += float(((rec - video.frames[t[sl], iy[sl], ix[sl]]) ** 2).sum())
        count += rec.shape[0] * 3
    return total / max(count, 1)


@torch.no_grad()
def render_frame(
    model: AtlasModel, t: int, size: tuple[int, int], device: torch.device
) -> tuple[np.ndarray, np.ndarray]:
    """Reconstruction [H, W, 3] and layer weights [H, W, L] of one frame at working resolution."""
    w, h = size
    xy, tt = frame_pixels(size, t, device)
    recs, ws = [], []
    for s in range(0, xy.shape[0], EVAL_CHUNK):
        r, wgt = model.reconstruct(xy[s : s + EVAL_CHUNK], tt[s : s + EVAL_CHUNK])
        recs.append(r)
        ws.append(wgt)
    return torch.cat(recs).reshape(h, w, 3).cpu().numpy(), torch.cat(ws).reshape(h, w, -1).cpu().numpy()


@torch.no_grad()
def evaluate_full(model: AtlasModel, video: VideoTensors, size: tuple[int, int], device: torch.device) -> dict:
    """Full-frame PSNR over every pixel of every frame, and per-layer alpha IoU against the masks."""
    t_count = video.shape[0]
    sq, n = 0.0, 0
    inter = np.zeros(video.masks.shape[0])
    union = np.zeros(video.masks.shape[0])
    frames_np = video.frames.cpu().numpy()
    masks_np = video.masks.cpu().numpy()
    for t in range(t_count):
        rec, wts = render_frame(model, t, size, device)
        sq += float(((rec - frames_np[t]) ** 2).sum())
        n += rec.size
        for f in range(masks_np.shape[0]):
            group = video.mask_layers[f] if video.mask_layers is not None else (f + 1,)
            a = wts[..., list(group)].sum(-1) > 0.5
            m = masks_np[f, t]
            inter[f] += float((a & m).sum())
            union[f] += float((a | m).sum())
    mse = sq / max(n, 1)
    iou = [float(i / u) if u > 0 else 1.0 for i, u in zip(inter, union, strict=True)]
    return {"psnr": psnr_from_mse(mse), "mse": mse, "alpha_iou": iou}


class _Stop:
    """Signal flag: SIGINT/SIGTERM ask the loop to checkpoint and exit at the next step."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self._old: dict[int, Any] = {}

    def __enter__(self) -> _Stop:
        for s in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(ValueError):  # not the main thread (tests calling fit in a thread)
                self._old[s] = signal.signal(s, self._handle)
        return self

    def _handle(self, signum: int, _frame: Any) -> None:
        self.signum = signum

    def __exit__(self, *exc: Any) -> None:
        for s, h in self._old.items():
            signal.signal(s, h)


class FitCancelled(Exception):
    """The fit was interrupted by a signal after writing a checkpoint."""


def make_optimizer(model: AtlasModel, cfg: FitConfig, device: torch.device) -> torch.optim.Optimizer:
    """Adam; the fused kernel where the device has one (on CPU it halves the cost of updating dense grids)."""
    groups = model.param_groups(cfg)
    try:
        return torch.optim.Adam(groups, fused=device.type in ("cpu", "cuda"))
    except (RuntimeError, TypeError):
        return torch.optim.Adam(groups)


def train_step(
    model: AtlasModel,
    video: VideoTensors,
    cfg: FitConfig,
    optim: torch.optim.Optimizer,
    sched: torch.optim.lr_scheduler.LRScheduler,
    gen: torch.Generator,
    step: int,
    device: torch.device,
) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """One optimisation step at ``step`` (the loss weights in force there); ``fit`` and ``bench`` share it."""
    ix, iy, tt = sample_batch(video, cfg.batch, cfg.object_sample_share, gen, device)
    loss, terms = compute_losses(model, video, cfg, step, ix, iy, tt)
    optim.zero_grad(set_to_none=True)
    loss.backward()
    optim.step()
    sched.step()
    return loss, terms


#: The ETA measures the two cost regimes' ratio before training only when the early one (global rigidity on)
#: is at least this share of the steps; below it (the paper preset: 5000 of 400000) a wrong guess costs
#: little and the probe's steps (seconds each for the paper model) would not pay for themselves.
REGIME_PROBE_MIN_SHARE = 0.05
#: ... and only for fits of at least this many steps: the probe costs about five steps, under 1% here, and a
#: shorter fit is over before an ETA matters (the stability tests' tiny fits count every objective call).
REGIME_PROBE_MIN_STEPS = 500


def regime_cost_ratio(
    model: AtlasModel, video: VideoTensors, cfg: FitConfig, device: torch.device, repeats: int = 2
) -> float | None:
    """Seconds of a step after the global-rigidity term ends over one while it is on (forward and backward,
    the best of ``repeats``), so the ETA of a fit still in the early regime does not assume the later steps
    cost as much. The fit's state is untouched: its own generator, no optimiser step, gradients cleared."""
    boundary = cfg.global_rigidity_steps
    if not (0 < boundary < cfg.steps) or boundary < REGIME_PROBE_MIN_SHARE * cfg.steps:
        return None
    if cfg.steps < REGIME_PROBE_MIN_STEPS:
        return None
    gen = torch.Generator().manual_seed(cfg.seed + 104_729)

    def timed(step: int) -> float:
        ix, iy, tt = sample_batch(video, cfg.batch, cfg.object_sample_share, gen, device)
        t0 = time.perf_counter()
        loss, _ = compute_losses(model, video, cfg, step, ix, iy, tt)
        loss.backward()
        if device.type == "cuda":
            torch.cuda.synchronize()
        seconds = time.perf_counter() - t0
        model.zero_grad(set_to_none=True)
        return seconds

    timed(0)  # warm-up: allocator, kernels
    early = min(timed(0) for _ in range(repeats))
    late = min(timed(boundary) for _ in range(repeats))
    return late / early if early > 0 else None


def _lr_lambda(cfg: FitConfig) -> Callable[[int], float]:
    ratio = max(cfg.lr_final_ratio, 1e-6)
    steps = max(cfg.steps, 1)
    return lambda s: ratio ** (min(s, steps) / steps)


def make_scheduler(optim: torch.optim.Optimizer, cfg: FitConfig) -> torch.optim.lr_scheduler.LambdaLR:
    """The fit's learning-rate schedule: exponential decay to ``lr_final_ratio`` at ``cfg.steps``."""
    return torch.optim.lr_scheduler.LambdaLR(optim, _lr_lambda(cfg))


def fit(
    clip: str | Path | None,
    mask_dirs: list[str | Path],
    run_dir: str | Path,
    cfg: FitConfig,
    device_name: str = "auto",
    resume: bool = False,
    frame_range: tuple[int, int] | None = None,
    progress_bar: bool = True,
    stream: Any = None,
    scribble_dir: str | Path | None = None,
    auto_masks: bool = False,
) -> dict[str, Any]:
    """Fit a layered atlas to ``clip``; writes config, clip record, scene analysis, checkpoint and metrics
    into ``run_dir``. ``auto_masks``: no masks given, find them from motion (written to RUN_DIR/auto_masks
    for the artist to check) and fit with them; nothing moving gives a background-only fit. ``scribble_dir``:
    red/green/... strokes that split the one mask's object into several foreground layers (paper Sec. 4.4)."""
    run_dir = Path(run_dir)
    ckpt_path = run_dir / C.RUN_CHECKPOINT
    if resume:
        clip_rec = _read_json(run_dir / C.RUN_CLIP)
        clip = clip or clip_rec["source"]
        mask_dirs = mask_dirs or clip_rec["masks"]
        frame_range = frame_range or tuple(clip_rec["frame_range"])  # type: ignore[assignment]
        scribble_dir = scribble_dir or clip_rec.get("scribbles")
    else:
        if ckpt_path.exists():
            raise InputError(
                run_dir,
                "this folder already holds a fit",
                "pass --resume to continue it, or choose a new --out",
            )
        if clip is None:
            raise InputError(None, "no clip given", "pass a frame folder or movie file")
    _check_writable(run_dir)
    device = select_device(device_name)
    torch.manual_seed(cfg.seed)
    # the input is read and validated before anything is written: bad input leaves no run folder behind
    reporter = Reporter(None, stream)
    expect = clip_rec.get("fingerprint") if resume else None
    layers_source, masks_note = None, None
    if auto_masks and not resume:
        if mask_dirs:
            raise InputError(None, f"{C.FIT_AUTO_MASKS_FLAG} and --mask both given", "pass one of them")
        mask_dirs, masks_note = _find_auto_masks(clip, run_dir, frame_range, reporter)  # type: ignore[arg-type]
        layers_source = C.SCENE_LAYERS_AUTO
    prepared = prepare_clip(clip, mask_dirs, cfg, run_dir, frame_range, reporter, expect, scribble_dir)  # type: ignore[arg-type]
    run_dir.mkdir(parents=True, exist_ok=True)
    reporter.log_path = run_dir / C.RUN_LOG
    info = prepared.info
    first = frame_range[0] if frame_range else 0
    clip_record = {
        "schema": C.SCHEMA_VERSION,
        "source": info.source,
        "kind": info.kind,
        "frame_range": [first, first + info.num_frames - 1],
        "frame_numbers": list(info.frame_numbers),
        "native_size": [info.width, info.height],
        "working_size": list(prepared.size),
        "fps": info.fps,
        "colorspace": info.colorspace,
        "masks": prepared.mask_dirs,
        "fingerprint": prepared.fingerprint,
    }
    if prepared.scribble_dir is not None:
        clip_record["scribbles"] = prepared.scribble_dir
    state = None
    if resume:
        if clip_rec.get("fingerprint") != prepared.fingerprint:
            raise InputError(
                info.source,
                "the clip changed since this run started",
                "fit it into a new --out instead of --resume",
            )
        state = load_checkpoint(ckpt_path, device)
        scene = read_scene_file(run_dir)  # None: a run from before the analysis, resumed as it was built
    else:
        scene = analyse_scene(
            prepared.frames.shape[0],
            prepared.flow,
            prepared.masks,
            cfg,
            layers_source=layers_source,
            scribbles=0 if prepared.scribbles is None else int((prepared.scribbles >= 0).any((1, 2)).sum()),
            masks_note=masks_note,
            foreground_layers=prepared.num_foreground,
        )
        atomic_write_text(run_dir / C.RUN_CONFIG, cfg.to_json())
        atomic_write_text(run_dir / C.RUN_CLIP, json.dumps(clip_record, indent=2))
        write_scene_file(run_dir, scene)
    if scene is not None:
        reporter.emit(C.EVENT_STAGE, stage="scene", message=scene.summary(), scene=scene.to_dict())

    reporter.emit(C.EVENT_STAGE, stage="init", message=f"building the {cfg.model} model on {device.type}")
    model = build_model(cfg, prepared, scene, None if state is None else state.get("motions")).to(device)
    video = build_video_tensors(
        prepared.frames,
        prepared.masks,
        prepared.flow,
        cfg.mask_prior_margin_px,
        device,
        prepared.scribbles,
        prepared.mask_layers,
    )
    optim = make_optimizer(model, cfg, device)
    sched = torch.optim.lr_scheduler.LambdaLR(optim, _lr_lambda(cfg))
    gen = torch.Generator().manual_seed(cfg.seed)
    step, train_seconds = 0, 0.0
    if state is not None:
        model.load_state_dict(state["model"])
        optim.load_state_dict(state["optim"])
        sched.load_state_dict(state["sched"])
        gen.set_state(state["gen"].cpu())
        step, train_seconds = int(state["step"]), float(state["train_seconds"])
    else:
        t0 = time.perf_counter()
        model.prepare(cfg, device)
        train_seconds += time.perf_counter() - t0

    eval_gen = torch.Generator().manual_seed(cfg.seed + 7919)
    ex, ey, et = sample_pixels(video.shape, cfg.eval_pixels, eval_gen, device)

    def checkpoint() -> None:
        save_checkpoint(
            ckpt_path,
            {
                "schema": C.SCHEMA_VERSION,
                "model": model.state_dict(),
                "optim": optim.state_dict(),
                "sched": sched.state_dict(),
                "gen": gen.get_state(),
                "step": step,
                "train_seconds": train_seconds,
                "fingerprint": prepared.fingerprint,
                "motions": model_motions(model),
            },
        )
        reporter.emit(C.EVENT_CHECKPOINT, step=step, path=str(ckpt_path))

    reporter.emit(C.EVENT_STAGE, stage="train", message=f"{cfg.steps} steps, preset {cfg.preset}")
    bar = tqdm(
        total=cfg.steps,
        initial=step,
        disable=not progress_bar,
        file=sys.stderr,
        unit="step",
        dynamic_ncols=True,
    )
    last_ckpt = time.monotonic()
    # the ETA extrapolates this session's steps only (not calibration, not time before a resume), each cost
    # regime at its own rate (engine.fit.eta)
    clock = StepClock(cfg.global_rigidity_steps, regime_cost_ratio(model, video, cfg, device))
    terms: dict[str, torch.Tensor] = {}
    with _Stop() as stop:
        while step < cfg.steps:
            t0 = time.perf_counter()
            loss, terms = train_step(model, video, cfg, optim, sched, gen, step, device)
            dt = time.perf_counter() - t0
            clock.add(step, dt)
            step += 1
            train_seconds += dt
            bar.update(1)
            if step % cfg.eval_every == 0 or step == cfg.steps or step == 1:
                psnr = psnr_from_mse(evaluate_pixels(model, video, ex, ey, et))
                eta = clock.eta(step, cfg.steps)
                reporter.emit(
                    C.EVENT_PROGRESS,
                    step=step,
                    total=cfg.steps,
                    psnr=round(psnr, 3),
                    elapsed=round(train_seconds, 2),
                    eta=None if eta is None else round(eta, 1),
                    losses={k: round(float(v.detach()), 6) for k, v in terms.items()},
                )
                bar.set_postfix(psnr=f"{psnr:.2f}")
                if not np.isfinite(float(loss.detach())):
                    raise RuntimeError(f"loss became non-finite at step {step}: {terms}")
            if stop.signum is not None:
                checkpoint()
                bar.close()
                reporter.emit(C.EVENT_CANCELLED, step=step, checkpoint=str(ckpt_path))
                raise FitCancelled(f"interrupted by signal {stop.signum} at step {step}")
            if time.monotonic() - last_ckpt > cfg.checkpoint_seconds:
                checkpoint()
                last_ckpt = time.monotonic()
    bar.close()
    checkpoint()
    reporter.emit(C.EVENT_STAGE, stage="evaluate", message="full-frame PSNR over every pixel")
    ev = evaluate_full(model, video, prepared.size, device)
    metrics = {
        "schema": C.SCHEMA_VERSION,
        "psnr": ev["psnr"],
        "mse": ev["mse"],
        "alpha_iou": ev["alpha_iou"],
        "steps": step,
        "train_seconds": train_seconds,
        "seconds_per_step": train_seconds / max(step, 1),
        "preset": cfg.preset,
        "model": cfg.model,
        "device": device.type,
        "working_size": list(prepared.size),
        "frames": int(video.shape[0]),
        "engine_version": C.ENGINE_VERSION,
        "torch_version": torch.__version__,
    }
    atomic_write_text(run_dir / C.RUN_METRICS, json.dumps(metrics, indent=2))
    reporter.emit(C.EVENT_DONE, metrics=metrics)
    return metrics


def load_run(run_dir: str | Path, device_name: str = "cpu") -> tuple[AtlasModel, PreparedClip, FitConfig]:
    """A finished (or checkpointed) fit: its model with the checkpoint's weights, its clip, its config."""
    run_dir = Path(run_dir)
    cfg = FitConfig.from_json((run_dir / C.RUN_CONFIG).read_text(encoding="utf-8"), run_dir / C.RUN_CONFIG)
    rec = _read_json(run_dir / C.RUN_CLIP)
    frame_range = (int(rec["frame_range"][0]), int(rec["frame_range"][1]))
    reporter = Reporter(None, io.StringIO())
    prepared = prepare_clip(
        rec["source"], rec["masks"], cfg, run_dir, frame_range, reporter, scribble_dir=rec.get("scribbles")
    )
    device = select_device(device_name)
    state = load_checkpoint(run_dir / C.RUN_CHECKPOINT, device)
    model = build_model(cfg, prepared, read_scene_file(run_dir), state.get("motions")).to(device)
    model.load_state_dict(state["model"])
    return model.eval(), prepared, cfg


def _find_auto_masks(
    clip: str | Path, run_dir: Path, frame_range: tuple[int, int] | None, reporter: Reporter
) -> tuple[list[str | Path], str]:
    """``fit --auto-masks``: masks from motion into RUN_DIR/auto_masks (PNGs the artist can check and fix,
    then fit again with ``--mask``). Returns the mask folders to fit with (none when nothing moves) and the
    analysis' one-line message for the scene record."""
    from engine.data.auto_masks import write_auto_masks

    info = open_clip(clip, frame_range)
    if info.num_frames < 2:
        return [], "a single frame has no motion to find an object by"
    folder = run_dir / C.AUTO_MASKS_DIR
    reporter.emit(C.EVENT_STAGE, stage="masks", message=f"finding moving objects; masks go to {folder}")
    report = write_auto_masks(clip, folder, frame_range)
    print(f"auto masks: {report.result.message} ({folder})", file=sys.stderr)
    if not report.result.found:
        return [], report.result.message
    return [folder], report.result.message


def model_motions(model: AtlasModel) -> list[dict[str, Any]] | None:
    """The fast model's per-layer starting motion and atlas box, for the checkpoint (None: other models)."""
    motions = getattr(model, "layer_motions", None)
    if motions is None:
        return None
    return [
        {
            "to_ref": torch.from_numpy(np.asarray(m.to_ref, np.float64)),
            "center": torch.from_numpy(np.asarray(m.center, np.float64)),
            "half_extent": float(m.half_extent),
            "aspect": [float(a) for a in m.aspect],
        }
        for m in motions
    ]


def motion_from_state(rec: dict[str, Any]) -> LayerMotion:
    return LayerMotion(
        to_ref=rec["to_ref"].cpu().numpy().astype(np.float64),
        center=rec["center"].cpu().numpy().astype(np.float64),
        half_extent=float(rec["half_extent"]),
        aspect=(float(rec["aspect"][0]), float(rec["aspect"][1])),
    )


def _check_writable(run_dir: Path) -> None:
    """One-line error if ``run_dir`` (or the nearest folder that exists above it) cannot be written."""
    probe = run_dir
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    if not (probe.is_dir() and os.access(probe, os.W_OK | os.X_OK)):
        raise InputError(run_dir, "output folder is not writable", "choose a folder you can write to with --out")


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(
            path, "this run folder has no record of its clip", "resume a folder written by `fit`"
        ) from None
    except json.JSONDecodeError:
        raise InputError(path, "not valid JSON", "restore it or fit into a new --out") from None
    if data.get("schema") != C.SCHEMA_VERSION:
        raise InputError(path, f"run schema {data.get('schema')!r} is incompatible", "fit into a new --out")
    return data


__all__ = [
    "FitCancelled",
    "PreparedClip",
    "build_model",
    "fit",
    "prepare_clip",
    "render_frame",
    "select_device",
    "train_step",
]
