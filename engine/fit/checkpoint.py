"""Checkpoints: atomic writes, safe loads (``weights_only=True``), everything needed to resume exactly."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch

from ..errors import InputError
from ..io.atomic import atomic_write

__all__ = ["CHECKPOINT_DAMAGED_FIX", "checkpoint_bytes", "load_checkpoint", "nonfinite_entries", "save_checkpoint"]

#: The fix for a checkpoint that cannot be used: the artist's edits and exports survive a --refit.
CHECKPOINT_DAMAGED_FIX = "restore it, or fit again with --refit (edits and exports are kept)"

#: What torch.save adds to the tensors' bytes (the pickled structure, the zip's headers), per tensor and in all:
#: a full disk's message asks for the tensors plus this, so freeing what it says is enough.
CHECKPOINT_OVERHEAD_PER_TENSOR = 1024
CHECKPOINT_OVERHEAD = 1024 * 1024


def _tensors(value: Any, where: str = "") -> Iterator[tuple[str, torch.Tensor]]:
    """Every tensor inside a checkpoint's nested dicts and lists, with where it is (``optim/state/3/exp_avg``)."""
    if isinstance(value, torch.Tensor):
        yield where, value
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from _tensors(item, f"{where}/{key}" if where else str(key))
    elif isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            yield from _tensors(item, f"{where}/{i}" if where else str(i))


def checkpoint_bytes(state: dict[str, Any]) -> int:
    """About what ``torch.save(state)`` writes: every tensor's bytes plus the format's overhead (``need=`` of the
    atomic write, so a full disk says how much to free)."""
    tensors = [t for _, t in _tensors(state)]
    data = sum(t.numel() * t.element_size() for t in tensors)
    return data + CHECKPOINT_OVERHEAD_PER_TENSOR * len(tensors) + CHECKPOINT_OVERHEAD


def nonfinite_entries(state: dict[str, Any]) -> list[str]:
    """Where a checkpoint holds NaN or Inf (floating tensors only): a checkpoint is written only when this is
    empty, so the one on disk is always one a fit can continue from."""
    return [
        where
        for where, t in _tensors(state)
        if t.is_floating_point() and t.numel() and not bool(torch.isfinite(t).all())
    ]


def save_checkpoint(path: Path, state: dict[str, Any]) -> None:
    atomic_write(path, lambda tmp: torch.save(state, tmp), fsync=False, need=checkpoint_bytes(state))


def load_checkpoint(path: Path, device: torch.device) -> dict[str, Any]:
    try:
        return torch.load(path, map_location=device, weights_only=True)
    except FileNotFoundError:
        raise InputError(path, "no checkpoint to resume from", "run `fit` without --resume first") from None
    except Exception as exc:  # corrupt or foreign file
        raise InputError(
            path,
            f"checkpoint cannot be read ({type(exc).__name__})",
            CHECKPOINT_DAMAGED_FIX,
        ) from None
