"""A quick visual check of a fit: a contact sheet of frames and the atlases, written as PNG.

Not the export (that writes EXR passes at native resolution); this is what a person looks at first to
judge the decomposition: does the foreground alpha follow the object, does the background layer hold
the plate without the object, do the atlases look like unwrapped, undistorted pictures.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch

from ..data.video import frame_pixels
from ..io.atomic import atomic_write_bytes
from ..model.atlas_model import AtlasModel

#: Atlas images in the sheet are rendered at this many pixels per side.
ATLAS_PX = 384


def _to_u8(img: np.ndarray) -> np.ndarray:
    return (np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


@torch.no_grad()
def layer_images(model: AtlasModel, t: int, size: tuple[int, int], device: torch.device) -> list[np.ndarray]:
    """[reconstruction, alpha of layer 1.. as grey, each layer's colour] for frame ``t``."""
    w, h = size
    xy, tt = frame_pixels(size, t, device)
    wts = model.alpha(xy, tt)
    cols = [model.color(i, model.uv(i, xy, tt)) for i in range(model.num_layers)]
    rec = sum(wts[:, i : i + 1] * cols[i] for i in range(model.num_layers))
    out = [rec.reshape(h, w, 3).cpu().numpy()]
    out += [wts[:, i : i + 1].repeat(1, 3).reshape(h, w, 3).cpu().numpy() for i in range(1, model.num_layers)]
    out += [c.reshape(h, w, 3).cpu().numpy() for c in cols]
    return out


@torch.no_grad()
def atlas_image(model: AtlasModel, layer: int, px: int, device: torch.device) -> np.ndarray:
    """The layer's atlas colours over its square [-1, 1]^2, as an image (row 0 is v = -1, like the frames)."""
    g = (torch.arange(px, device=device, dtype=torch.float32) + 0.5) / px * 2.0 - 1.0
    vv, uu = torch.meshgrid(g, g, indexing="ij")
    uv = torch.stack((uu.reshape(-1), vv.reshape(-1)), -1)
    return model.color(layer, uv).reshape(px, px, 3).cpu().numpy()


def write_contact_sheet(
    model: AtlasModel,
    frames: np.ndarray,
    size: tuple[int, int],
    device: torch.device,
    path: Path,
    picks: int = 3,
) -> Path:
    """Rows: original | reconstruction | alpha(s) | per-layer colours, for a few frames; then the atlases."""
    t_count = frames.shape[0]
    ts = sorted({round(i * (t_count - 1) / max(picks - 1, 1)) for i in range(picks)})
    rows = []
    for t in ts:
        imgs = [frames[t], *layer_images(model, t, size, device)]
        rows.append(np.concatenate([_to_u8(i) for i in imgs], axis=1))
    sheet = np.concatenate(rows, axis=0)
    atl = [_to_u8(atlas_image(model, i, ATLAS_PX, device)) for i in range(model.num_layers)]
    atl_row = np.concatenate(atl, axis=1)
    if atl_row.shape[1] < sheet.shape[1]:
        atl_row = np.pad(atl_row, ((0, 0), (0, sheet.shape[1] - atl_row.shape[1]), (0, 0)))
    else:
        sheet = np.pad(sheet, ((0, 0), (0, atl_row.shape[1] - sheet.shape[1]), (0, 0)))
    sheet = np.concatenate((sheet, atl_row), axis=0)
    ok, buf = cv2.imencode(".png", cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    if not ok:
        raise RuntimeError(f"could not encode {path}")
    atomic_write_bytes(path, buf.tobytes())
    return path
