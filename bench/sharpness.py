"""Atlas sharpness: the plate re-rendered from the EXPORTED atlas textures through the exported UV passes, compared
with the plate inside the object's mask.

No network: each layer's atlas texture (``atlases/<Layer>.exr``, scene-linear, premultiplied by its coverage) is
sampled at the pixel's UV bilinearly, as a compositor's Map UV (or STMap) does (``edit.equations.sample_texture``),
un-premultiplied, and the layers are summed weighted by their coverage Z. An atlas that averages several views of
the object (a turning or bending object mapped to one place) is blurred, and its PSNR here is low on any clip,
whatever the tracks say. PSNR is measured on sRGB-encoded values clipped to [0, 1], the scale of the fit's PSNR.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from engine.edit.equations import sample_texture
from engine.errors import InputError
from engine.export.manifest import EXPORT_AGAIN, LayerPasses, Manifest
from engine.io.clip import iter_frames, open_clip, read_masks
from engine.io.colour import linear_to_srgb, to_working
from engine.io.images import read_image

#: The mean squared error is floored here, so a perfect re-render scores PSNR_CAP_DB instead of infinity.
MSE_FLOOR = 1e-10
#: 10 * log10(1 / MSE_FLOOR): the highest PSNR reported.
PSNR_CAP_DB = 10.0 * math.log10(1.0 / MSE_FLOOR)
#: A frame whose mask has fewer pixels than this is not scored (its PSNR is None): there is no object to judge.
MIN_MASK_PIXELS = 1
#: A sampled atlas colour is un-premultiplied only where its coverage exceeds this; below it the texel holds no
#: colour (0 / 0) and contributes black.
UNPREMULT_MIN_COVERAGE = 1e-6


def load_atlases(manifest: Manifest) -> list[np.ndarray]:
    """Every layer's atlas texture as premultiplied scene-linear RGBA [H, W, 4] (row 0 at the top)."""
    out = []
    for layer in manifest.layers:
        path = manifest.resolve(layer["atlas_exr"])
        if not path.is_file():
            raise InputError(path, "atlas texture does not exist", EXPORT_AGAIN)
        pixels, _ = read_image(path)
        if pixels.shape[2] != 4:
            raise InputError(path, f"atlas texture has {pixels.shape[2]} channels, not RGBA", EXPORT_AGAIN)
        out.append(pixels)
    return out


def rerender(passes: list[LayerPasses], atlases: list[np.ndarray]) -> np.ndarray:
    """The frame [H, W, 3] (scene-linear) the atlases give through the passes: sum over layers of Z times the
    atlas colour sampled bilinearly at the UV (premultiplied sample divided by its own coverage)."""
    out = np.zeros((*passes[0].z.shape, 3), np.float32)
    for p, atlas in zip(passes, atlases, strict=True):
        s = sample_texture(atlas, p.uv, "bilinear")
        cover = s[..., 3:4]
        colour = np.where(cover > UNPREMULT_MIN_COVERAGE, s[..., :3] / np.maximum(cover, UNPREMULT_MIN_COVERAGE), 0.0)
        out += p.z[..., None] * colour
    return out


def _psnr(mse: float) -> float:
    return 10.0 * math.log10(1.0 / max(mse, MSE_FLOOR))


def masked_psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float | None:
    """PSNR (dB, peak 1) of ``a`` against ``b`` [H, W, C] over the pixels of ``mask`` [H, W]; None for a mask with
    fewer than MIN_MASK_PIXELS pixels; at most PSNR_CAP_DB."""
    return PooledPSNR().add(a, b, mask)


class PooledPSNR:
    """Frame by frame, ``masked_psnr`` of each frame and, pooled, the PSNR of every masked pixel together (one
    difference per frame serves both): how the re-rendered atlas and the fit's networks are scored alike."""

    def __init__(self) -> None:
        self.sq_sum = 0.0
        self.count = 0

    def add(self, a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float | None:
        """This frame's ``masked_psnr``; its masked pixels join the pool."""
        if not mask.any():
            return None
        diff = a[mask].astype(np.float64) - b[mask].astype(np.float64)
        sq = float((diff * diff).sum())
        self.sq_sum += sq
        self.count += diff.size
        return _psnr(sq / diff.size) if int(mask.sum()) >= MIN_MASK_PIXELS else None

    @property
    def pooled(self) -> float | None:
        """The PSNR of every pixel added so far; None before any."""
        return None if self.count == 0 else _psnr(self.sq_sum / self.count)


def atlas_sharpness(manifest_path: str | Path, plate: str | Path, masks: list[str | Path]) -> dict:
    """Per exported frame, the masked PSNR of the re-render against the plate (``plate``: its frames are matched
    to the export's by frame number; ``masks``: the object's mask folders, joined); their mean over the frames
    with a mask, and the PSNR of all masked pixels together."""
    manifest = Manifest(manifest_path)
    info = open_clip(plate)
    size = manifest.resolution
    if (info.width, info.height) != size:
        raise InputError(
            info.source,
            f"plate is {info.width}x{info.height}, the export's passes are {size[0]}x{size[1]}",
            "pass the plate the export was made from",
        )
    numbers = list(info.frame_numbers)
    missing = [f for f in manifest.frames if f not in numbers]
    if missing:
        fix = "pass the plate the export was made from"
        raise InputError(info.source, f"has no frame {missing[0]} of the export", fix)
    if not masks:
        raise InputError(None, "no mask folder given", "pass the object's masks with --masks FOLDER")
    mask = np.zeros((info.num_frames, size[1], size[0]), bool)
    for folder in masks:
        mask |= read_masks(folder, info, size)
    atlases = load_atlases(manifest)
    wanted = set(manifest.frames)
    per_frame: dict[str, float | None] = {}
    pool = PooledPSNR()
    for k, rgb in enumerate(iter_frames(info)):
        number = numbers[k]
        if number not in wanted:
            continue
        plate_enc = np.clip(to_working(rgb, info.colorspace, info.colour_config), 0.0, 1.0)
        render_enc = np.clip(linear_to_srgb(rerender(manifest.read_passes(number), atlases)), 0.0, 1.0)
        per_frame[str(number)] = pool.add(render_enc, plate_enc, mask[k])
    scored = [v for v in per_frame.values() if v is not None]
    return {
        "psnr_mean": float(np.mean(scored)) if scored else None,
        "psnr_pooled": pool.pooled,
        "frames_scored": len(scored),
        "per_frame": per_frame,
        "manifest": str(manifest.path),
    }


__all__ = [
    "MIN_MASK_PIXELS",
    "MSE_FLOOR",
    "PSNR_CAP_DB",
    "UNPREMULT_MIN_COVERAGE",
    "PooledPSNR",
    "atlas_sharpness",
    "load_atlases",
    "masked_psnr",
    "rerender",
]
