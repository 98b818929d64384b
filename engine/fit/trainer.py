"""The fit's training loop: ``Trainer`` (in the way of nerfstudio's Trainer) sets up a fit of a prepared clip
(model, pixel tensors, optimiser, schedule, sampling generator), steps, evaluates, saves and restores it; ``fit``
runs it on a clip into a run folder. The bench, ``estimate`` and the speed table train through the same object.

Progress goes to stdout as JSON lines (``contract.progress_line``) and to stderr as a tqdm bar.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import shlex
import signal
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from .. import contract as C
from ..config import LR_FIELDS, PRESETS, RESUMABLE_FIELDS, FitConfig, check_config, resume_changes
from ..data.long_flow import long_flow_gaps
from ..data.scene_analysis import SceneAnalysis
from ..data.scribbles import propagate_labels
from ..data.video import VideoTensors, frame_pixels, mask_hold_layers, sample_batch, sample_pixels
from ..errors import FitDiverged, InputError
from ..io.colour import recorded_space, resolve
from ..model.atlas_model import AtlasModel, FastModel, motion_regions
from ..model.losses import psnr_from_mse
from ..model.motion_init import LayerMotion, estimate_layer_motion
from ..model.objective import TARGET_RANGE, compute_losses
from ..model.paper_model import PaperModel
from .checkpoint import nonfinite_entries
from .device import select_device, synchronize
from .eta import JobClock, StepClock
from .prepare import PreparedClip, prepare_clip
from .progress import Reporter, logged_fraction
from .run_folder import FOREIGN_CHECKPOINT_FIX, ClipRecord, RunFolder

#: Pixels per forward chunk when evaluating whole frames (bounds memory of the evaluation).
EVAL_CHUNK = 65536
#: The live PSNR's fixed pixel sample is drawn with seed ``cfg.seed + EVAL_SEED_OFFSET`` (apart from training's).
EVAL_SEED_OFFSET = 7919
#: The regime cost probe draws its batches with seed ``cfg.seed + PROBE_SEED_OFFSET`` (the fit's own are untouched).
PROBE_SEED_OFFSET = 104_729
#: Seconds between two ``job`` messages while training between the live-PSNR steps (the bar moves between them).
JOB_EVENT_SECONDS = 1.0
#: Timed live-PSNR samples before training (the fastest sets the seconds per pixel: the estimate of evaluation and
#: export, ``JobClock``): on a busy machine one sample's time varies tenfold.
START_SAMPLES = 3
#: A foreground alpha above this counts as the layer's when comparing it with its mask (alpha IoU).
ALPHA_IOU_THRESHOLD = 0.5
#: The learning rate's decay never goes below this fraction (a zero ratio would stop the decay's logarithm).
MIN_LR_RATIO = 1e-6
#: A diverged fit's message suggests the preset's rate, or this fraction of the rate it diverged with when that
#: was no higher than the preset's.
LR_RETRY_FACTOR = 0.1
#: A loss weight more than this many times its preset's (or than this, where the preset's is below 1) is named as a
#: diverged fit's likely cause: a resume keeps the weights, so lower rates alone would diverge again.
WEIGHT_SUSPECT_FACTOR = 100.0
#: Characters of a torch error kept in the one-line message of a checkpoint that does not fit the model.
ERROR_DETAIL_CHARS = 160


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
                    flow,
                    region,
                    clip.size,
                    cfg.init_motion,
                    margin=cfg.atlas_margin_fg,
                    extent_masks=fg_regions[0],
                    background=motions[0],
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
                    background=motions[0],
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
    """Mean squared error of the reconstruction at the given pixels, against the plate in the objective's
    ``TARGET_RANGE`` (what a reconstruction can reach: an HDR highlight, or an absurd value clamped to
    ``prepare.PLATE_VALUE_LIMIT``, counts as the range's top, so one pixel cannot decide the PSNR; a no-op for
    8/16-bit plates)."""
    lo, hi = TARGET_RANGE
    total, count = 0.0, 0
    for s in range(0, ix.shape[0], EVAL_CHUNK):
        sl = slice(s, s + EVAL_CHUNK)
        xy = torch.stack((ix[sl], iy[sl]), -1).float() + 0.5
        rec, _ = model.reconstruct(xy, t[sl])
        total += float(((rec - video.frames[t[sl], iy[sl], ix[sl]].clamp(lo, hi)) ** 2).sum())
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
    """Full-frame PSNR over every pixel of every frame (against the plate in ``TARGET_RANGE``, as
    ``evaluate_pixels``), and per-layer alpha IoU against the masks."""
    t_count = video.shape[0]
    sq, n = 0.0, 0
    inter = np.zeros(video.masks.shape[0])
    union = np.zeros(video.masks.shape[0])
    frames_np = video.frames.cpu().numpy()
    masks_np = video.masks.cpu().numpy()
    lo, hi = TARGET_RANGE
    for t in range(t_count):
        rec, wts = render_frame(model, t, size, device)
        sq += float(((rec - np.clip(frames_np[t], lo, hi)) ** 2).sum())
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


# --- divergence: every step's loss, gradients and parameters are finite ------------------------------------


class NonFinite(FitDiverged):
    """A step's loss, gradients or parameters (or a checkpoint about to be written) hold NaN or Inf. ``train``
    turns it into the fit's one-line ``FitDiverged`` (the learning rates, how to continue)."""

    def __init__(self, step: int, quantity: str, where: list[str]) -> None:
        self.step, self.quantity, self.where = step, quantity, where
        inside = f" ({', '.join(where[:4])}{', ...' if len(where) > 4 else ''})" if where else ""
        super().__init__(f"step {step}: the {quantity}{inside} became NaN/Inf")


def all_finite(tensors: list[torch.Tensor]) -> torch.Tensor:
    """0-d bool tensor: every value of every tensor is finite, without a synchronisation (the caller reads it
    once). One fused pass: ``torch._foreach_norm``'s 2-norm of each tensor, which NaN and Inf propagate into (the
    vectorised norm: the infinity norm, exact for any finite value, costs about 16 times as much on a CPU). A
    magnitude beyond about 1.8e19 overflows the float32 norm and counts as non-finite too: a fit's values and
    gradients are far below it unless it is diverging."""
    tensors = [t for t in tensors if t.numel()]
    if not tensors:
        return torch.tensor(True)
    return torch.isfinite(torch.stack(torch._foreach_norm(tensors))).all()


def require_finite(ok: torch.Tensor, step: int, quantity: str, where: Callable[[], list[str]]) -> None:
    """Raise ``NonFinite`` unless ``ok`` (the step's one synchronisation for this check); ``where`` names the
    culprits, computed only then."""
    if not bool(ok):
        raise NonFinite(step, quantity, where())


def nonfinite_terms(terms: dict[str, torch.Tensor]) -> list[str]:
    return [name for name, value in terms.items() if not bool(torch.isfinite(value.detach()).all())]


def nonfinite_groups(optim: torch.optim.Optimizer, grads: bool) -> list[str]:
    """The parameter groups (``grids``, ``mappings``, ...) whose gradients (or values) are not all finite."""
    names = []
    for i, group in enumerate(optim.param_groups):
        tensors = [p.grad if grads else p for p in group["params"]]
        if not bool(all_finite([t for t in tensors if t is not None])):
            names.append(str(group.get("name", i)))
    return names


def suspect_weights(error: NonFinite, cfg: FitConfig) -> list[str]:
    """The loss weights (``w_*``) far above their preset's (``WEIGHT_SUSPECT_FACTOR``), the furthest first; those
    of the terms that went non-finite before the rest."""
    preset = PRESETS.get(cfg.preset, FitConfig())

    def ratio(name: str) -> float:
        return float(getattr(cfg, name)) / max(float(getattr(preset, name)), 1.0)

    names = [f.name for f in dataclasses.fields(cfg) if f.name.startswith("w_")]
    high = sorted((n for n in names if ratio(n) > WEIGHT_SUSPECT_FACTOR), key=ratio, reverse=True)
    named = [n for n in high if error.quantity == "loss" and n.removeprefix("w_") in error.where]
    return named + [n for n in high if n not in named]


def diverged_message(error: NonFinite, cfg: FitConfig, run: RunFolder, checkpoint_step: int | None) -> str:
    """The one line of a diverged fit: the step, what went non-finite, the likely cause (a loss weight far above
    its preset's, else its learning rates or the plate's values) and the command that continues from the last good
    checkpoint with lower rates, or, for a weight (a resume keeps the weights), the fit again with the preset's."""
    preset = PRESETS.get(cfg.preset, FitConfig())
    weights = suspect_weights(error, cfg)
    if weights:
        shown = ", ".join(f"{w}={getattr(cfg, w):g}" for w in weights)
        theirs = ", ".join(f"{getattr(preset, w):g}" for w in weights)
        sets = " ".join(f"--set {w}={getattr(preset, w):g}" for w in weights)
        return (
            f"{run.path}: the fit diverged at {error} — likely cause: the loss weight {shown}, far above the "
            f"{cfg.preset} preset's ({theirs}); a resume keeps the weights, so fit again with --refit {sets} "
            "(edit layers and exports are kept)"
        )
    high = [k for k in LR_FIELDS if getattr(cfg, k) > getattr(preset, k)]
    lower = {k: getattr(preset, k) for k in high} or {k: getattr(cfg, k) * LR_RETRY_FACTOR for k in LR_FIELDS}
    rates = ", ".join(f"{k}={getattr(cfg, k):g}" for k in (high or LR_FIELDS))
    cause = f"a learning rate too high ({rates}) or extreme values in the plate"
    if checkpoint_step is None:
        return f"{run.path}: the fit diverged at {error} — likely cause: {cause}; lower the rate and fit again"
    sets = " ".join(f"--set {k}={v:g}" for k, v in lower.items())
    return (
        f"{run.path}: the fit diverged at {error} — likely cause: {cause}; the checkpoint keeps step "
        f"{checkpoint_step}, the last good one: continue from it with a lower rate: "
        f"python -m {C.CLI_MODULE} fit --resume --out {shlex.quote(str(run.path))} {sets}"
    )


def _one_line(exc: BaseException) -> str:
    """A torch error (often several lines) as a short clause for a one-line message."""
    text = " ".join(part.strip() for part in str(exc).splitlines() if part.strip()) or type(exc).__name__
    return text if len(text) <= ERROR_DETAIL_CHARS else text[: ERROR_DETAIL_CHARS - 3] + "..."


@contextlib.contextmanager
def checkpoint_fits(path: Path | None) -> Iterator[None]:
    """A checkpoint loaded into a model it was not saved from (another run's, a damaged one: missing weights,
    wrong shapes, a broken optimiser or sampler state) is one line naming ``path``, not torch's traceback."""
    try:
        yield
    except InputError as exc:
        if exc.path is not None:
            raise
        raise InputError(path, exc.problem, exc.fix) from None
    except (RuntimeError, ValueError, TypeError, KeyError, IndexError, AttributeError) as exc:
        problem = f"checkpoint does not fit this run's model ({_one_line(exc)})"
        raise InputError(path, problem, FOREIGN_CHECKPOINT_FIX) from None


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
    """A layer's starting motion as ``model_motions`` saved it (a malformed one raises: ``checkpoint_fits``)."""
    return LayerMotion(
        to_ref=rec["to_ref"].cpu().numpy().astype(np.float64),
        center=rec["center"].cpu().numpy().astype(np.float64),
        half_extent=float(rec["half_extent"]),
        aspect=(float(rec["aspect"][0]), float(rec["aspect"][1])),
    )


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
        ix, iy, tt = sample_batch(video, cfg.batch, cfg.object_sample_share, self.gen, self.device)
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
        reporter.emit(C.EVENT_CHECKPOINT, step=self.step, path=str(run.checkpoint))

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
        job.atlas_texels = self.model.num_layers * C.ATLAS_SIZE_DEFAULT**2  # the export's atlases (its default size)
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
    colorspace: str | None = None,
    fps: Fraction | None = None,
    start_frame: int | None = None,
) -> dict[str, Any]:
    """Fit a layered atlas to ``clip``; writes config, clip record, scene analysis, checkpoint and metrics
    into ``run_dir``. ``auto_masks``: no masks given, find them from motion (written to RUN_DIR/auto_masks
    for the artist to check) and fit with them; nothing moving gives a background-only fit. ``scribble_dir``:
    red/green/... strokes that split the one mask's object into several foreground layers (paper Sec. 4.4).
    ``fps``: the plate's rate where its files state none; ``start_frame``: a movie's first frame number (both
    recorded in clip.json, neither changes the fit; a resume keeps the recorded ones).

    The run folder is written under its lock (``RunFolder.lock``), taken once the input is read and checked (at
    once when the folder exists): a second ``fit`` into it is refused with one line. A folder that holds a fit
    (``RunFolder.fit_contents``) takes ``resume`` (continue it: the same clip, masks and config, but for the
    schedule's ``RESUMABLE_FIELDS``) or ``refit`` (fit again: edits/ and exports/ are kept). ``colorspace``: the
    plate's colour space (``fit --colorspace``; default from the config's file rules or the file type)."""
    check_config(cfg)
    if resume and refit:
        raise InputError(
            None, "--resume and --refit both given", "pass --resume to continue the fit, or --refit to fit again"
        )
    run = RunFolder(run_dir)
    if not resume and clip is None:
        raise InputError(None, "no clip given", "pass a frame folder or movie file")
    find_masks = auto_masks and not resume
    if find_masks and mask_dirs:
        raise InputError(None, f"{C.FIT_AUTO_MASKS_FLAG} and --mask both given", "pass one of them")
    if cfg.model == "paper" and not resume:
        _check_paper_layers(mask_dirs, find_masks, scribble_dir)
    run.check_writable()
    device = select_device(device_name)
    reporter = Reporter(stream=stream)
    with contextlib.ExitStack() as stack:
        lock = _WriteLock(run, stack, plain=not (resume or refit))
        if run.path.is_dir():
            lock()  # a folder that exists: another process writing it is refused before the clip is read
        state = scene = saved = None
        expect = colour_config = None
        if resume:
            saved, record = run.read_config(), run.read_clip()
            scene = run.read_scene(record)
            _check_resume_inputs(run, record, clip, mask_dirs, frame_range, scribble_dir)
            missing = record.missing_input(run.path)
            if missing is not None:
                raise missing
            colorspace, colour_config = _check_resume_colour(run, record, colorspace)
            _check_resume_config(run, saved, cfg)
            state = run.load_checkpoint(device)
            run.check_checkpoint_belongs(state, saved, record)
            # the bar continues where the stopped fit showed it, from the first message (the flow's) on
            shown = logged_fraction(run.log, int(state["step"]), cfg.steps)
            if shown is not None:
                reporter.job.resume_from(shown)
            clip, mask_dirs, frame_range = record.source, list(record.masks), record.frame_range
            scribble_dir, expect = record.scribbles, record.fingerprint
            fps, start_frame = record.exact_rate, record.movie_start
        # the input is read and validated before anything is written: bad input leaves no run folder behind
        prepared = prepare_clip(
            clip,  # type: ignore[arg-type]  # a resume's clip is the recorded one; a new fit's was checked above
            mask_dirs,
            cfg,
            run.path,
            frame_range,
            reporter,
            expect,
            scribble_dir,
            auto_masks=find_masks,
            before_writing=lock,  # the lock from the first write (the flow cache) on
            colorspace=colorspace,
            colour_config=colour_config,
            fps=fps,
            start_frame=start_frame,
        )
        new_fit = saved is None or scene is None
        if new_fit:
            scene = prepared.analyse(cfg)
        # built (a resume: its checkpoint restored and checked) before anything is written
        trainer = Trainer(cfg, prepared, scene, device, state=state, state_source=run.checkpoint)
        reporter.log_path = run.log
        if new_fit:
            if refit:
                run.clear_fit()
            run.write_config(cfg)
            run.write_clip(prepared.record())
            run.write_scene(scene)
        elif cfg != saved:
            run.write_config(cfg)  # the resume's new schedule, before its next checkpoint
        return _fit_locked(run, trainer, reporter, progress_bar)


def _check_paper_layers(mask_dirs: list[str | Path], auto_masks: bool, scribble_dir: str | Path | None) -> None:
    """The paper's architecture has one background and one foreground layer: exactly one --mask (masks found by
    motion may be none, and scribbles split the object into several), checked before anything is read."""
    given = None
    if auto_masks:
        given = f"{C.FIT_AUTO_MASKS_FLAG} was given"
    elif scribble_dir is not None:
        given = f"{C.SCRIBBLE_ARG} split the object into layers"
    elif len(mask_dirs) != 1:
        given = f"{len(mask_dirs)} --mask folders were given"
    if given is not None:
        raise InputError(
            None,
            f"the paper model fits one background and one foreground layer, but {given}",
            "pass exactly one --mask, or use a fast preset (draft, balanced or final)",
        )


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
        "working_size": list(trainer.clip.size),
        "frames": int(trainer.video.shape[0]),
        "engine_version": C.ENGINE_VERSION,
        "torch_version": torch.__version__,
    }
    run.write_metrics(metrics)
    reporter.emit(C.EVENT_DONE, metrics=metrics)
    return metrics


#: What ``fit_state`` finds in a run folder for ``fit --resume-if-started``.
FIT_NEW, FIT_STARTED, FIT_FINISHED = "new", "started", "finished"


def fit_state(
    run_dir: str | Path,
    clip: str | Path | None,
    mask_dirs: list[str | Path],
    cfg: FitConfig,
    frame_range: tuple[int, int] | None = None,
    scribble_dir: str | Path | None = None,
    colorspace: str | None = None,
) -> str:
    """For a retried fit (``fit --resume-if-started``, whose arguments are the same on every try): ``FIT_NEW`` when
    ``run_dir`` holds no checkpoint (start it), ``FIT_STARTED`` when it holds one of this same fit (continue it as
    ``--resume`` does), ``FIT_FINISHED`` when it holds this fit finished (nothing to do). This same fit: the clip,
    masks, scribbles, frames and colour space given are the recorded ones and ``cfg`` differs from config.json in
    nothing but the schedule (``RESUMABLE_FIELDS``), checked as ``--resume`` checks them; else one line. Reads
    only: the fit that follows takes the lock."""
    run = RunFolder(run_dir)
    if not run.checkpoint.exists():
        return FIT_NEW
    saved, record = run.read_config(), run.read_clip()
    _check_resume_inputs(run, record, clip, mask_dirs, frame_range, scribble_dir)
    _check_resume_colour(run, record, colorspace)
    _check_resume_config(run, saved, cfg)
    metrics = run.read_metrics()
    if metrics is not None and cfg == saved:
        return FIT_FINISHED
    return FIT_STARTED


def _same_path(given: str | Path, recorded: str) -> bool:
    """Whether a path given on the command line names what the run recorded (symlinks and ``~`` resolved)."""
    return os.path.realpath(os.path.expanduser(os.fspath(given))) == os.path.realpath(recorded)


def _check_resume_inputs(
    run: RunFolder,
    record: ClipRecord,
    clip: str | Path | None,
    mask_dirs: list[str | Path],
    frame_range: tuple[int, int] | None,
    scribble_dir: str | Path | None,
) -> None:
    """``--resume`` continues the fit of the clip, masks, scribbles and frames clip.json records: any of them given
    again must be the recorded one (a different mask folder would otherwise be fitted while clip.json keeps the
    old one). One line naming the first difference."""
    changed: tuple[str, str, str] | None = None
    if clip is not None and not _same_path(clip, record.source):
        changed = ("the clip", str(clip), record.source)
    elif mask_dirs and not (len(mask_dirs) == len(record.masks) and all(map(_same_path, mask_dirs, record.masks))):
        changed = ("--mask", ", ".join(map(str, mask_dirs)), ", ".join(record.masks) or "no masks")
    elif scribble_dir is not None and (record.scribbles is None or not _same_path(scribble_dir, record.scribbles)):
        changed = ("--scribbles", str(scribble_dir), record.scribbles or "no scribbles")
    elif frame_range is not None and tuple(frame_range) != tuple(record.frame_range):
        first, last = record.frame_range
        changed = ("--frames", f"{frame_range[0]}:{frame_range[1]}", f"{first}:{last}")
    if changed is not None:
        what, given, recorded = changed
        raise InputError(
            run.clip,
            f"--resume with {what} {given}, but this run fitted {recorded}",
            "drop it to continue the fit as it started, or fit with it into a new --out (or --refit)",
        )


def _check_resume_colour(run: RunFolder, record: ClipRecord, given: str | None) -> tuple[str, str | None]:
    """The recorded plate colour space and config a resume continues with, as recorded (a run made before colour
    management: "sRGB"/"linear" and no config, which ``prepare_clip`` reads as it did); a ``--colorspace`` that
    names another space is refused in one line."""
    space, config = recorded_space(record.colorspace, record.colour_config)
    if given is not None and resolve(given, config) != space:
        raise InputError(
            run.clip,
            f"--resume with --colorspace {given}, but this run fitted the plate as {space!r}",
            "drop --colorspace to continue the fit as it started, or fit with it into a new --out (or --refit)",
        )
    return record.colorspace, record.colour_config


def _check_resume_config(run: RunFolder, saved: FitConfig, cfg: FitConfig) -> None:
    """A resume may change the schedule (``config.RESUMABLE_FIELDS``) and nothing else: one line naming the
    first other field that differs from config.json."""
    _, refused = resume_changes(saved, cfg)
    if refused:
        key = refused[0]
        raise InputError(
            run.config,
            f"--resume cannot change {key} ({getattr(saved, key)!r} -> {getattr(cfg, key)!r}); "
            f"a resume changes only {', '.join(RESUMABLE_FIELDS)}",
            "drop that --set to continue the fit, or fit with it into a new --out (or --refit)",
        )


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
    scene = run.read_scene(record)
    device = select_device(device_name)
    state = run.load_checkpoint(device)
    run.check_checkpoint_belongs(state, cfg, record)
    with checkpoint_fits(run.checkpoint):
        model = rebuild_model(cfg, record, scene, state["motions"]).to(device)
        model.load_state_dict(state["model"])
    return FittedRun(run, cfg, record, scene, model.eval(), run.read_metrics())


def load_run(run_dir: str | Path, device_name: str = "cpu") -> tuple[AtlasModel, PreparedClip, FitConfig]:
    """A finished (or checkpointed) fit's model with its weights, its clip prepared again (frames, masks, flow
    from the cache) and its config: for looking at a fit against its plate (the demo's contact sheet)."""
    fitted = load_fitted(run_dir, device_name)
    record = fitted.clip
    missing = record.missing_input(fitted.folder.path)
    if missing is not None:
        raise missing
    prepared = prepare_clip(
        record.source,
        list(record.masks),
        fitted.cfg,
        fitted.folder.path,
        record.frame_range,
        scribble_dir=record.scribbles,
        # the plate as it was fitted: its recorded colour space, rate and movie numbering, not today's defaults
        colorspace=record.colorspace,
        colour_config=record.colour_config,
        fps=record.exact_rate,
        start_frame=record.movie_start,
    )
    return fitted.model, prepared, fitted.cfg


__all__ = [
    "EVAL_CHUNK",
    "FitCancelled",
    "FittedRun",
    "NonFinite",
    "PreparedClip",
    "Reporter",
    "Trainer",
    "build_model",
    "fit",
    "fit_state",
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
