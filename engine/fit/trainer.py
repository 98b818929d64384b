"""The fit's training loop: ``Trainer`` (in the way of nerfstudio's Trainer) sets up a fit of a prepared clip
(model, pixel tensors, optimiser, schedule, sampling generator), steps, evaluates, saves and restores it; ``fit``
runs it on a clip into a run folder. The bench, ``estimate`` and the speed table train through the same object.

Progress goes to stdout as JSON lines (``contract.progress_line``) and to stderr as a tqdm bar.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from engine import contract as C
from engine.config import FitConfig
from engine.data.scene_analysis import SceneAnalysis
from engine.data.scribbles import propagate_labels
from engine.data.video import VideoTensors, build_video_tensors, frame_pixels, sample_batch, sample_pixels
from engine.errors import InputError
from engine.fit.device import select_device, synchronize
from engine.fit.eta import StepClock
from engine.fit.prepare import PreparedClip, prepare_clip
from engine.fit.progress import Reporter
from engine.fit.run_folder import ClipRecord, RunFolder
from engine.model.atlas_model import AtlasModel, FastModel, motion_regions
from engine.model.losses import psnr_from_mse
from engine.model.motion_init import LayerMotion, estimate_layer_motion
from engine.model.objective import compute_losses
from engine.model.paper_model import PaperModel

#: Pixels per forward chunk when evaluating whole frames (bounds memory of the evaluation).
EVAL_CHUNK = 65536
#: The live PSNR's fixed pixel sample is drawn with seed ``cfg.seed + EVAL_SEED_OFFSET`` (apart from training's).
EVAL_SEED_OFFSET = 7919
#: The regime cost probe draws its batches with seed ``cfg.seed + PROBE_SEED_OFFSET`` (the fit's own are untouched).
PROBE_SEED_OFFSET = 104_729
#: A foreground alpha above this counts as the layer's when comparing it with its mask (alpha IoU).
ALPHA_IOU_THRESHOLD = 0.5
#: The learning rate's decay never goes below this fraction (a zero ratio would stop the decay's logarithm).
MIN_LR_RATIO = 1e-6


# --- the model a clip calls for -----------------------------------------------------------------------------


def build_model(cfg: FitConfig, clip: PreparedClip, scene: SceneAnalysis | None = None) -> AtlasModel:
    """A new model for ``clip``: the components ``scene`` calls for (engine.data.scene_analysis; None = every
    component), the fast model's layers starting at the motion the flow shows inside their masks."""
    t = clip.frames.shape[0]
    if cfg.model == "paper":
        return assemble_model(cfg, clip.size, t, 1 + clip.num_foreground, scene, None)
    if cfg.model != "fast":
        raise InputError(None, f"unknown model {cfg.model!r}", "use --set model=fast or model=paper")
    flow = clip.flow if t > 1 else None
    background = C.BG_MOTION_DEFORMABLE if scene is None else scene.background_motion
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
        # (an eroded box cut the rim off small objects)
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
    return assemble_model(cfg, clip.size, t, len(motions), scene, motions)


def assemble_model(
    cfg: FitConfig,
    size: tuple[int, int],
    frames: int,
    layers: int,
    scene: SceneAnalysis | None,
    motions: list[LayerMotion] | None,
) -> AtlasModel:
    """The model of ``layers`` layers over ``frames`` frames of ``size`` (W, H) with ``scene``'s components; the
    fast model's layers start at ``motions``. What ``build_model`` makes for a new fit and ``rebuild_model``
    for a saved one."""
    if cfg.model == "paper":
        model: AtlasModel = PaperModel(cfg, size, frames, num_layers=layers)
    elif cfg.model == "fast":
        if motions is None or len(motions) != layers:
            raise InputError(
                None,
                f"the fast model needs a starting motion for each of its {layers} layers",
                C.RUN_FILE_OTHER_VERSION_FIX,
            )
        background = C.BG_MOTION_DEFORMABLE if scene is None else scene.background_motion
        alpha_network = True if scene is None else (scene.alpha_network or len(motions) > 1)
        model = FastModel(cfg, size, frames, motions, background=background, alpha_network=alpha_network)
    else:
        raise InputError(None, f"unknown model {cfg.model!r}", "use --set model=fast or model=paper")
    model.active_terms = None if scene is None else scene.term_set
    return model


def rebuild_model(
    cfg: FitConfig, clip: ClipRecord, scene: SceneAnalysis, saved_motions: list[dict[str, Any]] | None
) -> AtlasModel:
    """The model a checkpoint was saved from, built from the run folder alone (no frames, masks or flow): the
    fast model's layers start at the motions the fit saved, so a run reloads into the same shapes and scales
    whatever the engine version or the flow backend would compute today."""
    motions = None if saved_motions is None else [motion_from_state(m) for m in saved_motions]
    return assemble_model(cfg, clip.working_size, clip.num_frames, clip.layers, scene, motions)


# --- evaluation --------------------------------------------------------------------------------------------


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
            a = wts[..., list(group)].sum(-1) > ALPHA_IOU_THRESHOLD
            m = masks_np[f, t]
            inter[f] += float((a & m).sum())
            union[f] += float((a | m).sum())
    mse = sq / max(n, 1)
    iou = [float(i / u) if u > 0 else 1.0 for i, u in zip(inter, union, strict=True)]
    return {"psnr": psnr_from_mse(mse), "mse": mse, "alpha_iou": iou}


# --- optimisation ------------------------------------------------------------------------------------------


def make_optimizer(model: AtlasModel, cfg: FitConfig, device: torch.device) -> torch.optim.Optimizer:
    """Adam; the fused kernel where the device has one (on CPU it halves the cost of updating dense grids)."""
    groups = model.param_groups(cfg)
    try:
        return torch.optim.Adam(groups, fused=device.type in ("cpu", "cuda"))
    except (RuntimeError, TypeError):
        return torch.optim.Adam(groups)


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
    gen = torch.Generator().manual_seed(cfg.seed + PROBE_SEED_OFFSET)

    def timed(step: int) -> float:
        ix, iy, tt = sample_batch(video, cfg.batch, cfg.object_sample_share, gen, device)
        t0 = time.perf_counter()
        loss, _ = compute_losses(model, video, cfg, step, ix, iy, tt)
        loss.backward()
        synchronize(device)
        seconds = time.perf_counter() - t0
        model.zero_grad(set_to_none=True)
        return seconds

    timed(0)  # warm-up: allocator, kernels
    early = min(timed(0) for _ in range(repeats))
    late = min(timed(boundary) for _ in range(repeats))
    return late / early if early > 0 else None


def make_scheduler(optim: torch.optim.Optimizer, cfg: FitConfig) -> torch.optim.lr_scheduler.LambdaLR:
    """The fit's learning-rate schedule: exponential decay to ``lr_final_ratio`` at ``cfg.steps``."""
    ratio = max(cfg.lr_final_ratio, MIN_LR_RATIO)
    steps = max(cfg.steps, 1)
    return torch.optim.lr_scheduler.LambdaLR(optim, lambda s: ratio ** (min(s, steps) / steps))


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


# --- the training loop --------------------------------------------------------------------------------------


class Trainer:
    """One fit of a prepared clip: its model, pixel tensors, optimiser, learning-rate schedule, sampling generator,
    step count and training clock.

    ``Trainer(cfg, clip, scene, device)`` sets a new fit up (the same seed gives the same model); with ``state``
    (a checkpoint) it continues one. ``calibrate`` runs the model's own set-up, ``train_step`` trains the next
    step, ``optimise`` one step at a given step's loss weights (the timed steps of ``estimate`` and the speed
    table), ``evaluate_sample``/``evaluate_full`` measure, ``save``/``state_dict``/``restore`` are the
    checkpoint, and ``train`` is the loop of ``fit``. ``video``: pixel tensors shared by several trainers of the
    same clip (the bench and the estimate try several presets on one clip).
    """

    def __init__(
        self,
        cfg: FitConfig,
        clip: PreparedClip,
        scene: SceneAnalysis | None,
        device: torch.device,
        video: VideoTensors | None = None,
        state: dict[str, Any] | None = None,
    ) -> None:
        self.cfg, self.clip, self.scene, self.device = cfg, clip, scene, device
        torch.manual_seed(cfg.seed)  # the model's initial weights
        if state is None:
            model = build_model(cfg, clip, scene)
        else:
            motions = None if state["motions"] is None else [motion_from_state(m) for m in state["motions"]]
            model = assemble_model(cfg, clip.size, clip.frames.shape[0], 1 + clip.num_foreground, scene, motions)
        self.model = model.to(device)
        if video is None:
            video = build_video_tensors(
                clip.frames, clip.masks, clip.flow, cfg.mask_prior_margin_px, device, clip.scribbles, clip.mask_layers
            )
        self.video = video
        self.optim = make_optimizer(self.model, cfg, device)
        self.sched = make_scheduler(self.optim, cfg)
        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.step = 0  # steps done: the next step's index
        self.train_seconds = 0.0  # optimisation steps and the model's calibration, nothing else
        #: seconds per step since this start or resume, per cost regime: the ETA (set up at the first ``train_step``)
        self.clock: StepClock | None = None
        self._sample: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None
        if state is not None:
            self.restore(state)

    def calibrate(self) -> None:
        """The model's own set-up before its first step (the paper model pre-trains its mappings), counted as
        training time as the fit counts it."""
        t0 = time.perf_counter()
        self.model.prepare(self.cfg, self.device)
        self.train_seconds += time.perf_counter() - t0

    def optimise(self, at: int) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """One optimisation step with the loss weights in force at step ``at``; the step count and the clock are
        left as they are."""
        cfg, video = self.cfg, self.video
        ix, iy, tt = sample_batch(video, cfg.batch, cfg.object_sample_share, self.gen, self.device)
        loss, terms = compute_losses(self.model, video, cfg, at, ix, iy, tt)
        self.optim.zero_grad(set_to_none=True)
        loss.backward()
        self.optim.step()
        self.sched.step()
        return loss, terms

    def train_step(self) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The fit's next step, timed into ``train_seconds`` and the clock (first-call set-up: the cost ratio of
        the two regimes, measured off the clock with ``regime_cost_ratio``)."""
        if self.clock is None:
            ratio = regime_cost_ratio(self.model, self.video, self.cfg, self.device)
            self.clock = StepClock(self.cfg.global_rigidity_steps, ratio)
        t0 = time.perf_counter()
        loss, terms = self.optimise(self.step)
        synchronize(self.device)
        dt = time.perf_counter() - t0
        self.clock.add(self.step, dt)
        self.step += 1
        self.train_seconds += dt
        return loss, terms

    @property
    def finished(self) -> bool:
        return self.step >= self.cfg.steps

    def eta(self) -> float | None:
        """Seconds of training left (None before the clock has a rate)."""
        return None if self.clock is None else self.clock.eta(self.step, self.cfg.steps)

    def evaluate_sample(self) -> float:
        """PSNR on the fit's fixed sample of ``eval_pixels`` pixels (the live PSNR of the progress lines)."""
        if self._sample is None:
            gen = torch.Generator().manual_seed(self.cfg.seed + EVAL_SEED_OFFSET)
            self._sample = sample_pixels(self.video.shape, self.cfg.eval_pixels, gen, self.device)
        return psnr_from_mse(evaluate_pixels(self.model, self.video, *self._sample))

    def evaluate_full(self) -> dict:
        """Full-frame PSNR over every pixel of every frame, and each mask's alpha IoU (``evaluate_full``)."""
        return evaluate_full(self.model, self.video, self.clip.size, self.device)

    def state_dict(self) -> dict[str, Any]:
        """Everything a resume needs to continue exactly: weights, optimiser, schedule, sampling state, clock,
        and the layers' starting motions (the model's shapes)."""
        return {
            "model": self.model.state_dict(),
            "optim": self.optim.state_dict(),
            "sched": self.sched.state_dict(),
            "gen": self.gen.get_state(),
            "step": self.step,
            "train_seconds": self.train_seconds,
            "fingerprint": self.clip.fingerprint,
            "motions": model_motions(self.model),
        }

    def restore(self, state: dict[str, Any]) -> None:
        self.model.load_state_dict(state["model"])
        self.optim.load_state_dict(state["optim"])
        self.sched.load_state_dict(state["sched"])
        self.gen.set_state(state["gen"].cpu())
        self.step, self.train_seconds = int(state["step"]), float(state["train_seconds"])

    def save(self, run: RunFolder, reporter: Reporter) -> None:
        run.save_checkpoint(self.state_dict())
        reporter.emit(C.EVENT_CHECKPOINT, step=self.step, path=str(run.checkpoint))

    def train(self, run: RunFolder, reporter: Reporter, progress_bar: bool = True) -> None:
        """The fit's loop up to ``cfg.steps``: a progress line (live PSNR, ETA, loss terms) at the first step,
        every ``eval_every`` steps and the last; a checkpoint every ``checkpoint_seconds``, at the end, and at
        SIGINT/SIGTERM, which then raise ``FitCancelled``."""
        cfg = self.cfg
        reporter.emit(C.EVENT_STAGE, stage="train", message=f"{cfg.steps} steps, preset {cfg.preset}")
        bar = tqdm(
            total=cfg.steps,
            initial=self.step,
            disable=not progress_bar,
            file=sys.stderr,
            unit="step",
            dynamic_ncols=True,
        )
        last_ckpt = time.monotonic()
        with _Stop() as stop:
            while not self.finished:
                loss, terms = self.train_step()
                bar.update(1)
                if self.step % cfg.eval_every == 0 or self.step == cfg.steps or self.step == 1:
                    psnr = self.evaluate_sample()
                    eta = self.eta()
                    reporter.emit(
                        C.EVENT_PROGRESS,
                        step=self.step,
                        total=cfg.steps,
                        psnr=round(psnr, 3),
                        elapsed=round(self.train_seconds, 2),
                        eta=None if eta is None else round(eta, 1),
                        losses={k: round(float(v.detach()), 6) for k, v in terms.items()},
                    )
                    bar.set_postfix(psnr=f"{psnr:.2f}")
                    if not np.isfinite(float(loss.detach())):
                        raise RuntimeError(f"loss became non-finite at step {self.step}: {terms}")
                if stop.signum is not None:
                    self.save(run, reporter)
                    bar.close()
                    reporter.emit(C.EVENT_CANCELLED, step=self.step, checkpoint=str(run.checkpoint))
                    raise FitCancelled(f"interrupted by signal {stop.signum} at step {self.step}")
                if time.monotonic() - last_ckpt > cfg.checkpoint_seconds:
                    self.save(run, reporter)
                    last_ckpt = time.monotonic()
        bar.close()
        self.save(run, reporter)


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
    refit: bool = False,
) -> dict[str, Any]:
    """Fit a layered atlas to ``clip``; writes config, clip record, scene analysis, checkpoint and metrics
    into ``run_dir``. ``auto_masks``: no masks given, find them from motion (written to RUN_DIR/auto_masks
    for the artist to check) and fit with them; nothing moving gives a background-only fit. ``scribble_dir``:
    red/green/... strokes that split the one mask's object into several foreground layers (paper Sec. 4.4)."""
    run = RunFolder(run_dir)
    expect = None
    if resume:
        record = run.read_clip()
        clip = clip or record.source
        mask_dirs = mask_dirs or list(record.masks)
        frame_range = frame_range or record.frame_range
        scribble_dir = scribble_dir or record.scribbles
        expect = record.fingerprint
    else:
        if run.holds_fit() and not refit:
            raise InputError(
                run.path, "this folder already holds a fit", "pass --resume to continue it, or choose a new --out"
            )
        if clip is None:
            raise InputError(None, "no clip given", "pass a frame folder or movie file")
    run.check_writable()
    device = select_device(device_name)
    # the input is read and validated before anything is written: bad input leaves no run folder behind
    reporter = Reporter(stream=stream)
    find_masks = auto_masks and not resume
    if find_masks and mask_dirs:
        raise InputError(None, f"{C.FIT_AUTO_MASKS_FLAG} and --mask both given", "pass one of them")
    prepared = prepare_clip(
        clip, mask_dirs, cfg, run.path, frame_range, reporter, expect, scribble_dir, auto_masks=find_masks
    )
    run.path.mkdir(parents=True, exist_ok=True)
    reporter.log_path = run.log
    state = None
    if resume:
        state = run.load_checkpoint(device)
        scene = run.read_scene()
    else:
        scene = prepared.analyse(cfg)
        run.write_config(cfg)
        run.write_clip(prepared.record())
        run.write_scene(scene)
    reporter.emit(C.EVENT_STAGE, stage="scene", message=scene.summary(), scene=scene.to_dict())

    reporter.emit(C.EVENT_STAGE, stage="init", message=f"building the {cfg.model} model on {device.type}")
    trainer = Trainer(cfg, prepared, scene, device, state=state)
    if state is None:
        trainer.calibrate()
    trainer.train(run, reporter, progress_bar)
    reporter.emit(C.EVENT_STAGE, stage="evaluate", message="full-frame PSNR over every pixel")
    ev = trainer.evaluate_full()
    metrics = {
        "schema": C.RUN_METRICS_SCHEMA,
        "psnr": ev["psnr"],
        "mse": ev["mse"],
        "alpha_iou": ev["alpha_iou"],
        "steps": trainer.step,
        "train_seconds": trainer.train_seconds,
        "seconds_per_step": trainer.train_seconds / max(trainer.step, 1),
        "preset": cfg.preset,
        "model": cfg.model,
        "device": device.type,
        "working_size": list(prepared.size),
        "frames": int(trainer.video.shape[0]),
        "engine_version": C.ENGINE_VERSION,
        "torch_version": torch.__version__,
    }
    run.write_metrics(metrics)
    reporter.emit(C.EVENT_DONE, metrics=metrics)
    return metrics


# --- a fitted run, loaded back ------------------------------------------------------------------------------


@dataclass
class FittedRun:
    """A fit as its run folder holds it, loaded without its clip: what ``export`` works from."""

    folder: RunFolder
    cfg: FitConfig
    clip: ClipRecord
    scene: SceneAnalysis
    model: AtlasModel
    metrics: dict[str, Any] | None  # None: the fit has not finished


def load_fitted(run_dir: str | Path, device_name: str = "cpu") -> FittedRun:
    """The model of a finished (or checkpointed) fit with its weights, from the run folder alone: the plate,
    masks, scribbles and flow are not read."""
    run = RunFolder(run_dir)
    cfg = run.read_config()
    record = run.read_clip()
    scene = run.read_scene()
    device = select_device(device_name)
    state = run.load_checkpoint(device)
    model = rebuild_model(cfg, record, scene, state["motions"]).to(device)
    model.load_state_dict(state["model"])
    return FittedRun(run, cfg, record, scene, model.eval(), run.read_metrics())


def load_run(run_dir: str | Path, device_name: str = "cpu") -> tuple[AtlasModel, PreparedClip, FitConfig]:
    """A finished (or checkpointed) fit's model with its weights, its clip prepared again (frames, masks, flow
    from the cache) and its config: for looking at a fit against its plate (the demo's contact sheet)."""
    fitted = load_fitted(run_dir, device_name)
    record = fitted.clip
    prepared = prepare_clip(
        record.source,
        list(record.masks),
        fitted.cfg,
        fitted.folder.path,
        record.frame_range,
        scribble_dir=record.scribbles,
    )
    return fitted.model, prepared, fitted.cfg


__all__ = [
    "EVAL_CHUNK",
    "FitCancelled",
    "FittedRun",
    "PreparedClip",
    "Reporter",
    "Trainer",
    "build_model",
    "fit",
    "load_fitted",
    "load_run",
    "make_optimizer",
    "make_scheduler",
    "prepare_clip",
    "rebuild_model",
    "regime_cost_ratio",
    "render_frame",
    "select_device",
]
