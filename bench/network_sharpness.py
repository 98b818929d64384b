"""The ceiling of ``sharpness``: the fit's own networks' reconstruction against the plate inside the object's mask.

``sharpness`` re-renders the plate from the exported, discretised atlas textures; this renders it from the fitted
networks themselves, at the working size the fit saw, on the same encoding (sRGB-encoded values clipped to [0, 1])
and the same mask. The gap between the two is what the export loses: texels whose coverage the texture drops, or a
texture too coarse for the mapping. Where the networks themselves score low, the mapping averages several views of
the object, and no texture can do better.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from bench.sharpness import PooledPSNR
from engine.errors import InputError
from engine.fit.evaluation import render_frame
from engine.fit.fitted_run import load_fitted
from engine.io.clip import open_clip, read_frames, read_masks
from engine.io.colour import to_working


@torch.no_grad()
def network_sharpness(run_dir: str | Path, plate: str | Path, masks: list[str | Path], device: str = "cpu") -> dict:
    """PSNR of the fit's reconstruction against ``plate`` inside ``masks`` (joined), at the fit's working size:
    pooled over every fitted frame with a mask, and per frame (None where the mask is empty)."""
    fitted = load_fitted(run_dir, device)
    size = tuple(fitted.clip.working_size)
    info = open_clip(plate)
    numbers = list(info.frame_numbers)
    missing = [n for n in fitted.clip.frame_numbers if n not in numbers]
    if missing:
        raise InputError(info.source, f"has no frame {missing[0]} of the fit", "pass the plate the fit was made from")
    if not masks:
        raise InputError(None, "no mask folder given", "pass the object's masks with --masks FOLDER")
    frames = np.clip(to_working(read_frames(info, size), info.colorspace, info.colour_config), 0.0, 1.0)
    mask = np.zeros(frames.shape[:3], bool)
    for folder in masks:
        mask |= read_masks(folder, info, size)
    model_device = next(fitted.model.parameters()).device
    per_frame: dict[str, float | None] = {}
    pool = PooledPSNR()
    for t, number in enumerate(fitted.clip.frame_numbers):
        k = numbers.index(number)
        if not mask[k].any():
            per_frame[str(number)] = None
            continue
        rec, _ = render_frame(fitted.model, t, size, model_device)  # type: ignore[arg-type]
        per_frame[str(number)] = pool.add(np.clip(rec, 0.0, 1.0), frames[k], mask[k])
    return {"psnr_pooled": pool.pooled, "working_size": list(size), "per_frame": per_frame, "run": str(run_dir)}


__all__ = ["network_sharpness"]
