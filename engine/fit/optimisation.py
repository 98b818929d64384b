"""The fit's optimiser and learning-rate schedule, as a new fit builds them and a resume restores them."""

from __future__ import annotations

from collections.abc import Callable

import torch

from ..config import FitConfig
from ..model.atlas_model import AtlasModel

#: The learning rate's decay never goes below this fraction (a zero ratio would stop the decay's logarithm).
MIN_LR_RATIO = 1e-6


def make_optimizer(model: AtlasModel, cfg: FitConfig, device: torch.device) -> torch.optim.Optimizer:
    """Adam; the fused kernel where the device has one (on CPU it halves the cost of updating dense grids)."""
    groups = model.param_groups(cfg)
    try:
        return torch.optim.Adam(groups, fused=device.type in ("cpu", "cuda"))
    except (RuntimeError, TypeError):
        return torch.optim.Adam(groups)


def make_scheduler(optim: torch.optim.Optimizer, cfg: FitConfig) -> torch.optim.lr_scheduler.LambdaLR:
    """The fit's learning-rate schedule: exponential decay to ``lr_final_ratio`` at ``cfg.steps``; the mappings' group
    there by ``cfg.lr_mapping_steps`` when that is sooner."""
    ratio = max(cfg.lr_final_ratio, MIN_LR_RATIO)

    def decay(last: int) -> Callable[[int], float]:
        steps = max(last, 1)
        return lambda s: ratio ** (min(s, steps) / steps)

    mapping_last = min(cfg.lr_mapping_steps, cfg.steps) if cfg.lr_mapping_steps > 0 else cfg.steps
    lambdas = [decay(mapping_last if group.get("name") == "mappings" else cfg.steps) for group in optim.param_groups]
    return torch.optim.lr_scheduler.LambdaLR(optim, lambdas)
