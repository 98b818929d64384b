"""Checkpoints: atomic writes, safe loads (``weights_only=True``), everything needed to resume exactly."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from engine.errors import InputError
from engine.io.atomic import atomic_write

__all__ = ["load_checkpoint", "save_checkpoint"]


def save_checkpoint(path: Path, state: dict[str, Any]) -> None:
    atomic_write(path, lambda tmp: torch.save(state, tmp), fsync=False)


def load_checkpoint(path: Path, device: torch.device) -> dict[str, Any]:
    try:
        return torch.load(path, map_location=device, weights_only=True)
    except FileNotFoundError:
        raise InputError(path, "no checkpoint to resume from", "run `fit` without --resume first") from None
    except Exception as exc:  # corrupt or foreign file
        raise InputError(
            path,
            f"checkpoint cannot be read ({type(exc).__name__})",
            "delete it and fit again without --resume",
        ) from None
