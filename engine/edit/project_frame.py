"""`project-frame`: paint on one frame, land it on the atlases (so `render` carries it to every frame).

Every pixel of the painted frame has, per layer, an atlas position (its UV pass) and an opacity (its
alpha pass). A pixel's paint goes to the layer(s) that own the pixel — alpha >= ``OWNER_ALPHA``, or the
largest alpha — so paint on the swan lands in the swan's atlas and not in the water behind it. The
owned pixels' premultiplied linear RGBA (unpainted pixels included, as zeros, so nothing bleeds between
strokes) are interpolated linearly over their Delaunay triangulation in atlas texels (scipy's
LinearNDInterpolator, the reference's choice), kept only within ``REACH_PX`` frame pixels of a sample,
and composited OVER the layer's existing edit layer. The previous edit layer is kept in
``edits/history/`` first: nothing the artist painted is lost.
"""

from __future__ import annotations

import datetime
import os
import posixpath
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .. import contract as C
from ..errors import DiskFullError, InputError
from ..export.manifest import LayerPasses, Manifest
from ..io.atomic import DISK_ERRORS, as_disk_full, atomic_write, move_into_place, signals_held
from ..io.clip import same_aspect
from ..io.colour import linear_to_srgb
from ..io.images import image_header, read_image, write_png, write_rgba_exr
from .equations import edit_to_premultiplied, load_edit
from .staged_folder import STAGING_SUFFIX

#: A layer owns a pixel when its alpha is at least this (or it is the largest of the pixel's alphas).
OWNER_ALPHA = 0.5
#: Texels farther than this many frame pixels from every owned sample stay unpainted (no hull bleeding).
REACH_PX = 1.5
#: Owned pixels within this many pixels of paint join the triangulation (they pin alpha to 0 around it).
CONTEXT_PX = 3
HISTORY_DIR = "history"

#: Told each stage as it starts: (stage, message, step, total); the CLI prints them as progress lines.
StageCallback = Callable[[str, str, int, int], None]
#: The stages of ``project_frame``, in order (``step`` of ``total`` on its progress lines).
STAGES = ("read", "project", "write")


def read_frame_edit(path: str | Path, size: tuple[int, int]) -> np.ndarray:
    """The painted frame as premultiplied linear RGBA at the plate's native ``size`` (W, H)."""
    pixels, is_float = read_image(path)
    if pixels.shape[2] not in (2, 4):
        raise InputError(
            path, "frame edit has no alpha channel", "save the paint as RGBA (transparent where unpainted)"
        )
    edit = edit_to_premultiplied(pixels, is_float)
    h, w = edit.shape[:2]
    if (w, h) != size:
        if not same_aspect((w, h), size):
            raise InputError(
                path, f"frame edit is {w}x{h} but the plate is {size[0]}x{size[1]}", "paint at the plate's size"
            )
        edit = cv2.resize(edit, size, interpolation=cv2.INTER_LINEAR)
    return edit


def owners(passes: list[LayerPasses]) -> np.ndarray:
    """bool [L, H, W]: which layers own each pixel."""
    a = np.stack([p.alpha for p in passes])
    return (a >= OWNER_ALPHA) | (a >= a.max(0, keepdims=True))


def splat_layer(
    frame_edit: np.ndarray, p: LayerPasses, owned: np.ndarray, tex_size: tuple[int, int]
) -> np.ndarray | None:
    """This layer's share of a frame edit as a premultiplied RGBA texture [H, W, 4] (None: nothing lands)."""
    from scipy.interpolate import LinearNDInterpolator

    painted = (frame_edit[..., 3] > 0.0) & owned & (p.z > 0.0)
    if not painted.any():
        return None
    k = 2 * CONTEXT_PX + 1
    near = cv2.dilate(painted.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)
    sel = near & owned & (p.z > 0.0)
    tw, th = tex_size
    # texel coordinates: x right, y down from the texture's top row (file order)
    x = p.uv[..., 0][sel] * tw - 0.5
    y = (1.0 - p.uv[..., 1][sel]) * th - 0.5
    vals = frame_edit[sel]
    pts = np.stack((x, y), -1).astype(np.float64)
    x0, x1 = int(max(0, np.floor(x.min()))), int(min(tw - 1, np.ceil(x.max())))
    y0, y1 = int(max(0, np.floor(y.min()))), int(min(th - 1, np.ceil(y.max())))
    if x1 < x0 or y1 < y0:
        return None
    gx, gy = np.meshgrid(np.arange(x0, x1 + 1), np.arange(y0, y1 + 1))
    # texels per frame pixel: how far apart neighbouring samples land in the texture
    spacing = _sample_spacing(p.uv, sel, tw, th)
    reach = max(1.0, REACH_PX * spacing)
    hit = np.zeros(gx.shape, np.uint8)
    xi = np.clip(np.rint(x).astype(int) - x0, 0, x1 - x0)
    yi = np.clip(np.rint(y).astype(int) - y0, 0, y1 - y0)
    hit[yi, xi] = 1
    dist = cv2.distanceTransform(1 - hit, cv2.DIST_L2, 5)
    keep = dist <= reach
    out = np.zeros((th, tw, 4), np.float32)
    if len(pts) >= 3 and np.linalg.matrix_rank(pts - pts.mean(0)) == 2:
        try:
            interp = LinearNDInterpolator(pts, vals, fill_value=np.nan)
            got = interp(gx[keep], gy[keep])
        except Exception:  # Qhull refuses degenerate (collinear) input: fall back to nearest samples
            got = np.full((int(keep.sum()), 4), np.nan)
    else:
        got = np.full((int(keep.sum()), 4), np.nan)
    # texels outside the triangulation but within reach (the rim): the nearest sample's value
    miss = ~np.isfinite(got).all(-1)
    if miss.any():
        from scipy.spatial import cKDTree

        _, nearest = cKDTree(pts).query(np.stack((gx[keep][miss], gy[keep][miss]), -1))
        got[miss] = vals[nearest]
    block = out[y0 : y1 + 1, x0 : x1 + 1]
    block[keep] = np.clip(got, 0.0, None).astype(np.float32)
    block[..., 3] = np.clip(block[..., 3], 0.0, 1.0)
    return out if out[..., 3].any() else None


def _sample_spacing(uv: np.ndarray, sel: np.ndarray, tw: int, th: int) -> float:
    """Median texel distance between horizontally adjacent selected pixels (>= 1 when the atlas is finer)."""
    both = sel[:, 1:] & sel[:, :-1]
    if not both.any():
        return 1.0
    du = (uv[:, 1:, 0] - uv[:, :-1, 0])[both] * tw
    dv = (uv[:, 1:, 1] - uv[:, :-1, 1])[both] * th
    return float(np.median(np.hypot(du, dv)))


def over(top: np.ndarray, bottom: np.ndarray) -> np.ndarray:
    """Premultiplied ``top`` over ``bottom``."""
    return top + bottom * (1.0 - top[..., 3:4])


def save_edit_like(path: Path, edit: np.ndarray, like: Path | None = None) -> None:
    """Write a premultiplied linear RGBA edit in the format of ``like`` (default: ``path`` itself): EXR as is, PNG
    as sRGB straight, at the bit depth the existing PNG has."""
    like = path if like is None else like
    if like.suffix.lower() == ".exr":
        write_rgba_exr(path, edit)
        return
    bits = 16 if like.exists() and image_header(like)[2] == 16 else 8
    a = edit[..., 3:4]
    with np.errstate(invalid="ignore", divide="ignore"):
        straight = np.where(a > 0.0, edit[..., :3] / np.maximum(a, 1e-12), 0.0)
    write_png(path, np.concatenate((np.clip(linear_to_srgb(straight), 0.0, 1.0), a), -1), bits)


def _stamp() -> str:
    return datetime.datetime.now().strftime("%Y%m%d-%H%M%S-%f")


def backup(path: Path, dest: Path | None = None) -> Path | None:
    """Copy an edit layer into ``dest`` (default: ``history/`` beside it, with a timestamp), atomically, before it
    is changed; None when there is nothing to keep."""
    if not path.exists():
        return None
    if dest is None:
        dest = path.parent / HISTORY_DIR / f"{path.stem}.{_stamp()}{path.suffix}"

    def copy(tmp: str) -> None:
        shutil.copyfile(path, tmp)

    return atomic_write(dest, copy)


def _history_path(manifest: Manifest, layer: dict, path: Path, stamp: str) -> Path:
    """Where the edit layer ``path`` is kept before it changes: ``history/`` beside it, checked like every path
    written through a manifest (a ``history`` linked out of the run folder is refused)."""
    folder = manifest.resolve_write(posixpath.join(posixpath.dirname(layer["edit_layer"]), HISTORY_DIR))
    return folder / f"{path.stem}.{stamp}{path.suffix}"


@dataclass
class _Change:
    """One edit layer about to change: its file, its new pixels, and (once staged) the new file and its backup."""

    layer: dict
    path: Path
    edit: np.ndarray
    staged: Path | None = None
    kept: Path | None = None


def project_frame(
    manifest_path: str | Path,
    frame: int,
    edit_path: str | Path,
    layers: list[str] | None = None,
    on_stage: StageCallback | None = None,
) -> dict[str, Path]:
    """Land the paint of ``edit_path`` (drawn on plate frame ``frame``) on the export's edit layers, holding the
    run folder's lock. Every changed layer is kept in ``history/`` first, and the new layers replace the old ones
    together once all are written: a failure, a full disk or a cancel leaves every edit layer as it was.
    ``on_stage`` is told each of ``STAGES`` as it starts (the CLI prints them: the add-on's progress bar)."""

    def stage(name: str, message: str) -> None:
        if on_stage is not None:
            on_stage(name, message, STAGES.index(name), len(STAGES))

    manifest = Manifest(manifest_path)
    manifest.check_layers(layers)
    manifest.check_frame(frame)
    stage("read", f"reading the paint and the passes of frame {frame}")
    frame_edit = read_frame_edit(edit_path, manifest.resolution)
    with C.run_lock(manifest.run_root, C.VERB_PROJECT_FRAME):
        passes = manifest.read_passes(frame)
        stage("project", "projecting the paint into the atlases of the layers that own it")
        splats = project_to_textures(manifest, passes, frame_edit, layers)
        changes = []
        for layer, splat in zip(manifest.layers, splats, strict=True):
            if splat is None:
                continue
            path = manifest.edit_file(layer)
            old = load_edit(path) if path.exists() else np.zeros_like(splat)
            if old.shape != splat.shape:
                splat = cv2.resize(splat, (old.shape[1], old.shape[0]), interpolation=cv2.INTER_LINEAR)
            changes.append(_Change(layer, path, over(splat, old)))
        stage("write", f"writing {len(changes)} edit layer(s), the previous ones kept in {HISTORY_DIR}/")
        _replace_edit_layers(manifest, changes)
    written = {c.layer["name"]: c.path for c in changes}
    for name, path in written.items():
        print(f"{name}: paint landed in {path}", file=sys.stderr)
    if not written:
        print(f"warning: {edit_path} has no paint on any layer of frame {frame}", file=sys.stderr)
    return written


def _replace_edit_layers(manifest: Manifest, changes: list[_Change]) -> None:
    """Back up every changed layer into ``history/`` and write its new pixels into a hidden staging folder of the
    run folder, then move them all into place (signals held). On any failure the staging goes, and so do the
    backups of the layers that were not replaced: the edit layers and their history are as they were."""
    stamp = _stamp()
    prefix = f".{C.VERB_PROJECT_FRAME}{STAGING_SUFFIX}"
    for leftover in manifest.run_root.glob(f"{prefix}*"):  # under the lock: a killed project-frame's staging
        shutil.rmtree(leftover, ignore_errors=True)
    staging = manifest.run_root / f"{prefix}{os.getpid()}"
    replaced: set[int] = set()
    try:
        staging.mkdir()
        for i, c in enumerate(changes):
            c.kept = backup(c.path, _history_path(manifest, c.layer, c.path, stamp))
            c.staged = staging / f"{i}{c.path.suffix}"
            save_edit_like(c.staged, c.edit, like=c.path)
        with signals_held():
            for i, c in enumerate(changes):
                move_into_place(staging / f"{i}{c.path.suffix}", c.path)
                replaced.add(i)
    except BaseException as exc:
        for i, c in enumerate(changes):
            if c.kept is not None and i not in replaced:
                c.kept.unlink(missing_ok=True)
        shutil.rmtree(staging, ignore_errors=True)
        full = _disk_full_for(changes, exc) if isinstance(exc, DISK_ERRORS) else None
        if full is not None:
            raise full from None
        raise
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _disk_full_for(changes: list[_Change], exc: BaseException) -> DiskFullError | None:
    """The disk-full line with what the change needs: a history copy of each layer and its new file (about the
    size of the old one; a new layer's uncompressed size). None when ``exc`` is not a full disk."""
    need = 0
    for c in changes:
        old = c.path.stat().st_size if c.path.exists() else 0
        need += old + max(old, c.edit.shape[0] * c.edit.shape[1] * c.edit.shape[2])
    return as_disk_full(exc, changes[0].path.parent, need)


def project_to_textures(
    manifest: Manifest, passes: list[LayerPasses], frame_edit: np.ndarray, layers: list[str] | None = None
) -> list[np.ndarray | None]:
    """Each layer's splatted texture at its edit layer's size (None where nothing lands)."""
    own = owners(passes)
    out: list[np.ndarray | None] = []
    for i, layer in enumerate(manifest.layers):
        if layers is not None and layer["name"] not in layers:
            out.append(None)
            continue
        path = manifest.edit_file(layer)
        size = image_header(path)[:2] if path.exists() else tuple(layer["atlas_size"])
        out.append(splat_layer(frame_edit, passes[i], own[i], size))
    return out


__all__ = [
    "STAGES",
    "StageCallback",
    "over",
    "owners",
    "project_frame",
    "project_to_textures",
    "read_frame_edit",
    "splat_layer",
]
