"""Paint slip: how far paint on an export moves away from the plate's own motion between neighbouring frames.

No ground truth needed. For pixels a foreground layer owns in frame t (``Z > OWNED_COVERAGE``), where the DIS flow
to frame t+1 survives a round trip (``ROUND_TRIP_PX``), paint at that pixel's UV shows in frame t+1 at the owned
pixel whose UV is nearest (``paint_tracking.nearest_positions``, sub-pixel); the slip is that position's distance
from where the flow carries the pixel. A fit that follows the plate slips a fraction of a pixel (a swan gliding:
about 0.1 px); paint on a mapping that cannot follow legs and a turning head slips pixels per frame, which the eye
sees as swimming long before a track drifts away. It is the frame-to-frame half of what `paint-tracks` scores, on
every clip, tracks or not.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.flow_tracks import dis_flow, plate_codes
from bench.paint_tracking import OWNED_COVERAGE, nearest_positions, texel_uv
from engine import contract as C
from engine.errors import InputError
from engine.export.manifest import Manifest
from engine.io.clip import open_clip

#: A flow vector counts where the backward flow brings its end back within this many pixels of its start: the
#: motion is then well defined, not an occlusion or a textureless guess.
ROUND_TRIP_PX = 0.5
#: The fix of a plate that is not the export's.
FIX_PLATE = "pass the plate the export was made from"
#: Pixels sampled per frame pair (the median of a few thousand is stable to a hundredth of a pixel).
SAMPLES_PER_FRAME = 1500


def frame_slip(
    uv_a: np.ndarray,
    owned_a: np.ndarray,
    uv_b: np.ndarray,
    owned_b: np.ndarray,
    forward: np.ndarray,
    backward: np.ndarray,
    samples: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """The slip (pixels) of up to ``samples`` owned pixels of frame a with a round-trip-consistent flow to frame b.

    ``uv_*`` [H, W, 2] in texels, ``owned_*`` bool [H, W], ``forward`` (a -> b) and ``backward`` (b -> a) [H, W, 2]
    flows, pixel (i, j) moving by them. Empty when no pixel qualifies (nothing owned in either frame, or no
    consistent flow)."""
    h, w = owned_a.shape
    if not owned_b.any():
        return np.zeros(0)
    iy, ix = np.nonzero(owned_a)
    if len(iy) > samples:
        pick = rng.choice(len(iy), samples, replace=False)
        iy, ix = iy[pick], ix[pick]
    to_x, to_y = ix + forward[iy, ix, 0], iy + forward[iy, ix, 1]
    inside = (to_x >= 0) & (to_x <= w - 1) & (to_y >= 0) & (to_y <= h - 1)
    bx = np.clip(np.rint(to_x).astype(np.int64), 0, w - 1)
    by = np.clip(np.rint(to_y).astype(np.int64), 0, h - 1)
    back = backward[by, bx]
    round_trip = np.hypot(forward[iy, ix, 0] + back[:, 0], forward[iy, ix, 1] + back[:, 1])
    keep = inside & (round_trip < ROUND_TRIP_PX)
    if not keep.any():
        return np.zeros(0)
    iy, ix, to_x, to_y = iy[keep], ix[keep], to_x[keep], to_y[keep]
    painted = nearest_positions(uv_b, owned_b, uv_a[iy, ix]) - 0.5  # pixel centres at i + 0.5 there, at i here
    return np.hypot(painted[:, 0] - to_x, painted[:, 1] - to_y)


def _summary(slips: list[np.ndarray]) -> dict:
    px = np.concatenate(slips) if slips else np.zeros(0)
    if not px.size:
        return {"median_px": None, "mean_px": None, "p90_px": None, "pixels": 0}
    return {
        "median_px": float(np.median(px)),
        "mean_px": float(np.mean(px)),
        "p90_px": float(np.percentile(px, 90)),
        "pixels": int(px.size),
    }


def export_slip(manifest_path: str | Path, plate: str | Path, samples: int = SAMPLES_PER_FRAME, seed: int = 0) -> dict:
    """Every foreground layer's slip over each pair of neighbouring exported frames, and all foreground layers
    pooled (``plate``: the clip the export was made from; its frames are matched to the export's by number)."""
    manifest = Manifest(manifest_path)
    codes, size = plate_codes(plate)
    if size != manifest.resolution:
        w, h = manifest.resolution
        raise InputError(plate, f"is {size[0]}x{size[1]}, the export's passes are {w}x{h}", FIX_PLATE)
    at = {number: k for k, number in enumerate(open_clip(plate).frame_numbers)}
    numbers = manifest.frames
    missing = [n for n in numbers if n not in at]
    if missing:
        raise InputError(plate, f"has no frame {missing[0]} of the export", FIX_PLATE)
    layers = [i for i, layer in enumerate(manifest.layers) if layer["role"] == C.ROLE_FOREGROUND]
    rng = np.random.default_rng(seed)
    slips: dict[int, list[np.ndarray]] = {i: [] for i in layers}

    def owned_uvs(number: int) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """Each foreground layer's UVs in texels and the pixels it owns, in one exported frame."""
        passes = manifest.read_passes(number)
        return {
            i: (texel_uv(passes[i], tuple(manifest.layers[i]["atlas_size"])), passes[i].z > OWNED_COVERAGE)
            for i in layers
        }

    ahead = owned_uvs(numbers[0]) if numbers else {}
    for t in range(len(numbers) - 1):
        here, ahead = ahead, owned_uvs(numbers[t + 1])  # each frame read and converted once
        a_code, b_code = codes[at[numbers[t]]], codes[at[numbers[t + 1]]]
        forward, backward = dis_flow(a_code, b_code), dis_flow(b_code, a_code)
        for i in layers:
            slips[i].append(frame_slip(*here[i], *ahead[i], forward, backward, samples, rng))
    return {
        "layers": {manifest.layers[i]["name"]: _summary(slips[i]) for i in layers},
        "foreground": _summary([s for i in layers for s in slips[i]]),
        "frame_pairs": max(len(numbers) - 1, 0),
        "manifest": str(manifest.path),
    }


__all__ = ["ROUND_TRIP_PX", "SAMPLES_PER_FRAME", "export_slip", "frame_slip"]
