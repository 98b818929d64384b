"""The paper's edit equations, in numpy: the reference the Blender compositor tree is checked against.

For each pixel and layer i, the layer's edit RGBA (premultiplied, linear) is sampled at the pixel's UV
and blended over the ORIGINAL plate colour; the layers are then blended by the learned alpha:

    out = sum_i alpha_i * (a_i * rgb_i + (1 - a_i) * plate) = plate * (1 - sum_i Z_i a_i) + sum_i Z_i P_i

with ``Z_i`` the UV pass's third channel (alpha_i where the layer's atlas covers the pixel) and
``P_i = a_i * rgb_i`` the premultiplied edit sample. That is exactly what Blender's Map UV gives
(``sample(image, uv) * Z``) summed over layers and put over the plate with one premultiplied Alpha Over.
With every edit layer empty it returns the plate bit for bit.

Texture conventions (Blender's Map UV, Nuke's STMap): u, v in [0, 1] with the origin at the bottom-left,
texel centres at ((i + 0.5) / W, (j + 0.5) / H), and "Clip" extension: outside the texture is zero.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..export.manifest import LayerPasses
from ..io.colour import srgb_to_linear
from ..io.images import image_header, read_image

FILTERS = ("bilinear", "nearest")


def edit_to_premultiplied(pixels: np.ndarray, is_float: bool) -> np.ndarray:
    """An edit image as linear premultiplied RGBA float32 [H, W, 4], the way Blender loads it:
    integer files (PNG) are sRGB with straight alpha, decoded by the OCIO transform Blender applies (the same
    values to the last bit, docs/colour.md); float files (EXR) are scene-linear Rec.709 and premultiplied."""
    h, w, c = pixels.shape
    if c == 4:
        rgb, a = pixels[..., :3], pixels[..., 3:4]
    elif c == 3:
        rgb, a = pixels, np.ones((h, w, 1), np.float32)
    elif c == 2:
        rgb, a = np.repeat(pixels[..., :1], 3, -1), pixels[..., 1:2]
    elif c == 1:
        rgb, a = np.repeat(pixels, 3, -1), np.ones((h, w, 1), np.float32)
    else:
        raise ValueError(f"edit image has {c} channels; expected grey, RGB or RGBA")
    rgb = np.nan_to_num(rgb.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    a = np.clip(np.nan_to_num(a.astype(np.float32), nan=0.0), 0.0, 1.0)
    if is_float:
        return np.concatenate((rgb, a), -1)
    return np.concatenate((srgb_to_linear(rgb) * a, a), -1)


#: Blender turns an 8-bit image's code values into floats as ``code * (1 / 255)`` (a float32 product), which is
#: one float step off ``code / 255`` for some codes; the edit layers are decoded from the same floats, so the
#: OCIO decode that follows gives Blender's values to the last bit (docs/colour.md).
BYTE_SCALE = np.float32(1.0 / 255.0)


def load_edit(path: str | Path) -> np.ndarray:
    """Read an edit layer file as linear premultiplied RGBA [H, W, 4]."""
    pixels, is_float = read_image(path)
    if not is_float and image_header(path)[2] == 8:
        pixels = np.rint(pixels * np.float32(255.0)) * BYTE_SCALE
    return edit_to_premultiplied(pixels, is_float)


def sample_texture(tex: np.ndarray, uv: np.ndarray, filter: str = "bilinear") -> np.ndarray:
    """Sample ``tex`` [H, W, C] (row 0 at the top) at ``uv`` [..., 2] with Clip extension -> [..., C]."""
    if filter not in FILTERS:
        raise ValueError(f"unknown filter {filter!r}; use one of {FILTERS}")
    th, tw, c = tex.shape
    u = uv[..., 0].astype(np.float64)
    v = uv[..., 1].astype(np.float64)
    inside = (u >= 0.0) & (u <= 1.0) & (v >= 0.0) & (v <= 1.0)
    if filter == "nearest":
        # the texel coordinate in float32, as Blender's Map UV (and a GPU) computes it: in float64 a UV on a
        # texel edge can round to the other side of it and pick the neighbouring texel
        col = np.clip(np.floor(uv[..., 0].astype(np.float32) * np.float32(tw)), 0, tw - 1).astype(np.int64)
        row_up = np.clip(np.floor(uv[..., 1].astype(np.float32) * np.float32(th)), 0, th - 1).astype(np.int64)
        out = tex[th - 1 - row_up, col]
        return np.where(inside[..., None], out, 0.0).astype(np.float32)
    # continuous texel coordinates (texel centres at integers), rows counted from the bottom
    x = u * tw - 0.5
    y = v * th - 0.5
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    fx = (x - x0)[..., None].astype(np.float32)
    fy = (y - y0)[..., None].astype(np.float32)
    out = np.zeros((*u.shape, c), np.float32)
    for dy, wy in ((0, 1.0 - fy), (1, fy)):
        for dx, wx in ((0, 1.0 - fx), (1, fx)):
            xi, yi = x0 + dx, y0 + dy
            ok = inside & (xi >= 0) & (xi < tw) & (yi >= 0) & (yi < th)  # texels outside the image are zero
            vals = tex[th - 1 - np.clip(yi, 0, th - 1), np.clip(xi, 0, tw - 1)]
            out += np.where(ok[..., None], vals, 0.0) * (wx * wy)
    return out


def composite_edits(
    plate_linear: np.ndarray,
    passes: list[LayerPasses],
    edits: list[np.ndarray | None],
    filter: str = "bilinear",
) -> np.ndarray:
    """Edited frame [H, W, 3] (linear) from the plate, each layer's passes and premultiplied edits."""
    return composite_touched(plate_linear, passes, edits, filter)[0]


def composite_touched(
    plate_linear: np.ndarray,
    passes: list[LayerPasses],
    edits: list[np.ndarray | None],
    filter: str = "bilinear",
) -> tuple[np.ndarray, np.ndarray]:
    """``composite_edits`` and where an edit touched the frame (bool [H, W]: some coverage or colour added); the
    other pixels are the plate's, so a render in the plate's colour space copies them instead of converting."""
    out_premult = np.zeros_like(plate_linear, dtype=np.float32)
    cover = np.zeros(plate_linear.shape[:2], np.float32)
    for p, edit in zip(passes, edits, strict=True):
        if edit is None:
            continue
        s = sample_texture(edit, p.uv, filter) * p.z[..., None]
        out_premult += s[..., :3]
        cover += s[..., 3]
    touched = (cover != 0.0) | (out_premult != 0.0).any(-1)
    return plate_linear * (1.0 - cover[..., None]) + out_premult, touched


def edit_is_empty(edit: np.ndarray | None) -> bool:
    return edit is None or not bool(np.any(edit[..., 3] > 0.0))


__all__ = [
    "FILTERS",
    "composite_edits",
    "composite_touched",
    "edit_is_empty",
    "edit_to_premultiplied",
    "load_edit",
    "sample_texture",
]
