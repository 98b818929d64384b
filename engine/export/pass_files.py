"""A frame's pass file as an export writes it: its name (the plate's frame number, padded as the plate's files
are), the size of its channels, and the STMap copy of a layer's UV pass.

Torch-free, so an export made by hand (without a fit) names and fills its passes the same way.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .. import contract as C
from ..terms.export_names import (
    ALPHA_CHANNELS,
    PASS_PRECISION_COMPACT,
    PASS_PRECISION_FULL,
    PASS_PRECISIONS,
    PASS_UV_STEP,
    PASSES_DIR,
    STMAP_CHANNELS,
    frame_padding,
    pass_file_name,
)

if TYPE_CHECKING:
    from ..fit.run_folder import ClipRecord

#: A layer's pass channels (UV X, Y, Z, alpha and the STMap copy) and their bytes uncompressed: the disk-full
#: estimate of a frame of passes before any is written.
PASS_CHANNELS_PER_LAYER = len(C.UV_CHANNELS) + len(ALPHA_CHANNELS) + len(STMAP_CHANNELS)
PASS_BYTES_PER_CHANNEL = 4


def pass_padding(clip: ClipRecord) -> int:
    """The digits of the pass files' frame numbers: the plate's own padding (``terms.export_names.frame_padding``)."""
    return frame_padding(clip.frame_files, clip.frame_numbers)


def pass_file(dest: Path, number: int, clip: ClipRecord) -> Path:
    return dest / PASSES_DIR / pass_file_name(number, pass_padding(clip))


def kept_precision(
    u: np.ndarray, v: np.ndarray, coverage: np.ndarray, alpha: np.ndarray, precision: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A layer's u, v, coverage and alpha with the bits ``precision`` keeps (``terms.export_names.PASS_PRECISIONS``),
    float32 either way. ``compact``: alpha and coverage rounded to half float's precision towards zero (they lie in
    0..1, where half's step is at most 2^-11: at most 4.9e-4 off, and the layers' sum stays at most one), u and v to the
    nearest multiple of ``terms.export_names.PASS_UV_STEP`` (a power of two: the division is exact, whatever the value).
    The networks' lowest bits are noise ZIP cannot compress; without them a frame of passes takes half the bytes
    (``bench export-size``). NaN stays NaN."""
    if precision == PASS_PRECISION_FULL:
        return u, v, coverage, alpha
    if precision != PASS_PRECISION_COMPACT:
        raise ValueError(f"unknown pass precision {precision!r}: use one of {', '.join(PASS_PRECISIONS)}")
    step = np.float32(PASS_UV_STEP)
    grid = [(np.round(np.asarray(x, np.float32) / step) * step).astype(np.float32) for x in (u, v)]
    return grid[0], grid[1], _half_down(coverage), _half_down(alpha)


def _half_down(values: np.ndarray) -> np.ndarray:
    """``values`` (0..1) rounded to half float's precision towards zero, as float32: the layers' opacities summed
    stay at most one (rounded to nearest they could pass it by 2^-12 per layer, and a compositor that clamps
    ``1 - sum`` would then differ from one that does not). At most 2^-11 off, NaN kept."""
    given = np.asarray(values, np.float32)
    half = given.astype(np.float16)
    over = np.abs(half.astype(np.float32)) > np.abs(given)  # rounded away from zero: one step back
    half[over] = np.nextafter(half[over], np.float16(0))
    return half.astype(np.float32)


def stmap_values(chans: dict[str, np.ndarray], uv_pass: str) -> tuple[np.ndarray, ...]:
    """A layer's STMap copy (terms.export_names.STMAP_CHANNELS: R, G, B, A) from its UV pass: u, v, zeros and the
    coverage, the same float32 values (not half: on a 1000-texel atlas half floats round u, v by up to a quarter
    texel)."""
    u, v, z = (chans[C.channel_name(uv_pass, c)] for c in C.UV_CHANNELS)
    return u, v, np.zeros_like(u), z


__all__ = [
    "PASS_BYTES_PER_CHANNEL",
    "PASS_CHANNELS_PER_LAYER",
    "kept_precision",
    "pass_file",
    "pass_padding",
    "stmap_values",
]
