"""Paint tracking scored on an EXPORT: where a dot painted on an atlas shows in every frame, against TAP-Vid tracks.

The user never sees the networks, only the exported passes (native resolution, u, v in [0, 1] with v up, the
layer's coverage in Z: docs/export.md), so this reads nothing else. A query point takes the UV of the layer that owns
it (the largest ``Alpha<Layer>`` at the query, bilinear) in its query frame; in every other frame the prediction is
the pixel, among those the layer covers (``Z >= OWNED_COVERAGE``: where its paint shows), whose UV is nearest that UV
(a KD-tree on the UVs in texels, so u and v weigh as the atlas's square texels), refined to sub-pixel by one
Gauss-Newton step on the pass's local UV Jacobian. A frame where the layer covers no pixel has no position: the
point counts as a miss there. Scores are ``tracking.track_report``'s: TAP-Vid delta_avg, native and at 256x256.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from bench.report_file import to_plate_scale
from bench.tracking import Tracks, sample_bilinear, scored_positions, track_report
from engine.errors import InputError
from engine.export.manifest import LayerPasses, Manifest

#: A pixel shows a layer's paint where the layer's coverage (the UV pass's Z) is at least this: mostly that layer's.
#: At least, not above: compact passes round coverage towards zero onto a grid holding 0.5 itself, so a fitted
#: coverage just above 0.5 reads as exactly 0.5 and is the same pixel as in a full-precision export.
OWNED_COVERAGE = 0.5
#: The sub-pixel step is skipped where the UV Jacobian's determinant (texels^2 per pixel^2) is below this: the UV
#: barely changes with the pixel there (a folded or collapsed mapping), so no step direction can be trusted.
UV_JACOBIAN_MIN_DET = 1e-6
#: The sub-pixel step moves at most this far per axis: the nearest pixel is within half a pixel of an exact match,
#: so a longer step means the local linearisation does not hold.
MAX_STEP_PX = 1.0
#: The position of a point that has none in a frame (its layer covers no pixel there): a miss at every threshold.
MISS = np.inf


def track_frame_numbers(manifest: Manifest, frames: int) -> list[int]:
    """The plate frame numbers of track frames 0..frames-1 (the clip's frames in order), each checked to have
    passes in this export."""
    numbers = [int(n) for n in manifest.clip["frame_numbers"][:frames]]
    exported = set(manifest.frames)
    missing = [n for n in numbers if n not in exported]
    if missing:
        raise InputError(
            manifest.path,
            f"frame {missing[0]} has no passes, and the tracks need frames {numbers[0]}..{numbers[-1]}",
            "export every frame of the clip (export without --frames)",
        )
    return numbers


def texel_uv(passes: LayerPasses, atlas_size: tuple[int, int]) -> np.ndarray:
    """[H, W, 2] UV in texels of the layer's atlas (u * W, v * H): distances in it are isotropic."""
    return passes.uv.astype(np.float64) * np.asarray(atlas_size, np.float64)


def query_owners(
    manifest: Manifest, numbers: list[int], query_t: np.ndarray, query_xy: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(owner layer [N], its UV in texels [N, 2]) of each query at its query frame, both bilinear at the query."""
    n = len(query_t)
    owner = np.zeros(n, np.int64)
    uv = np.zeros((n, 2), np.float64)
    for t in np.unique(query_t).tolist():
        sel = np.nonzero(query_t == t)[0]
        passes = manifest.read_passes(numbers[t])
        q = query_xy[sel]
        alphas = np.stack([sample_bilinear(p.alpha[..., None], q)[:, 0] for p in passes], -1)
        owner[sel] = alphas.argmax(-1)
        for layer in np.unique(owner[sel]).tolist():
            at = sel[owner[sel] == layer]
            size = tuple(manifest.layers[layer]["atlas_size"])
            uv[at] = sample_bilinear(texel_uv(passes[layer], size), query_xy[at])
    return owner, uv


def _derivative(uv: np.ndarray, owned: np.ndarray, iy: np.ndarray, ix: np.ndarray, axis: int) -> np.ndarray:
    """d(uv)/d(pixel) along ``axis`` (0: y, 1: x) at pixels (iy, ix), from the neighbours the layer owns: central
    where both are, one-sided where one is, zero where none is (the Jacobian guard then skips the step)."""
    h, w = owned.shape
    lim = h if axis == 0 else w
    pos = iy if axis == 0 else ix

    def neighbour(d: int) -> tuple[np.ndarray, np.ndarray]:
        j = np.clip(pos + d, 0, lim - 1)
        y, x = (j, ix) if axis == 0 else (iy, j)
        ok = (pos + d >= 0) & (pos + d < lim) & owned[y, x]
        return uv[y, x], ok

    centre = uv[iy, ix]
    (after, a_ok), (before, b_ok) = neighbour(1), neighbour(-1)
    central = (after - before) / 2.0
    forward, backward = after - centre, centre - before
    out = np.where((a_ok & b_ok)[:, None], central, np.where(a_ok[:, None], forward, backward))
    return np.where((a_ok | b_ok)[:, None], out, 0.0)


def nearest_positions(uv: np.ndarray, owned: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """[M, 2] continuous pixel positions (centre of pixel i at i + 0.5) whose UV is nearest each target UV, among
    the ``owned`` pixels of one frame (``uv`` [H, W, 2] in texels). ``MISS`` everywhere when none is owned."""
    m = len(targets)
    if not owned.any():
        return np.full((m, 2), MISS)
    iy_all, ix_all = np.nonzero(owned)
    _, k = cKDTree(uv[iy_all, ix_all]).query(targets)
    iy, ix = iy_all[k], ix_all[k]
    jac = np.stack((_derivative(uv, owned, iy, ix, 1), _derivative(uv, owned, iy, ix, 0)), -1)  # [M, 2 uv, 2 xy]
    det = np.linalg.det(jac)
    ok = np.abs(det) > UV_JACOBIAN_MIN_DET
    step = np.zeros((m, 2))
    if ok.any():
        rhs = (targets - uv[iy, ix])[ok][..., None]
        step[ok] = np.clip(np.linalg.solve(jac[ok], rhs)[..., 0], -MAX_STEP_PX, MAX_STEP_PX)
    return np.stack((ix, iy), -1) + 0.5 + step


def paint_tracks(manifest: Manifest, tracks: Tracks) -> tuple[np.ndarray, np.ndarray]:
    """Where paint at each query point shows in every frame of the export: (positions [N, T, 2] in the tracks'
    pixels, ``MISS`` where its layer covers no pixel; the owner layer of each query [N]). ``tracks`` must already
    fit the export's frames (``Tracks.cut``)."""
    numbers = track_frame_numbers(manifest, tracks.num_frames)
    scale = to_plate_scale(tracks, manifest.resolution)
    qt = np.rint(tracks.query_txy[:, 0]).astype(np.int64)
    qxy = tracks.query_txy[:, 1:3].astype(np.float64) * scale
    owner, target = query_owners(manifest, numbers, qt, qxy)
    out = np.zeros((len(qt), tracks.num_frames, 2), np.float64)
    for t, number in enumerate(numbers):
        passes = manifest.read_passes(number)
        for layer in np.unique(owner).tolist():
            sel = np.nonzero(owner == layer)[0]
            uv = texel_uv(passes[layer], tuple(manifest.layers[layer]["atlas_size"]))
            out[sel, t] = nearest_positions(uv, passes[layer].z >= OWNED_COVERAGE, target[sel])
    at_query = qt < tracks.num_frames
    out[np.nonzero(at_query)[0], qt[at_query]] = qxy[at_query]
    return out / scale, owner


def score_export(manifest_path: str | Path, tracks: Tracks) -> dict:
    """``paint_tracks`` scored: ``track_report`` plus the queries each layer owns and the scored positions that
    missed because their layer covered no pixel in that frame."""
    manifest = Manifest(manifest_path)
    tracks = tracks.cut(len(manifest.clip["frame_numbers"]))
    pred, owner = paint_tracks(manifest, tracks)
    report = track_report(pred, tracks)
    scored = scored_positions(tracks.occluded, np.rint(tracks.query_txy[:, 0]).astype(np.int64))
    report["misses"] = int((scored & ~np.isfinite(pred).all(-1)).sum())
    report["owners"] = {
        layer["name"]: int((owner == i).sum()) for i, layer in enumerate(manifest.layers) if (owner == i).any()
    }
    report["manifest"] = str(manifest.path)
    return report


__all__ = [
    "MAX_STEP_PX",
    "MISS",
    "OWNED_COVERAGE",
    "UV_JACOBIAN_MIN_DET",
    "nearest_positions",
    "paint_tracks",
    "query_owners",
    "score_export",
    "track_frame_numbers",
]
