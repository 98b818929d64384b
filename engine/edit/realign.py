"""`realign`: carry the edit layers painted against one export of a run onto a later export's mapping.

A refined fit (``fit --refine``) maps the clip onto its atlases a little differently, so paint painted in the old
atlas would drift on the object. Every frame both exports share tells where each new atlas texel was in the old
atlas: at a pixel the layer owns in both (``project_frame.owners``: alpha >= 0.5, or the largest alpha) the new UV
and the old UV are the same point of the object. Those pairs, averaged per new texel over the frames, give the
inverse map new texel -> old UV, interpolated linearly over their Delaunay triangulation (scipy's
LinearNDInterpolator, as ``project_frame`` does) and kept within ``REACH_PX`` frame pixels of a pair. The old edit
(premultiplied linear) is sampled there (``equations.sample_texture``, bilinear) into the new edit layer. Texels no
frame shows in both exports keep their paint where it was (the map is taken as the identity there), so no paint is
ever dropped.

Each changed edit layer is kept in ``edits/history/`` first and written in the format it has (PNG sRGB straight, or
float EXR); the layers change together or not at all (``project_frame``'s replacement), holding the run folder's
lock, and ``edits/aligned.json`` then records the export the paint matches: running it again does nothing.

``placement_error`` measures what it achieves: the paint rendered through the old passes against the paint
rendered through the new ones, per frame (premultiplied linear colour over the painted pixels, and the IoU of the
painted areas).
"""

from __future__ import annotations

import contextlib
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .. import contract as C
from ..errors import InputError
from ..export.manifest import Manifest
from .aligned import aligned_export, carried_sources, published_exports, write_aligned
from .equations import composite_touched, load_edit, sample_texture
from .project_frame import REACH_PX, _Change, _replace_edit_layers, _sample_spacing, owners

#: A pixel counts as painted when the paint covers at least this much of it (for the IoU of painted areas).
PAINTED_COVER = 0.5
#: Pairs are kept for interpolation within this many texels of the old paint (beyond it the map is not needed).
PAINT_MARGIN_TEXELS = 4


@dataclass
class _Pairs:
    """Per new texel (row-major, rows from the top) the sums of the new texel positions and old UVs that land there."""

    new_xy: np.ndarray  # float64 [N, 2]: summed texel coordinates in the new mapping
    old_uv: np.ndarray  # float64 [N, 2]: summed old UVs
    count: np.ndarray  # int64 [N]
    spacing: list[float]  # texels per frame pixel, per frame

    def mean(self) -> tuple[np.ndarray, np.ndarray]:
        """(new texel position, old UV) of every texel some pair landed on, averaged over its pairs."""
        hit = self.count > 0
        n = self.count[hit][:, None].astype(np.float64)
        return self.new_xy[hit] / n, self.old_uv[hit] / n

    def reach(self) -> float:
        """How far (texels) from a pair the map is interpolated: ``REACH_PX`` frame pixels at the pairs' spacing."""
        return max(1.0, REACH_PX * (float(np.median(self.spacing)) if self.spacing else 1.0))


def _empty_pairs(n: int) -> _Pairs:
    return _Pairs(np.zeros((n, 2)), np.zeros((n, 2)), np.zeros(n, np.int64), [])


def _add_pairs(a: _Pairs, new_uv: np.ndarray, old_uv: np.ndarray, sel: np.ndarray, size: tuple[int, int]) -> None:
    """Bin the pixels ``sel`` (the new layer's UV ``new_uv`` and the old layer's ``old_uv``, [H, W, 2]) into ``a`` by
    the new texture's texel (``size``: w, h), with the frame's texel spacing."""
    tw, th = size
    x = new_uv[..., 0][sel].astype(np.float64) * tw - 0.5
    y = (1.0 - new_uv[..., 1][sel].astype(np.float64)) * th - 0.5
    ix = np.clip(np.rint(x).astype(np.int64), 0, tw - 1)
    iy = np.clip(np.rint(y).astype(np.int64), 0, th - 1)
    key = iy * tw + ix
    n = tw * th
    a.new_xy[:, 0] += np.bincount(key, x, n)
    a.new_xy[:, 1] += np.bincount(key, y, n)
    a.old_uv[:, 0] += np.bincount(key, old_uv[..., 0][sel].astype(np.float64), n)
    a.old_uv[:, 1] += np.bincount(key, old_uv[..., 1][sel].astype(np.float64), n)
    a.count += np.bincount(key, minlength=n)
    a.spacing.append(_sample_spacing(new_uv, sel, tw, th))


def _interpolated_near(
    pos: np.ndarray, values: np.ndarray, reach: float, size: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``values`` known at the texel positions ``pos`` [N, 2], interpolated linearly over their Delaunay triangulation
    at every texel of a texture of ``size`` (w, h) within ``reach`` texels of one (the nearest one's value where the
    triangulation does not cover it): (rows, columns, values there)."""
    from scipy.interpolate import LinearNDInterpolator
    from scipy.spatial import cKDTree

    tw, th = size
    marks = np.zeros((th, tw), np.uint8)
    marks[np.clip(np.rint(pos[:, 1]).astype(int), 0, th - 1), np.clip(np.rint(pos[:, 0]).astype(int), 0, tw - 1)] = 1
    dist = cv2.distanceTransform(1 - marks, cv2.DIST_L2, 5)
    gy, gx = np.nonzero(dist <= reach)
    targets = np.stack((gx, gy), -1).astype(np.float64)
    got = np.full((len(targets), 2), np.nan)
    if len(pos) >= 3 and np.linalg.matrix_rank(pos - pos.mean(0)) == 2:
        # Qhull refuses degenerate (collinear) input: then the nearest pair's value below
        with contextlib.suppress(Exception):
            got = LinearNDInterpolator(pos, values, fill_value=np.nan)(targets)
    miss = ~np.isfinite(got).all(-1)
    if miss.any():
        _, nearest = cKDTree(pos).query(targets[miss])
        got[miss] = values[nearest]
    return gy, gx, got


def _gather(old: Manifest, new: Manifest, frames: list[int], sizes: dict[int, tuple[int, int]]) -> dict[int, _Pairs]:
    """Per layer index (those in ``sizes``: the edit layer's texture size), the (new texel, old UV) pairs of every
    pixel the layer owns in both exports, binned by new texel."""
    acc = {i: _empty_pairs(w * h) for i, (w, h) in sizes.items()}
    for frame in frames:
        p_old, p_new = old.read_passes(frame), new.read_passes(frame)
        own_old, own_new = owners(p_old), owners(p_new)
        for i, size in sizes.items():
            sel = own_old[i] & own_new[i] & (p_old[i].z > 0.0) & (p_new[i].z > 0.0)
            if sel.any():
                _add_pairs(acc[i], p_new[i].uv, p_old[i].uv, sel, size)
    return acc


def realign_texture(edit: np.ndarray, pairs: _Pairs) -> tuple[np.ndarray, int]:
    """The edit layer ``edit`` (premultiplied linear [H, W, 4], painted against the old mapping) moved onto the new
    one, and how many texels were re-sampled. Texels beyond every pair's reach keep their value (identity map)."""
    th, tw = edit.shape[:2]
    painted = (edit[..., 3] > 0.0).astype(np.uint8)
    if not painted.any() or not (pairs.count > 0).any():
        return edit.copy(), 0
    pos, old_uv = pairs.mean()  # texel coordinates (x right, y down; centres at integers)
    old_xy = np.stack((old_uv[:, 0] * tw - 0.5, (1.0 - old_uv[:, 1]) * th - 0.5), -1)
    reach = pairs.reach()
    k = 2 * int(np.ceil(reach + PAINT_MARGIN_TEXELS)) + 1
    near_paint = cv2.dilate(painted, np.ones((k, k), np.uint8)).astype(bool)

    def on_paint(xy: np.ndarray) -> np.ndarray:
        xi = np.clip(np.rint(xy[:, 0]).astype(np.int64), 0, tw - 1)
        yi = np.clip(np.rint(xy[:, 1]).astype(np.int64), 0, th - 1)
        return near_paint[yi, xi]

    keep_pairs = on_paint(pos) | on_paint(old_xy)  # pairs that bring paint somewhere, or take it away
    if not keep_pairs.any():
        return edit.copy(), 0
    pos, old_xy = pos[keep_pairs], old_xy[keep_pairs]
    shift = old_xy - pos  # texels: where the new texel's point of the object was in the old atlas
    gy, gx, got = _interpolated_near(pos, shift, reach, (tw, th))  # the texels within reach of a pair
    src = np.stack((gx, gy), -1).astype(np.float64) + got  # old texel coordinates
    uv = np.stack(((src[:, 0] + 0.5) / tw, 1.0 - (src[:, 1] + 0.5) / th), -1)
    out = edit.copy()
    out[gy, gx] = sample_texture(edit, uv, "bilinear")
    out[..., 3] = np.clip(out[..., 3], 0.0, 1.0)
    return out, len(gy)


def common_frames(old: Manifest, new: Manifest, step: int = 1) -> list[int]:
    """The plate frames both exports have passes of, every ``step``-th (the last one always)."""
    both = sorted(set(old.frames) & set(new.frames))
    if not both:
        raise InputError(new.path, f"shares no frame with {old.path}", "realign two exports of the same run's frames")
    picked = both[:: max(1, step)]
    return picked if picked[-1] == both[-1] else [*picked, both[-1]]


def resolve_exports(target: str | Path, source: str | Path | None) -> tuple[Manifest, Manifest]:
    """(old, new) manifests: ``target`` is the new export's manifest (or its folder, or the run folder: its newest
    export); ``source`` the old one as a manifest, an export folder or a version name (``v001``); default the export
    ``edits/aligned.json`` records, else the export before the new one (none: ``new`` itself, nothing to carry)."""
    target = Path(target)
    if (target / C.EXPORTS_DIR).is_dir() and not (target / C.MANIFEST_NAME).exists():
        versions = published_exports(target)
        if not versions:
            raise InputError(target, "has no export", f"export the run first: python -m {C.CLI_MODULE} export RUN_DIR")
        target = target / C.EXPORTS_DIR / versions[-1]
    new = Manifest(target)
    run = new.run_root
    if source is None:
        source = aligned_export(run)
        if source is None:
            earlier = [v for v in published_exports(run) if v < new.folder.name]
            if not earlier:
                return new, new  # the run's first export: the paint was made on it (nothing to carry)
            source = earlier[-1]
    src = Path(source)
    if not src.exists() and src.name == str(source):  # a version name
        src = run / C.EXPORTS_DIR / str(source)
        if not (src / C.MANIFEST_NAME).is_file():
            raise InputError(
                src,
                "is not an export of this run (the paint's export is needed to carry it over)",
                "pass --from with the export the edit layers were painted on",
            )
    return Manifest(src), new  # an export of another run: its paint is carried (``carry``)


def _other_fit(old: Manifest, new: Manifest) -> bool:
    """Whether ``old`` is an export of another fit (run folder) than ``new``: then its paint is carried (``carry``)."""
    return old.run_root.resolve() != new.run_root.resolve()


def realign(
    target: str | Path,
    source: str | Path | None = None,
    layers: list[str] | None = None,
    frame_step: int = 1,
) -> tuple[Manifest, dict[str, Path]]:
    """Move the edit layers painted against export ``source`` onto export ``target``'s mapping (see the module).
    Returns the new manifest and the edit layers changed (name -> file). Already aligned to ``target``: nothing."""
    old, new = resolve_exports(target, source)
    new.check_layers(layers)
    if _other_fit(old, new):
        return new, _carry(old, new, layers, frame_step)
    if old.folder.resolve() == new.folder.resolve() or aligned_export(new.run_root) == new.folder.name:
        print(f"edit layers already match {new.folder.name}: nothing to realign", file=sys.stderr)
        return new, {}
    old_names = {layer["name"]: k for k, layer in enumerate(old.layers)}
    changes: list[_Change] = []
    with C.run_lock(new.run_root, C.VERB_REALIGN):
        sizes: dict[int, tuple[int, int]] = {}
        edits: dict[int, np.ndarray] = {}
        for i, layer in enumerate(new.layers):
            if (layers is not None and layer["name"] not in layers) or old_names.get(layer["name"]) != i:
                continue  # a layer the old export does not have at this place: its paint is new
            path = new.edit_file(layer)
            if not path.exists():
                continue
            edit = load_edit(path)
            if edit[..., 3].any():
                sizes[i], edits[i] = (edit.shape[1], edit.shape[0]), edit
        pairs = _gather(old, new, common_frames(old, new, frame_step), sizes) if sizes else {}
        for i, edit in edits.items():
            moved, count = realign_texture(edit, pairs[i])
            if count:
                changes.append(_Change(new.layers[i], new.edit_file(new.layers[i]), moved))
            else:
                name = new.layers[i]["name"]
                print(f"{name}: no painted texel is seen in both exports; its paint stays as it is", file=sys.stderr)
        _replace_edit_layers(new, changes)
        write_aligned(new.run_root, new.folder.name)
    written = {c.layer["name"]: c.path for c in changes}
    for name, path in written.items():
        print(f"{name}: paint carried from {old.folder.name} to {new.folder.name} in {path}", file=sys.stderr)
    return new, written


def _carry(old: Manifest, new: Manifest, layers: list[str] | None, frame_step: int) -> dict[str, Path]:
    """The paint of ``old`` (an export of another fit of the same plate) laid onto ``new``'s edit layers
    (``carry.carry_edits``); the edit layers changed (name -> file)."""
    from .carry import carry_edits, check_same_plate

    check_same_plate(old, new)
    frames = common_frames(old, new, frame_step)
    source = str(old.path.resolve())
    with C.run_lock(new.run_root, C.VERB_REALIGN):
        earlier = carried_sources(new.run_root, new.folder.name)
        if source in earlier:
            print(f"{new.folder.name} already holds the paint of {old.path}: nothing to carry", file=sys.stderr)
            return {}
        targets = [new.edit_file(layer) for layer in new.layers]
        lacking = next((p for p in targets if not p.exists()), None)
        if lacking is not None:
            raise InputError(lacking, "edit layer does not exist", "export the new fit again, then carry the paint")
        changed = carry_edits(old, new, frames, load_edits(old), [load_edit(p) for p in targets])
        changes = [
            _Change(new.layers[j], targets[j], edit)
            for j, edit in sorted(changed.items())
            if layers is None or new.layers[j]["name"] in layers
        ]
        _replace_edit_layers(new, changes)
        write_aligned(new.run_root, new.folder.name, [*earlier, source])
    written = {c.layer["name"]: c.path for c in changes}
    for name, path in written.items():
        print(f"{name}: paint carried from {old.path} in {path}", file=sys.stderr)
    if not written:
        print(f"no painted texel of {old.path} is seen where {new.path} shows the plate", file=sys.stderr)
    return written


def realign_measured(
    target: str | Path, source: str | Path | None = None, layers: list[str] | None = None, frame_step: int = 1
) -> tuple[Manifest, dict[str, Any]]:
    """``realign``, and the paint's placement error against the old export (``placement_error``) with the
    re-aligned edit layers (``realigned``) and with the edit layers as they were (``not_realigned``)."""
    old, new = resolve_exports(target, source)
    before = load_edits(new)
    painted = load_edits(old) if _other_fit(old, new) else before  # the paint as it was painted
    manifest, written = realign(new.path, old.path, layers, frame_step)
    after = load_edits(new)
    return manifest, {
        "from": old.folder.name if not _other_fit(old, new) else str(old.path),
        "to": new.folder.name,
        "layers": sorted(written),
        "realigned": placement_error(old, new, painted, after),
        "not_realigned": placement_error(old, new, painted, before),
    }


# --- measuring it -----------------------------------------------------------------------------------------------


def paint_render(manifest: Manifest, frame: int, edits: list[np.ndarray | None]) -> tuple[np.ndarray, np.ndarray]:
    """The paint alone at ``frame`` through ``manifest``'s passes: premultiplied linear RGB [H, W, 3] and its
    coverage [H, W] (the edit equations over a black plate)."""
    passes = manifest.read_passes(frame)
    w, h = manifest.resolution
    rgb, _ = composite_touched(np.zeros((h, w, 3), np.float32), passes, edits)
    cover = np.zeros((h, w), np.float32)
    for p, edit in zip(passes, edits, strict=True):
        if edit is not None:
            cover += sample_texture(edit, p.uv)[..., 3] * p.z
    return rgb, cover


def placement_error(
    old: Manifest, new: Manifest, old_edits: list[np.ndarray | None], new_edits: list[np.ndarray | None], step: int = 1
) -> dict[str, Any]:
    """How far the paint ``new_edits`` rendered through ``new`` lands from ``old_edits`` through ``old`` over the
    frames both share: mean and max absolute colour difference (premultiplied linear, the channels' max) over the
    pixels painted in either, the IoU of the painted areas (cover >= ``PAINTED_COVER``), and ``landed``: the share
    of the old paint's pixels that the new paint covers."""
    total = inter = union = painted_old = 0
    err_sum, err_max = 0.0, 0.0
    frames = common_frames(old, new, step)
    for frame in frames:
        rgb_old, cov_old = paint_render(old, frame, old_edits)
        rgb_new, cov_new = paint_render(new, frame, new_edits)
        a, b = cov_old >= PAINTED_COVER, cov_new >= PAINTED_COVER
        inter += int((a & b).sum())
        union += int((a | b).sum())
        painted_old += int(a.sum())
        region = (cov_old > 0.0) | (cov_new > 0.0)
        if region.any():
            diff = np.abs(np.concatenate((rgb_old, cov_old[..., None]), -1) -
                          np.concatenate((rgb_new, cov_new[..., None]), -1))[region].max(-1)  # fmt: skip
            err_sum += float(diff.sum())
            err_max = max(err_max, float(diff.max()))
            total += int(region.sum())
    return {
        "frames": len(frames),
        "painted_pixels": total,
        "mean_error": err_sum / max(total, 1),
        "max_error": err_max,
        "iou": inter / union if union else 1.0,
        "landed": inter / painted_old if painted_old else 1.0,
    }


def load_edits(manifest: Manifest, files: dict[str, Path] | None = None) -> list[np.ndarray | None]:
    """Every layer's edit layer of ``manifest`` (``files``: other files for some layers, e.g. history copies)."""
    out: list[np.ndarray | None] = []
    for layer in manifest.layers:
        path = (files or {}).get(layer["name"], manifest.edit_file(layer))
        out.append(load_edit(path) if path.exists() else None)
    return out


__all__ = [
    "PAINTED_COVER",
    "common_frames",
    "load_edits",
    "paint_render",
    "placement_error",
    "realign",
    "realign_measured",
    "realign_texture",
    "resolve_exports",
]
