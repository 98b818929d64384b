"""Shared helpers of the stability suite: plates written in any format, and a fit that checks every step.

``monitored_fit`` runs the real ``engine.fit.trainer.fit`` (reading, flow, motion init, model, loop, evaluation)
on a short schedule, with two probes patched in: every loss term and the total must be finite at every
step, every gradient must be finite before each optimiser step, and every parameter finite after it.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from engine import contract as C
from engine.config import apply_overrides, preset_config
from engine.fit import trainer
from engine.fit.fit_inputs import FitInputs
from tests.engine.fit_helpers import quiet_fit
from tests.media_files import write_image

#: A short schedule that still crosses every phase: global rigidity, mask bootstrap, then the mask prior.
QUICK = {
    "steps": "24",
    "batch": "256",
    "eval_every": "12",
    "eval_pixels": "1000",
    "bootstrap_steps": "12",
    "global_rigidity_steps": "6",
}


def write_sequence(folder: Path, frames: np.ndarray, ext: str = "png", dtype: Any = np.uint8) -> Path:
    """Frames [T, H, W, C] (float, display values in [0, 1] unless ``dtype`` is float32) as 00000.ext..."""
    folder.mkdir(parents=True, exist_ok=True)
    for t, frame in enumerate(frames):
        if dtype == np.float32:
            pix = frame.astype(np.float32)
        else:
            top = np.iinfo(dtype).max
            pix = np.clip(np.rint(frame * top), 0, top).astype(dtype)
        write_image(folder / f"{t:05d}.{ext}", pix)
    return folder


def write_masks(folder: Path, masks: np.ndarray) -> Path:
    """Bool masks [T, H, W] as 8-bit 0/255 PNGs."""
    folder.mkdir(parents=True, exist_ok=True)
    for t, m in enumerate(masks):
        write_image(folder / f"{t:05d}.png", np.where(m, 255, 0).astype(np.uint8))
    return folder


@dataclass
class FitMonitor:
    """What the probes saw: steps checked, the worst magnitudes, and the last model and video tensors."""

    steps: int = 0
    optimizer_steps: int = 0
    term_names: set[str] = field(default_factory=set)
    max_abs_term: float = 0.0
    max_abs_grad: float = 0.0
    max_abs_param: float = 0.0
    problems: list[str] = field(default_factory=list)
    model: Any = None
    video: Any = None
    prepared: Any = None
    psnr_curve: list[tuple[int, float]] = field(default_factory=list)
    """(step, PSNR on the fixed evaluation sample) from the progress lines: step 1, every eval_every, the last."""

    @property
    def psnr_gain(self) -> float:
        """dB gained from the first to the last progress line: a short fit that is not diverging gains."""
        return self.psnr_curve[-1][1] - self.psnr_curve[0][1]

    def check_losses(self, step: int, total: torch.Tensor, terms: dict[str, torch.Tensor]) -> None:
        self.steps += 1
        for name, value in {"total": total, **terms}.items():
            v = float(value.detach())
            self.term_names.add(name)
            if not math.isfinite(v):
                self.problems.append(f"step {step}: loss term {name} = {v}")
            else:
                self.max_abs_term = max(self.max_abs_term, abs(v))

    def check_grads(self, optim: torch.optim.Optimizer) -> None:
        self.optimizer_steps += 1
        for group in optim.param_groups:
            for p in group["params"]:
                if p.grad is None:
                    continue
                if not bool(torch.isfinite(p.grad).all()):
                    self.problems.append(f"step {self.optimizer_steps}: non-finite grad in {group.get('name')}")
                else:
                    self.max_abs_grad = max(self.max_abs_grad, float(p.grad.abs().max()) if p.grad.numel() else 0.0)

    def check_params(self, optim: torch.optim.Optimizer) -> None:
        for group in optim.param_groups:
            for p in group["params"]:
                if not bool(torch.isfinite(p).all()):
                    self.problems.append(f"step {self.optimizer_steps}: non-finite parameter in {group.get('name')}")
                elif p.numel():
                    self.max_abs_param = max(self.max_abs_param, float(p.detach().abs().max()))

    def assert_stable(self, steps: int) -> None:
        """Every step was checked, and nothing was ever non-finite."""
        assert not self.problems, self.problems[:5]
        assert self.steps == steps and self.optimizer_steps == steps, (self.steps, self.optimizer_steps)
        # every term the scene analysis keeps (engine.data.scene_analysis) was evaluated and checked; a single frame has
        # no flow terms, a background-only clip no foreground terms: those are not evaluated at all
        expected = {"rgb", "gradient", "rigidity", "flow", "alpha_flow", "sparsity"}
        active = getattr(self.model, "active_terms", None)
        expected = {"total"} | (expected if active is None else expected & active)
        assert expected <= self.term_names, (expected, self.term_names)


def background_mapping_motion(model: Any, size: tuple[int, int], frames: int) -> tuple[np.ndarray, np.ndarray]:
    """How the background mapping moves each pixel of each frame: the distance (px) of its atlas point from the
    same pixel's in frame 0, [T, H*W], and the singular values (px per px) of the mapping's finite-difference
    Jacobian there, [T, H*W, 2] (1 and 1 for a rotation: a rigid, unscaled mapping)."""
    w, h = size
    ys, xs = np.mgrid[0:h, 0:w]
    xy = torch.tensor(np.stack([xs.ravel(), ys.ravel()], -1), dtype=torch.float32) + 0.5
    upp = model.uv_per_px(0)
    drifts, svals = [], []
    with torch.no_grad():
        uv0 = model.uv(0, xy, torch.zeros(len(xy), dtype=torch.long))
        for t in range(frames):
            tt = torch.full((len(xy),), t, dtype=torch.long)
            uvt = model.uv(0, xy, tt)
            drifts.append(((uvt - uv0).norm(dim=-1) / upp).numpy())
            jx = (model.uv(0, xy + torch.tensor([1.0, 0.0]), tt) - uvt) / upp
            jy = (model.uv(0, xy + torch.tensor([0.0, 1.0]), tt) - uvt) / upp
            svals.append(torch.linalg.svdvals(torch.stack([jx, jy], -1)).numpy())
    return np.stack(drifts), np.stack(svals)


#: The trainer's own functions, captured once, so probes installed twice in one test do not nest.
_ORIGINALS = (trainer.compute_losses, trainer.make_optimizer, trainer.prepare_clip)


def install_probes(monkeypatch: Any) -> FitMonitor:
    """Patch the trainer's loss function and optimiser factory with checking wrappers."""
    mon = FitMonitor()
    real_losses, real_optimizer, real_prepare = _ORIGINALS

    def prepare(*args, **kwargs):  # type: ignore[no-untyped-def]
        mon.prepared = real_prepare(*args, **kwargs)
        return mon.prepared

    def losses(model, video, cfg, step, ix, iy, t):  # type: ignore[no-untyped-def]
        mon.model, mon.video = model, video
        total, terms = real_losses(model, video, cfg, step, ix, iy, t)
        mon.check_losses(step, total, terms)
        return total, terms

    def optimizer(model, cfg, device):  # type: ignore[no-untyped-def]
        opt = real_optimizer(model, cfg, device)
        opt.register_step_pre_hook(lambda o, args, kwargs: mon.check_grads(o))
        opt.register_step_post_hook(lambda o, args, kwargs: mon.check_params(o))
        return opt

    monkeypatch.setattr(trainer, "prepare_clip", prepare)
    monkeypatch.setattr(trainer, "compute_losses", losses)
    monkeypatch.setattr(trainer, "make_optimizer", optimizer)
    return mon


def monitored_fit(
    monkeypatch: Any,
    frames_dir: Path,
    mask_dirs: list[Path],
    run: Path,
    preset: str = "draft",
    **overrides: str,
) -> tuple[dict, FitMonitor]:
    """A short real fit on CPU with the probes installed; returns its metrics and what the probes saw."""
    mon = install_probes(monkeypatch)
    cfg = apply_overrides(preset_config(preset), {**QUICK, **overrides})
    stream = io.StringIO()
    metrics = quiet_fit(run, cfg, FitInputs(frames_dir, list(mask_dirs)), stream)
    mon.psnr_curve = [
        (m["step"], m["psnr"])
        for m in map(C.parse_progress_line, stream.getvalue().splitlines())
        if m and m["event"] == C.EVENT_PROGRESS
    ]
    mon.assert_stable(cfg.steps)
    assert math.isfinite(metrics["psnr"]) and all(math.isfinite(v) for v in metrics["alpha_iou"])
    return metrics, mon
