"""The fit's training loop: ``Trainer`` (in the way of nerfstudio's Trainer) sets up a fit of a prepared clip
(model, pixel tensors, optimiser, schedule, sampling generator), steps, evaluates, saves and restores it; ``fit``
runs it on a clip into a run folder. The bench, ``estimate`` and the speed table train through the same object.

Progress goes to stdout as JSON lines (``terms.protocol.progress_line``) and to stderr as a tqdm bar.
"""

from __future__ import annotations

import contextlib
import dataclasses
import signal
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from .. import contract as C
from ..config import FitConfig, check_config
from ..data.long_flow import long_flow_gaps
from ..data.scene_analysis import SceneAnalysis
from ..data.video import VideoTensors, mask_hold_layers, sample_batch, sample_pixels
from ..errors import FitDiverged, InputError
from ..model.atlas_model import AtlasModel
from ..model.losses import psnr_from_mse
from ..model.objective import compute_losses
from ..terms.export_names import ATLAS_SIZE_DEFAULT
from ..terms.protocol import EVENT_CANCELLED, EVENT_CHECKPOINT
from ..terms.run_folder import RUN_METRICS_SCHEMA
from ..terms.versions import ENGINE_VERSION
from .checkpoint import nonfinite_entries
from .device import select_device, synchronize
from .divergence import NonFinite, all_finite, diverged_message, nonfinite_groups, nonfinite_terms, require_finite
from .eta import JobClock, StepClock
from .evaluation import evaluate_full, evaluate_pixels
from .model_build import assemble_model, build_model, checkpoint_fits, model_motions, motion_from_state
from .optimisation import make_optimizer, make_scheduler
from .prepare import PreparedClip, prepare_clip
from .progress import Reporter, logged_fraction
from .run_folder import RunFolder
from .run_plan import PLAN_DONE, FitPlan, ResumedFit, check_fit_inputs, read_resume

#: The live PSNR's fixed pixel sample is drawn with seed ``cfg.seed + EVAL_SEED_OFFSET`` (apart from training's).
EVAL_SEED_OFFSET = 7919
#: The regime cost probe draws its batches with seed ``cfg.seed + PROBE_SEED_OFFSET`` (the fit's own are untouched).
PROBE_SEED_OFFSET = 104_729
#: Seconds between two ``job`` messages while training between the live-PSNR steps (the bar moves between them).
JOB_EVENT_SECONDS = 1.0
#: Timed live-PSNR samples before training (the fastest sets the seconds per pixel: the estimate of evaluation and
#: export, ``JobClock``): on a busy machine one sample's time varies tenfold.
START_SAMPLES = 3


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
        ix, iy, tt = sample_batch(video, cfg.step_batch(video.shape[0]), cfg.object_sample_share, gen, device)
        t0 = time.perf_counter()
        loss, terms = compute_losses(model, video, cfg, step, ix, iy, tt)
        require_finite(torch.isfinite(loss), step + 1, "loss", lambda: nonfinite_terms(terms))
        loss.backward()
        synchronize(device)
        seconds = time.perf_counter() - t0
        model.zero_grad(set_to_none=True)
        return seconds

    timed(0)  # warm-up: allocator, kernels
    early = min(timed(0) for _ in range(repeats))
    late = min(timed(boundary) for _ in range(repeats))
    return late / early if early > 0 else None


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


def _note_held_masks(video: VideoTensors, cfg: FitConfig, mask_dirs: list[str]) -> None:
    """One ``note:`` line per mask layer whose mask term stays on after the bootstrap (``mask_hold_coverage``)."""
    if cfg.bootstrap_steps >= cfg.steps:
        return  # the bootstrap lasts the whole fit: every mask is fitted throughout anyway
    for f in np.flatnonzero(mask_hold_layers(video.prior_coverage, cfg.mask_hold_coverage)):
        name = mask_dirs[f] if f < len(mask_dirs) else f"mask layer {f + 1}"
        share = video.prior_coverage[f] or 0.0
        print(
            f"note: masks {name}: the mask prior holds only {share:.0%} of them (a small or thin object), so they "
            "are fitted for the whole fit, not only during the bootstrap (--set mask_hold_coverage=0 lets them go)",
            file=sys.stderr,
        )


def _check_long_flow(video: VideoTensors, cfg: FitConfig) -> None:
    """Pixel tensors shared by several configs (the bench, ``estimate``) hold the long-range correspondences of the
    config the clip was prepared with: one that asks for others would silently fit without them."""
    gaps = long_flow_gaps(cfg.long_flow_max_gap, video.shape[0])
    if not gaps:
        return
    want = (gaps, cfg.long_flow_stride, float(cfg.flow_threshold_px))
    if video.long_settings != want:
        raise InputError(
            None,
            f"the clip was prepared with long-range correspondences {video.long_settings}, this config needs {want}",
            "give every config of one run the same long_flow_max_gap, long_flow_stride and flow_threshold_px",
        )


# --- the training loop --------------------------------------------------------------------------------------


class Trainer:
    """One fit of a prepared clip: its model, pixel tensors, optimiser, learning-rate schedule, sampling generator,
    step count and training clock.

    ``Trainer(cfg, clip, scene, device)`` sets a new fit up (the same seed gives the same model); with ``state``
    (a checkpoint, read from ``state_source``) it continues one, with ``cfg``'s schedule. ``calibrate`` runs the
    model's own set-up, ``train_step`` trains the next step, ``optimise`` one step at a given step's loss weights
    (the timed steps of ``estimate`` and the speed table), ``evaluate_sample``/``evaluate_full`` measure,
    ``save``/``state_dict``/``restore`` are the checkpoint, and ``train`` is the loop of ``fit``. ``video``: pixel
    tensors shared by several trainers of the same clip (the bench and the estimate try several presets on one
    clip). Every step checks that its loss, gradients and parameters are finite (``NonFinite``).
    """

    def __init__(
        self,
        cfg: FitConfig,
        clip: PreparedClip,
        scene: SceneAnalysis | None,
        device: torch.device,
        video: VideoTensors | None = None,
        state: dict[str, Any] | None = None,
        state_source: Path | None = None,
    ) -> None:
        self.cfg, self.clip, self.scene, self.device = cfg, clip, scene, device
        torch.manual_seed(cfg.seed)  # the model's initial weights
        if state is None:
            model = build_model(cfg, clip, scene)
        else:
            with checkpoint_fits(state_source):
                motions = None if state["motions"] is None else [motion_from_state(m) for m in state["motions"]]
                model = assemble_model(cfg, clip.size, clip.frames.shape[0], 1 + clip.num_foreground, scene, motions)
        self.model = model.to(device)
        if video is None:
            video = clip.tensors(cfg, device)
        _check_long_flow(video, cfg)
        if state is None:
            _note_held_masks(video, cfg, clip.mask_dirs)
        self.video = video
        self.optim = make_optimizer(self.model, cfg, device)
        self.sched = make_scheduler(self.optim, cfg)
        self.gen = torch.Generator().manual_seed(cfg.seed)
        #: every parameter the optimiser steps, in its groups' order (the per-step finite checks)
        self.params = [p for group in self.optim.param_groups for p in group["params"]]
        self.step = 0  # steps done: the next step's index
        self.train_seconds = 0.0  # optimisation steps and the model's calibration, nothing else
        #: the step of the last checkpoint written or restored (None: none yet): where a diverged fit continues
        self.saved_step: int | None = None
        #: seconds per step since this start or resume, per cost regime: the ETA (set up at the first ``train_step``)
        self.clock: StepClock | None = None
        self._sample: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None
        if state is not None:
            with checkpoint_fits(state_source):
                self.restore(state)

    def calibrate(self) -> None:
        """The model's own set-up before its first step (the paper model pre-trains its mappings), counted as
        training time as the fit counts it."""
        t0 = time.perf_counter()
        self.model.prepare(self.cfg, self.device)
        self.train_seconds += time.perf_counter() - t0

    def optimise(self, at: int) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """One optimisation step with the loss weights in force at step ``at``; the step count and the clock are
        left as they are. Raises ``NonFinite`` on a non-finite loss before its backward pass (NaN/Inf coordinates
        crash grid_sample's CPU backward), on non-finite gradients before the optimiser steps (the parameters stay
        as they were), and on non-finite parameters after it: one synchronising read per check, the maths
        untouched."""
        cfg, video = self.cfg, self.video
        step = at + 1  # as the progress lines count
        ix, iy, tt = sample_batch(video, cfg.step_batch(video.shape[0]), cfg.object_sample_share, self.gen, self.device)
        loss, terms = compute_losses(self.model, video, cfg, at, ix, iy, tt)
        require_finite(torch.isfinite(loss), step, "loss", lambda: nonfinite_terms(terms))
        self.optim.zero_grad(set_to_none=True)
        loss.backward()
        grads = [p.grad for p in self.params if p.grad is not None]
        require_finite(all_finite(grads), step, "gradients", lambda: nonfinite_groups(self.optim, grads=True))
        self.optim.step()
        self.sched.step()
        require_finite(all_finite(self.params), step, "parameters", lambda: nonfinite_groups(self.optim, grads=False))
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

    def _train_left(self, resume_rate: float | None) -> float | None:
        """Training's seconds left: the clock's, else a resumed fit's rate so far (None: not measured yet)."""
        eta = self.eta()
        if eta is None and resume_rate is not None:
            return resume_rate * max(0, self.cfg.steps - self.step)
        return eta

    def _timed_sample(self, job: JobClock) -> float:
        """``evaluate_sample``, timed: its seconds per pixel estimate the evaluation and the export (``JobClock``)."""
        t0 = time.perf_counter()
        psnr = self.evaluate_sample()
        synchronize(self.device)
        job.pixel_rate(time.perf_counter() - t0, self.cfg.eval_pixels)
        return psnr

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
            "config": dataclasses.asdict(self.cfg),
            "motions": model_motions(self.model),
        }

    def restore(self, state: dict[str, Any]) -> None:
        """Continue from ``state`` (a checkpoint of this fit) with this trainer's config: its learning rates and
        schedule replace the checkpoint's (``fit --resume --set lr=...`` after a divergence); with the same config
        the rates are the ones the checkpoint holds, bit for bit."""
        self.model.load_state_dict(state["model"])
        self.optim.load_state_dict(state["optim"])
        self.sched.load_state_dict(state["sched"])
        self.gen.set_state(state["gen"].cpu())
        self.step, self.train_seconds = int(state["step"]), float(state["train_seconds"])
        self.saved_step = self.step
        base = [group["lr"] for group in self.model.param_groups(self.cfg)]
        self.sched.base_lrs = base
        for group, lr, decay in zip(self.optim.param_groups, base, self.sched.lr_lambdas, strict=True):
            group["initial_lr"] = lr
            group["lr"] = lr * decay(self.sched.last_epoch)  # what LambdaLR computes at this step

    def save(self, run: RunFolder, reporter: Reporter) -> None:
        """Write the checkpoint (atomically), unless it would hold NaN/Inf: then ``NonFinite``, and the checkpoint
        on disk stays the last good one."""
        state = self.state_dict()
        bad = nonfinite_entries(state)
        if bad:
            raise NonFinite(self.step, "checkpoint's values", bad)
        run.save_checkpoint(state)
        self.saved_step = self.step
        reporter.emit(EVENT_CHECKPOINT, step=self.step, path=str(run.checkpoint))

    def train(self, run: RunFolder, reporter: Reporter, progress_bar: bool = True) -> None:
        """The fit's loop up to ``cfg.steps``: a progress line (live PSNR, ETA, loss terms) at the first step,
        every ``eval_every`` steps and the last; a checkpoint every ``checkpoint_seconds``, at the end, and at
        SIGINT/SIGTERM, which then raise ``FitCancelled``. A step whose loss, gradients or parameters are not
        finite stops the fit with ``FitDiverged`` (one line; an ``error`` progress event), nothing written past
        the last good checkpoint."""
        try:
            self._train(run, reporter, progress_bar)
        except NonFinite as exc:
            message = diverged_message(exc, self.cfg, run, self.saved_step)
            reporter.emit(C.EVENT_ERROR, message=message, log=str(run.log))
            raise FitDiverged(message) from None

    def _train(self, run: RunFolder, reporter: Reporter, progress_bar: bool) -> None:
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
        job = reporter.job
        # a resumed fit's rate until its clock has one: its training seconds per step so far (the bar continues
        # from the checkpoint's share of the whole job, not from 0)
        resume_rate = self.train_seconds / self.step if self.step > 0 and self.train_seconds > 0 else None
        job.atlas_texels = self.model.num_layers * ATLAS_SIZE_DEFAULT**2  # the export's atlases (its default size)
        self.evaluate_sample()  # warm-up (allocator, kernels): the first sample of a process is slower than the rest
        for _ in range(START_SAMPLES):
            self._timed_sample(job)
        job.train(self.train_seconds, self._train_left(resume_rate))
        reporter.job_event("train", self.step, cfg.steps, job.train_left)
        last_job = time.monotonic()
        with _Stop() as stop, contextlib.closing(bar):
            while not self.finished:
                _, terms = self.train_step()
                bar.update(1)
                job.train(self.train_seconds, self._train_left(resume_rate))
                if self.step % cfg.eval_every == 0 or self.step == cfg.steps or self.step == 1:
                    psnr = self._timed_sample(job)
                    eta = self.eta()
                    reporter.emit(
                        C.EVENT_PROGRESS,
                        step=self.step,
                        total=cfg.steps,
                        psnr=round(psnr, 3),
                        elapsed=round(self.train_seconds, 2),
                        eta=None if eta is None else round(eta, 1),
                        losses={k: round(float(v.detach()), 6) for k, v in terms.items()},
                        **reporter.job_fields(),
                    )
                    bar.set_postfix(psnr=f"{psnr:.2f}")
                    last_job = time.monotonic()
                elif time.monotonic() - last_job >= JOB_EVENT_SECONDS:
                    reporter.job_event("train", self.step, cfg.steps, job.train_left)
                    last_job = time.monotonic()
                if stop.signum is not None:
                    self.save(run, reporter)
                    bar.close()
                    reporter.emit(EVENT_CANCELLED, step=self.step, checkpoint=str(run.checkpoint))
                    raise FitCancelled(f"interrupted by signal {stop.signum} at step {self.step}")
                if time.monotonic() - last_ckpt > cfg.checkpoint_seconds:
                    self.save(run, reporter)
                    last_ckpt = time.monotonic()
        bar.close()
        self.save(run, reporter)


def fit(run_dir: str | Path, plan: FitPlan, device_name: str = "auto", progress_bar: bool = True,
        stream: Any = None) -> dict[str, Any]:  # fmt: skip
    """Fit a layered atlas to ``plan.inputs`` as ``plan`` says (start, resume, refit, refine); writes config, clip
    record, scene analysis, checkpoint and metrics into ``run_dir``. The inputs' ``auto_masks``: no masks given,
    find them from motion (written to RUN_DIR/auto_masks for the artist to check) and fit with them; nothing moving
    gives a background-only fit. ``scribbles``: red/green/... strokes that split the one mask's object into several
    foreground layers (paper Sec. 4.4). ``parts`` (a new fit of one mask, no scribbles): those strokes found from
    the motion where the object's parts move apart (``auto_parts``; ``fit``'s default and ``--auto-parts``).

    The run folder is written under its lock (``RunFolder.lock``), taken once the input is read and checked (at
    once when the folder exists): a second ``fit`` into it is refused with one line. A folder that holds a fit
    (``RunFolder.fit_contents``) takes a resume (continue it: the same clip, masks and config, but for the
    schedule's ``RESUMABLE_FIELDS``; the plate read as recorded) or a refit (fit again: edits/ and exports/ are
    kept)."""
    if plan.action == PLAN_DONE:
        raise ValueError("a plan with nothing to do (PLAN_DONE) is not fitted: its metrics are the plan's")
    cfg, inputs, resume = plan.cfg, plan.inputs, plan.resume
    check_config(cfg)
    run = RunFolder(run_dir)
    check_fit_inputs(cfg, inputs, resume)
    run.check_writable()
    device = select_device(device_name)
    reporter = Reporter(stream=stream)
    with contextlib.ExitStack() as stack:
        lock = _WriteLock(run, stack, plain=not (resume or plan.refit))
        if run.path.is_dir():
            lock()  # a folder that exists: another process writing it is refused before the clip is read
        resumed = expect = None
        if resume:
            resumed = read_resume(run, cfg, device, inputs)
            # the bar continues where the stopped fit showed it, from the first message (the flow's) on
            shown = logged_fraction(run.log, int(resumed.state["step"]), cfg.steps)
            if shown is not None:
                reporter.job.resume_from(shown)
            inputs, expect = resumed.inputs, resumed.record
        # the input is read and validated before anything is written: bad input leaves no run folder behind
        # (the lock from the first write, the flow cache, on)
        prepared = prepare_clip(inputs, cfg, run.path, reporter, expect, before_writing=lock)
        trainer = _start_trainer(run, cfg, prepared, device, resumed, plan.refit)
        reporter.log_path = run.log
        return _fit_locked(run, trainer, reporter, progress_bar)


def _start_trainer(
    run: RunFolder,
    cfg: FitConfig,
    prepared: PreparedClip,
    device: torch.device,
    resumed: ResumedFit | None,
    refit: bool,
) -> Trainer:
    """``fit``'s trainer for ``prepared`` (a resume: its checkpoint restored and checked), built before anything
    is written; then the run folder's records: a new fit's config, clip record and scene (a refit's old fit
    cleared first), a resume's new schedule before its next checkpoint."""
    state = None if resumed is None else resumed.state
    scene = None if resumed is None else resumed.scene
    new_fit = resumed is None or scene is None
    if new_fit:
        scene = prepared.analyse(cfg)
    trainer = Trainer(cfg, prepared, scene, device, state=state, state_source=run.checkpoint)
    if new_fit:
        if refit:
            run.clear_fit()
        run.write_config(cfg)
        run.write_clip(prepared.record())
        run.write_scene(scene)
    elif resumed is not None and cfg != resumed.saved:
        run.write_config(cfg)  # the resume's new schedule, before its next checkpoint
    return trainer


class _WriteLock:
    """``fit``'s hold on the run folder: taken once (at once for a folder that exists, else when the input has been
    read and checked, so bad input creates no folder) and kept to the end of the fit; under it, a plain fit checks
    again that the folder holds no fit (another process may have fitted into it meanwhile)."""

    def __init__(self, run: RunFolder, stack: contextlib.ExitStack, plain: bool) -> None:
        self.run, self.stack, self.plain, self.held = run, stack, plain, False

    def __call__(self) -> None:
        if self.held:
            return
        self.stack.enter_context(self.run.lock(C.VERB_FIT))
        self.held = True
        if self.plain:
            self.run.refuse_plain_fit()


def _fit_locked(run: RunFolder, trainer: Trainer, reporter: Reporter, progress_bar: bool) -> dict[str, Any]:
    """``fit``'s training, evaluation and metrics, under the run folder's lock, the folder's records written."""
    cfg, scene, device = trainer.cfg, trainer.scene, trainer.device
    assert scene is not None  # a fit always has its scene analysis
    reporter.emit(C.EVENT_STAGE, stage="scene", message=scene.summary(), scene=scene.to_dict())
    reporter.emit(C.EVENT_STAGE, stage="init", message=f"the {cfg.model} model on {device.type}")
    if trainer.saved_step is None:
        trainer.calibrate()
        trainer.save(run, reporter)  # step 0: the last good checkpoint even of a fit that diverges at once
    trainer.train(run, reporter, progress_bar)
    reporter.emit(C.EVENT_STAGE, stage="evaluate", message="full-frame PSNR over every pixel")
    reporter.job_event("evaluate", 0, 1, reporter.job.eval_left)
    t0 = time.perf_counter()
    ev = trainer.evaluate_full()
    reporter.job.evaluated(time.perf_counter() - t0)
    reporter.job_event("evaluate", 1, 1, 0.0)
    metrics = {
        "schema": RUN_METRICS_SCHEMA,
        "psnr": ev["psnr"],
        "mse": ev["mse"],
        "alpha_iou": ev["alpha_iou"],
        "steps": trainer.step,
        "train_seconds": trainer.train_seconds,
        "seconds_per_step": trainer.train_seconds / max(trainer.step, 1),
        "preset": cfg.preset,
        "model": cfg.model,
        "device": device.type,
        "working_size": list(trainer.clip.size),
        "frames": int(trainer.video.shape[0]),
        "engine_version": ENGINE_VERSION,
        "torch_version": torch.__version__,
    }
    run.write_metrics(metrics)
    reporter.emit(C.EVENT_DONE, metrics=metrics)
    return metrics


__all__ = [
    "FitCancelled",
    "Trainer",
    "fit",
    "regime_cost_ratio",
]
