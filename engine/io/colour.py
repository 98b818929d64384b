"""sRGB transfer functions: the one place display-encoded and scene-linear values meet.

The fit works on display-encoded values (what the eye compares); EXR passes, atlases and the edit
composite are scene-linear like Blender's compositor, so the engine's render and Blender's agree.
"""

from __future__ import annotations

import numpy as np

#: Linear values at or below this use the linear segment of the sRGB curve (IEC 61966-2-1).
SRGB_LINEAR_CUTOFF = 0.0031308
#: Encoded values at or below this decode through the linear segment.
SRGB_ENCODED_CUTOFF = 0.04045


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """Decode sRGB to linear (float32). Values outside [0, 1] extend the curve symmetrically."""
    x = np.asarray(x, dtype=np.float32)
    a = np.abs(x)
    lin = np.where(a <= SRGB_ENCODED_CUTOFF, a / 12.92, np.power((a + 0.055) / 1.055, 2.4, dtype=np.float32))
    return (np.sign(x) * lin).astype(np.float32)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Encode linear to sRGB (float32); negatives mirror, values above 1 follow the curve (no clipping)."""
    x = np.asarray(x, dtype=np.float32)
    a = np.abs(x)
    enc = np.where(a <= SRGB_LINEAR_CUTOFF, a * 12.92, 1.055 * np.power(a, 1.0 / 2.4, dtype=np.float32) - 0.055)
    return (np.sign(x) * enc).astype(np.float32)


def to_linear(x: np.ndarray, colorspace: str) -> np.ndarray:
    """Pixel values of a file in ``colorspace`` ("sRGB" or "linear") as scene-linear float32."""
    if colorspace == "linear":
        return np.asarray(x, dtype=np.float32)
    if colorspace == "sRGB":
        return srgb_to_linear(x)
    raise ValueError(f"unknown colour space {colorspace!r}")


__all__ = ["linear_to_srgb", "srgb_to_linear", "to_linear"]
