"""Float edit layers: an 8-bit edit layer's pixels (sRGB-encoded, straight alpha) -> scene-linear, premultiplied
floats, what the float edit layer ``<Layer>.exr`` (``contract.float_edit_layer``) holds. No bpy here.

Pure Python over ``array.array`` (the add-on ships no numpy, and Blender's Python has no OCIO binding); the decode
is the contract's exact IEC 61966-2-1 curve, within 2.4e-5 of the OCIO decode Blender and the engine apply to the
PNG (a tenth of the smallest 8-bit step). Once baked, the EXR is read raw, identically, by both.
"""

from __future__ import annotations

import array

from ...engine import contract as C  # type: ignore[import-not-found]

#: RGBA: four floats per pixel, alpha last.
CHANNELS = 4


def straight_srgb_to_premultiplied_linear(px: array.array) -> array.array:
    """RGBA floats (sRGB-encoded, straight alpha) -> linear, premultiplied; alpha clamped to [0, 1]. The decoded
    values are cached: an 8-bit image has at most 256 of them."""
    out = array.array("f", [0.0]) * len(px)
    cache: dict[float, float] = {}
    for i in range(0, len(px), CHANNELS):
        a = min(max(px[i + 3], 0.0), 1.0)
        for k in range(3):
            c = px[i + k]
            lin = cache.get(c)
            if lin is None:
                lin = cache[c] = C.srgb_to_linear(c)
            out[i + k] = lin * a
        out[i + 3] = a
    return out
