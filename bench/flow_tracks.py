"""The point-tracking baseline an atlas must beat: DIS optical flow (OpenCV, preset ``medium``: the engine's own flow
backend, ``engine.data.flow.DISFlow``) chained frame to frame on the NATIVE plate, forward and backward from each
query frame, each position advanced by the flow bilinearly sampled where it is. The fitting bench's baseline
(``tracking.chained_flow_tracks`` on the fit's flow) is the same chain on the working-resolution plate."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bench.report_file import to_plate_scale
from bench.tracking import Tracks, chain_flow, track_report
from engine.data.flow import DISFlow
from engine.io.clip import iter_frames, open_clip
from engine.io.colour import to_working

#: DIS's speed/accuracy preset (``engine.data.flow.DIS_PRESETS``): the one the engine fits with.
DIS_PRESET = "medium"
#: 8-bit full scale: frames are kept as 8-bit codes (what DIS reads) so a long native plate fits in memory.
BYTE_MAX = 255.0


def plate_codes(frames_dir: str | Path) -> tuple[list[np.ndarray], tuple[int, int]]:
    """The clip's frames as 8-bit RGB [H, W, 3] in the fit's working encoding (sRGB-encoded: a linear EXR plate
    would put most of its detail in the lowest codes), and its native (W, H)."""
    info = open_clip(frames_dir)
    codes = []
    for rgb in iter_frames(info):
        enc = np.nan_to_num(to_working(rgb, info.colorspace, info.colour_config), nan=0.0, posinf=1.0, neginf=0.0)
        codes.append(np.rint(np.clip(enc, 0.0, 1.0) * BYTE_MAX).astype(np.uint8))
    return codes, (info.width, info.height)


def dis_flow(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """[H, W, 2] float32 flow from 8-bit RGB frame ``a`` to ``b`` (pixel (i, j) moves by it)."""
    scale = np.float32(1.0 / BYTE_MAX)
    return DISFlow(DIS_PRESET)(a.astype(np.float32) * scale, b.astype(np.float32) * scale)


def dis_flow_tracks(frames: Sequence[np.ndarray], query_txy: np.ndarray, num_frames: int) -> np.ndarray:
    """Chained DIS flow from each query (t, x, y) (pixel centre i + 0.5), forward and backward: [N, num_frames, 2].
    ``tracking.chain_flow`` with each frame pair's flow computed when the chain reaches it, so a long native plate's
    flow is never all in memory; pairs no query needs are skipped."""
    return chain_flow(
        query_txy,
        num_frames,
        lambda t: dis_flow(frames[t], frames[t + 1]),
        lambda t: dis_flow(frames[t], frames[t - 1]),
    )


def clip_flow_tracks(frames_dir: str | Path, tracks: Tracks) -> tuple[np.ndarray, Tracks]:
    """DIS tracks of ``tracks``' queries on the plate in ``frames_dir`` (its frames in order are the tracks'
    frames): (positions [N, T, 2] in the tracks' pixels, the tracks cut to the plate's length)."""
    codes, size = plate_codes(frames_dir)
    tracks = tracks.cut(len(codes))
    scale = to_plate_scale(tracks, size)
    q = tracks.query_txy.astype(np.float64).copy()
    q[:, 1:3] *= scale
    return dis_flow_tracks(codes, q, tracks.num_frames) / scale, tracks


def score_clip(frames_dir: str | Path, tracks: Tracks) -> dict:
    """``clip_flow_tracks`` scored by ``tracking.track_report``."""
    pred, cut = clip_flow_tracks(frames_dir, tracks)
    return {**track_report(pred, cut), "frames": str(Path(frames_dir).resolve())}


__all__ = ["DIS_PRESET", "clip_flow_tracks", "dis_flow", "dis_flow_tracks", "plate_codes", "score_clip"]
