"""Where a fit runs: the torch device and the number of CPU threads."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch

from ..errors import InputError


def _mps_available() -> bool:
    return bool(getattr(torch.backends, "mps", None) and torch.backends.mps.is_available())


def select_device(name: str = "auto") -> torch.device:
    """CUDA, then MPS, then CPU for ``auto``; an explicit device that is absent is a one-line error."""
    if name == "auto":
        if torch.cuda.is_available():
            return torch.device("cuda")
        if _mps_available():
            return torch.device("mps")
        return torch.device("cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise InputError(None, "--device cuda: no CUDA device is available", "use --device auto or cpu")
    if name == "mps" and not _mps_available():
        raise InputError(None, "--device mps: MPS is not available", "use --device auto or cpu")
    if name not in ("cpu", "cuda", "mps"):
        raise InputError(None, f"unknown device {name!r}", "use auto, cpu, cuda or mps")
    return torch.device(name)


def synchronize(device: torch.device) -> None:
    """Wait for the device's queued work (CUDA runs asynchronously: a timer must wait for it)."""
    if device.type == "cuda":
        torch.cuda.synchronize()


@contextlib.contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Run with ``n`` torch CPU threads (None: leave as is), then restore the previous count.

    On a loaded machine two threads per process can be slower than one (threads wait for each other), so
    ``estimate --threads`` and the bench set and state their thread count."""
    before = torch.get_num_threads()
    if n:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


__all__ = ["select_device", "synchronize", "torch_threads"]
