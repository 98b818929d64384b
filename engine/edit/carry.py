"""``realign --from`` an export of ANOTHER fit of the same plate: the paint carried to a new fit.

A new fit (another preset, other masks, Find Parts on or off) has its own atlases, often other layers (one object
split into parts, or the parts fitted as one). At a pixel that old layer ``i`` owns in the old export and new layer
``j`` owns in the new one (``project_frame.owners``), the old UV of ``i`` and the new UV of ``j`` are the same point
of the plate: those pairs, binned by new texel and averaged over the frames both exports show, give the inverse map
new texel -> old UV of ``i``, interpolated linearly over their Delaunay triangulation within ``REACH_PX`` frame pixels
of a pair (as ``realign`` does within one run). Old edit ``i`` (premultiplied linear) is sampled there and laid over
new edit ``j`` (premultiplied over: paint already on the new fit stays under it), for every pair of layers that
share pixels. The new edit layers change together, their old files kept in ``edits/history/``
(``project_frame._replace_edit_layers``); ``edits/aligned.json`` then records the new export.

What it achieves is measured where it matters, on the plate: the paint rendered through the old export against the
paint rendered through the new one, frame by frame (``realign.placement_error``: the share of the old paint's
pixels the new paint covers, ``landed``, the IoU, the colour error).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..export.manifest import Manifest
from .equations import sample_texture
from .project_frame import over, owners
from .realign import _add_pairs, _empty_pairs, _interpolated_near, _Pairs


def check_same_plate(old: Manifest, new: Manifest) -> None:
    """Two exports whose paint can be carried: the same plate size; else one line (``realign.common_frames`` asks
    for frames in common)."""
    if tuple(old.resolution) != tuple(new.resolution):
        raise InputError(
            old.path,
            f"is an export of a {old.resolution[0]}x{old.resolution[1]} plate, not the "
            f"{new.resolution[0]}x{new.resolution[1]} plate of {new.path}",
            "carry paint between fits of the same plate",
        )


def gather_pairs(
    old: Manifest, new: Manifest, frames: list[int], painted: list[int], sizes: list[tuple[int, int]]
) -> dict[tuple[int, int], _Pairs]:
    """Per (old layer in ``painted``, new layer) that own pixels in common, their pairs binned by new texel
    (``realign._Pairs``); ``sizes``: each new layer's edit texture size (w, h)."""
    acc: dict[tuple[int, int], _Pairs] = {}
    for frame in frames:
        p_old, p_new = old.read_passes(frame), new.read_passes(frame)
        own_old, own_new = owners(p_old), owners(p_new)
        for i in painted:
            seen_old = own_old[i] & (p_old[i].z > 0.0)
            for j, (tw, th) in enumerate(sizes):
                sel = seen_old & own_new[j] & (p_new[j].z > 0.0)
                if sel.any():
                    pair = acc.setdefault((i, j), _empty_pairs(tw * th))
                    _add_pairs(pair, p_new[j].uv, p_old[i].uv, sel, (tw, th))
    return acc


def carried_paint(old_edit: np.ndarray, pairs: _Pairs, size: tuple[int, int]) -> np.ndarray | None:
    """Old edit layer ``old_edit`` (premultiplied linear [h, w, 4]) as it lands on a new layer's texture of ``size``
    (w, h) through ``pairs``: premultiplied RGBA, transparent where no pair reaches or the old paint is empty;
    None when nothing lands."""
    from scipy.spatial import cKDTree

    tw, th = size
    if not (pairs.count > 0).any():
        return None
    pos, old_uv = pairs.mean()
    # only the pairs whose old point is on (or next to) the old paint bring any: the rest are left out of the map
    painted = sample_texture(old_edit, old_uv.astype(np.float32), "bilinear")[..., 3] > 0.0
    if not painted.any():
        return None
    reach = pairs.reach()
    near = cKDTree(pos[painted]).query(pos, distance_upper_bound=2.0 * reach + 2.0)[0] < np.inf
    gy, gx, got = _interpolated_near(pos[near], old_uv[near], reach, size)
    out = np.zeros((th, tw, 4), np.float32)
    out[gy, gx] = sample_texture(old_edit, got.astype(np.float32), "bilinear")
    out[..., 3] = np.clip(out[..., 3], 0.0, 1.0)
    return out if out[..., 3].any() else None


def carry_edits(
    old: Manifest, new: Manifest, frames: list[int], old_edits: list[np.ndarray | None], new_edits: list[np.ndarray]
) -> dict[int, np.ndarray]:
    """Each new layer's edit (``new_edits``: as they are now, premultiplied linear) with the old paint laid over it
    (``old_edits``: None or unpainted layers carry nothing); only the layers that changed."""
    painted = [i for i, e in enumerate(old_edits) if e is not None and e[..., 3].any()]
    sizes = [(e.shape[1], e.shape[0]) for e in new_edits]
    pairs = gather_pairs(old, new, frames, painted, sizes) if painted else {}
    changed: dict[int, np.ndarray] = {}
    for (i, j), pair in sorted(pairs.items()):
        edit = old_edits[i]
        assert edit is not None
        landed = carried_paint(edit, pair, sizes[j])
        if landed is not None:
            changed[j] = over(landed, changed.get(j, new_edits[j]))
    return changed


__all__ = ["carried_paint", "carry_edits", "check_same_plate", "gather_pairs"]
