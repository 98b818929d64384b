"""A 300-frame clip: the fit stays finite and its memory is bounded, linearly, by frames x pixels.

How it is bounded: everything per frame is stored once, at working resolution, in dense arrays: frames
(float32 RGB, 12 B/px), per layer a mask and a prior label (1 + 1 B/px), forward and backward flow
(2 x 8 B/px) and their consistency flags (2 x 1 B/px): 32 B per working pixel per frame with one mask
layer. On the CPU the training tensors share memory with the prepared arrays (no second copy). A step
touches ``batch`` random pixels whatever the clip length, and evaluation renders one frame at a time in
chunks of ``EVAL_CHUNK`` pixels. The test measures both the stored tensors and the process's peak
resident memory during the fit (Linux ``VmHWM``, reset through ``/proc/self/clear_refs``).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.stability.fitcheck import monitored_fit, write_masks, write_sequence

T, H, W = 300, 24, 32

#: Stored bytes per working pixel per frame with one foreground layer (see the module docstring).
BYTES_PER_PIXEL_FRAME = 12 + 1 + 1 + 16 + 2
#: Peak resident growth allowed during the fit: a few copies of the frames while flow is computed
#: (< 64 B per pixel per frame in total) plus a fixed allowance for the model, optimiser and torch's
#: own buffers, which do not grow with the clip (the allowance is several times what they take here).
PEAK_BYTES_PER_PIXEL_FRAME = 64
FIXED_ALLOWANCE = 400 * 2**20


def _vm_hwm() -> int | None:
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def _reset_peak() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def _storage_bytes(tensors) -> int:
    seen, total = set(), 0
    for t in tensors:
        s = t.untyped_storage()
        if s.data_ptr() not in seen:
            seen.add(s.data_ptr())
            total += s.nbytes()
    return total


def _long_clip(folder: Path) -> tuple[Path, Path]:
    """A blurred-noise plate panning half a pixel per frame, and a box that steps across and back."""
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.random((H + 8, W + T // 2 + 8, 3)).astype(np.float32), (0, 0), 1.5)
    frames = np.stack([texture[4 : 4 + H, t // 2 : t // 2 + W] for t in range(T)])
    masks = np.zeros((T, H, W), bool)
    for t in range(T):
        x = 4 + abs((t // 10) % 32 - 16)
        masks[t, 6:16, x : x + 10] = True
        frames[t, 6:16, x : x + 10] = frames[t, 6:16, x : x + 10] * 0.3 + 0.6
    return write_sequence(folder / "frames", frames), write_masks(folder / "masks", masks)


@pytest.mark.slow
def test_300_frame_clip_memory_is_bounded(tmp_path, monkeypatch):
    frames, masks = _long_clip(tmp_path)
    px_frames = T * H * W
    peak_ok = _reset_peak()
    base = _vm_hwm()
    metrics, mon = monitored_fit(monkeypatch, frames, [masks], tmp_path / "run", steps="6", eval_every="3")
    peak = _vm_hwm()
    assert metrics["frames"] == T

    v, p = mon.video, mon.prepared
    stored = [v.frames, v.masks, v.mask_valid, v.prior, v.fwd, v.bwd, v.fwd_ok, v.bwd_ok]
    stored_bytes = _storage_bytes(stored)
    expected = BYTES_PER_PIXEL_FRAME * px_frames
    # the flow arrays hold T-1 pairs, so the stored total is a little under 32 B/px/frame
    assert expected * 0.98 <= stored_bytes <= expected + T * 2
    # the training tensors ARE the prepared arrays (CPU): the clip is not held twice
    assert np.shares_memory(v.frames.numpy(), p.frames)
    assert np.shares_memory(v.fwd.numpy(), p.flow.forward) and np.shares_memory(v.bwd.numpy(), p.flow.backward)
    # the model grows with frames only through per-frame motion (2x3 per layer) and the coarse alpha grid
    params = sum(t.numel() for t in mon.model.parameters())
    print(
        f"\nstored {stored_bytes / 2**20:.1f} MB, params {params}, peak growth "
        f"{(peak - base) / 2**20 if peak_ok and base and peak else float('nan'):.1f} MB"
    )
    if peak_ok and base is not None and peak is not None:
        assert peak - base <= PEAK_BYTES_PER_PIXEL_FRAME * px_frames + FIXED_ALLOWANCE
