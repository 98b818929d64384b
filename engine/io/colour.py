"""sRGB transfer functions: the one place display-encoded and scene-linear values meet.

The fit works on display-encoded values (what the eye compares); EXR passes, atlases and the edit
composite are scene-linear like Blender's compositor, so the engine's render and Blender's agree.
"""

from __future__ import annotations

import numpy as np

from engine import contract as C

# The curve's constants are the contract's (IEC 61966-2-1), shared with the add-on's scalar decode.
SRGB_LINEAR_CUTOFF = C.SRGB_LINEAR_CUTOFF
SRGB_ENCODED_CUTOFF = C.SRGB_ENCODED_CUTOFF


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """Decode sRGB to linear (float32). Values outside [0, 1] extend the curve symmetrically."""
    x = np.asarray(x, dtype=np.float32)
    a = np.abs(x)
    decoded = np.power((a + C.SRGB_OFFSET) / C.SRGB_SCALE, C.SRGB_GAMMA, dtype=np.float32)
    lin = np.where(a <= SRGB_ENCODED_CUTOFF, a / C.SRGB_SLOPE, decoded)
    return (np.sign(x) * lin).astype(np.float32)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Encode linear to sRGB (float32); negatives mirror, values above 1 follow the curve (no clipping)."""
    x = np.asarray(x, dtype=np.float32)
    a = np.abs(x)
    encoded = C.SRGB_SCALE * np.power(a, 1.0 / C.SRGB_GAMMA, dtype=np.float32) - C.SRGB_OFFSET
    enc = np.where(a <= SRGB_LINEAR_CUTOFF, a * C.SRGB_SLOPE, encoded)
    return (np.sign(x) * enc).astype(np.float32)


def to_linear(x: np.ndarray, colorspace: str) -> np.ndarray:
    """Pixel values of a file in ``colorspace`` ("sRGB" or "linear") as scene-linear float32."""
    if colorspace == "linear":
        return np.asarray(x, dtype=np.float32)
    if colorspace == "sRGB":
        return srgb_to_linear(x)
    raise ValueError(f"unknown colour space {colorspace!r}")


__all__ = ["linear_to_srgb", "srgb_to_linear", "to_linear"]
