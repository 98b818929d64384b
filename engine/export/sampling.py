"""What the fitted networks say at the points an export needs: every layer's mapping and alpha at pixel centres,
and a layer's atlas colour at its texel centres.

The networks are continuous, so passes are evaluated at every native pixel centre whatever the working
resolution of the fit; points go through the networks ``EVAL_CHUNK`` at a time, so memory stays bounded at any
plate size.
"""

from __future__ import annotations

import numpy as np
import torch

from ..fit.evaluation import EVAL_CHUNK
from ..model.atlas_model import AtlasModel
from .atlas_frame import LayerFrame


@torch.no_grad()
def eval_pixels(model: AtlasModel, xy: torch.Tensor, t: int) -> tuple[list[np.ndarray], np.ndarray]:
    """Model uv of every layer [N, 2] and layer weights [N, L] at working-resolution points ``xy``."""
    n = xy.shape[0]
    uvs = [np.empty((n, 2), np.float32) for _ in range(model.num_layers)]
    wts = np.empty((n, model.num_layers), np.float32)
    for s in range(0, n, EVAL_CHUNK):
        sl = slice(s, s + EVAL_CHUNK)
        tt = torch.full((xy[sl].shape[0],), t, dtype=torch.long, device=xy.device)
        wts[sl] = model.alpha(xy[sl], tt).float().cpu().numpy()
        for i in range(model.num_layers):
            uvs[i][sl] = model.uv(i, xy[sl], tt).float().cpu().numpy()
    return uvs, wts


def pixel_grid(size: tuple[int, int], scale: tuple[float, float], device: torch.device) -> torch.Tensor:
    """Pixel centres of a ``size`` frame, in working-resolution coordinates (x * sx, y * sy)."""
    w, h = size
    ys, xs = torch.meshgrid(
        torch.arange(h, device=device, dtype=torch.float32),
        torch.arange(w, device=device, dtype=torch.float32),
        indexing="ij",
    )
    return torch.stack(((xs.reshape(-1) + 0.5) * scale[0], (ys.reshape(-1) + 0.5) * scale[1]), -1)


@torch.no_grad()
def colours_at(model: AtlasModel, layer: int, uv: np.ndarray, device: torch.device) -> np.ndarray:
    """The layer's atlas colour [N, 3] at atlas points ``uv`` [N, 2] (the model's units), clipped to [0, 1] as the
    texture is written."""
    pts = torch.from_numpy(np.ascontiguousarray(uv, dtype=np.float32)).to(device)
    out = np.empty((pts.shape[0], 3), np.float32)
    for s in range(0, pts.shape[0], EVAL_CHUNK):
        out[s : s + EVAL_CHUNK] = model.color(layer, pts[s : s + EVAL_CHUNK]).float().cpu().numpy()
    return np.clip(out, 0.0, 1.0)


def atlas_colours(model: AtlasModel, layer: int, frame: LayerFrame, device: torch.device) -> np.ndarray:
    w, h = frame.size
    return colours_at(model, layer, frame.texel_centres().reshape(-1, 2), device).reshape(h, w, 3)


__all__ = [
    "atlas_colours",
    "colours_at",
    "eval_pixels",
    "pixel_grid",
]
