"""Divergence: every step's loss, gradients and parameters are finite. The checks (one synchronising read each),
the names of what went NaN/Inf, and a diverged fit's one line: the likely cause and the command that continues."""

from __future__ import annotations

import dataclasses
import shlex
from collections.abc import Callable

import torch

from .. import contract as C
from ..config import LR_FIELDS, PRESETS, FitConfig
from ..errors import FitDiverged
from .run_folder import RunFolder

#: A diverged fit's message suggests the preset's rate, or this fraction of the rate it diverged with when that
#: was no higher than the preset's.
LR_RETRY_FACTOR = 0.1
#: A loss weight more than this many times its preset's (or than this, where the preset's is below 1) is named as a
#: diverged fit's likely cause: a resume keeps the weights, so lower rates alone would diverge again.
WEIGHT_SUSPECT_FACTOR = 100.0


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
