"""Synthetic clips of the motions real clips show and a sliding sprite does not, with ground truth.

Six scenes, each one kind of foreground motion over a textured plate under a mild camera pan (so optical flow has
texture everywhere to lock on to):

    turning     a textured cylinder spinning about its vertical axis while it drifts: texture on one side turns
                away and new texture comes round the other (the object's visible side changes)
    deforming   a textured body under a smooth non-rigid warp (a wave running down it, a lean, squash and
                stretch): no similarity explains its motion
    small_fast  a small object (about 2% of the frame) on a curving path, 12 px or more per frame, spinning
    thin        a propeller-like cross of 3 px wide bars, turning while it drifts
    turning_depth  an elongated textured body turning 180 degrees about its vertical axis under a pinhole camera:
                from side-on through end-on to its other side, near parts larger, its two sides unlike each other
    limbs_jump  a torso with two limbs swinging across it in opposite phase (one in front of it, one behind)
                while the body jumps: parts hide each other and come back (``bench.motion_bodies``)

Every scene is a forward model with an exact inverse: ``surface(t, x, y)`` gives the surface coordinate (the
object's texture coordinate, in texture pixels) and the anti-aliased coverage at any frame point, and
``position(t, uv)`` where a surface point is in frame ``t`` and whether the camera sees it. Frames are rendered
by sampling the analytic textures (``engine.data.synthetic``'s plate and sprite, a periodic one for the cylinder)
at the exact surface coordinate of every pixel, so a surface point has the same colour in every frame that shows
it. The ground truth is the surface-coordinate field (``gt_uv.npz``: NaN where the object is not visible), the
texture itself (``texture.png``, one texel per surface unit: re-sampled through the field it gives the object's
pixels) and TAP-Vid tracks of points spread over the object's parts (``tracks_tapvid.npz``), solved from the forward
model, so ``python -m bench clips`` scores atlas tracking on them against chained optical flow with no other
code. ``masks/`` holds the exact visible object, ``masks_rough/`` the rough roto the ``clips`` bench makes of it by
default (``bench.degrade``), for fitting a clip by hand as the bench does.

Conventions: a scene's own functions use points with pixel ``[y, x]`` at ``(x, y)`` (as ``engine.data.synthetic``);
tracks, ``colour_at`` and ``uv_at`` use the tracks' convention, pixel ``i``'s centre at ``i + 0.5``.

Here: the rendered scene and its clip folder. What decides a scene is ``bench.motion_spec``'s
``MotionSpec``; each kind's build (sizes, speeds, texture, description) is ``bench.motion_builders``; the
first four forward models are ``bench.motion_models``; the ground-truth tracks ``bench.motion_tracks``.
"""

from __future__ import annotations

import os
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from bench.bench_clip import TRACKS_FILE
from bench.degrade import write_degraded
from bench.motion_bodies import BACK_LIMB, FRONT_LIMB, TORSO, LimbsJump
from bench.motion_builders import BUILDERS, DESCRIPTIONS
from bench.motion_models import _Model
from bench.motion_spec import DEFAULT_FRAMES, DEFAULT_SIZE, KINDS, MotionSpec
from bench.motion_tracks import ground_truth_tracks, query_frames
from bench.tracking import Tracks, save_tracks
from engine.data.synthetic import _Background, _textures, write_pngs
from engine.io.images import cv2_write

GT_UV_NPZ = "gt_uv.npz"
TEXTURE_PNG = "texture.png"
#: The rough roto written beside the exact masks: the ``clips`` bench's default recipe, with its default seed.
ROUGH_MASKS = "masks_rough"
ROUGH_RECIPE = "dilated10_dropped10"
#: Per-layer masks of a scene whose object is better fitted as several layers (``masks_parts/NAME/``): the parts a
#: compositor would roto apart. On ``limbs_jump``, the limb that swings across the body, and the rest.
PART_MASKS = "masks_parts"
LIMBS_PARTS: dict[str, tuple[int, ...]] = {"body": (TORSO, BACK_LIMB), "front_limb": (FRONT_LIMB,)}
#: Zip members get this timestamp, so a rewritten clip's .npz files are byte-identical.
ZIP_DATE = (1980, 1, 1, 0, 0, 0)
#: Bytes of a zip member copied at a time when it is re-dated.
REPACK_BLOCK = 1 << 24
_FRAME_NAME = re.compile(r"^\d{5}\.png$")


@dataclass
class MotionScene:
    """A rendered motion scene and its ground truth."""

    spec: MotionSpec
    frames: np.ndarray  # float32 [T, H, W, 3] in [0, 1]
    masks: np.ndarray  # bool [T, H, W]: the object's coverage > 0.5 (the visible object)
    uv: np.ndarray  # float32 [T, H, W, 2]: the surface coordinate at each pixel centre, NaN off the object
    tracks: Tracks  # TAP-Vid tracks of points on the object, native pixels, centres at i + 0.5
    model: _Model
    background: _Background
    texture: np.ndarray  # float32 [Ht, Wt, 3]: texel [j, i] is the surface's colour at uv (i, j)

    @property
    def name(self) -> str:
        return self.spec.kind

    @property
    def description(self) -> str:
        return DESCRIPTIONS[self.spec.kind]

    def colour_at(self, t: int, xy: np.ndarray) -> np.ndarray:
        """The rendered colour of frame ``t`` at points ``xy`` [..., 2] (centres at i + 0.5), computed exactly as
        the frames are (the frames hold it at the pixel centres)."""
        p = np.asarray(xy, np.float64) - 0.5
        pan = np.asarray(self.spec.pan) * t
        plate = self.background(p[..., 0] + pan[0], p[..., 1] + pan[1])
        return _composite(self.model, t, p[..., 0], p[..., 1], plate)[0]

    def uv_at(self, t: int, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The exact surface coordinate [..., 2] and coverage [...] at points ``xy`` [..., 2] of frame ``t``."""
        p = np.asarray(xy, np.float64) - 0.5
        return self.model.surface(t, p[..., 0], p[..., 1])


def _composite(
    model: _Model, t: int, x: np.ndarray, y: np.ndarray, plate: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The object over ``plate`` [..., 3] at frame points ``x``, ``y``: colour, surface coordinate, coverage."""
    if isinstance(model, LimbsJump):  # parts over parts: each blends with its own coverage
        return model.composite(t, x, y, plate)
    uv, cov = model.surface(t, x, y)
    img = plate.copy()
    inside = cov > 0.0
    if inside.any():
        c = cov[inside][:, None]
        img[inside] = c * model.color(uv[inside]) + (1.0 - c) * plate[inside]
    return img, uv, cov


def _pixel_grid(spec: MotionSpec) -> tuple[np.ndarray, ...]:
    """Every pixel's (x, y) of a frame, and the columns and rows alone (the background's separable grid)."""
    ys, xs = np.mgrid[0 : spec.height, 0 : spec.width].astype(np.float64)
    return xs, ys, np.arange(spec.width, dtype=np.float64), np.arange(spec.height, dtype=np.float64)


def _render_frame(
    spec: MotionSpec, model: _Model, background: _Background, t: int, grid: tuple[np.ndarray, ...]
) -> tuple[np.ndarray, ...]:
    """Frame ``t``: its colours (float32), the mask, the surface coordinate (float32, NaN off the mask), the
    coverage (float32) and the part each pixel shows (int8, -1 off the mask)."""
    xs, ys, xv, yv = grid
    plate = background.grid(xv + spec.pan[0] * t, yv + spec.pan[1] * t)  # = background(xs + ..., ys + ...)
    frame, uv, cov = _composite(model, t, xs, ys, plate)
    mask = cov > 0.5
    uv_field = np.full((*mask.shape, 2), np.nan, np.float32)
    uv_field[mask] = uv[mask]
    part = model.visible_part(t, xs, ys) if isinstance(model, LimbsJump) else np.where(mask, 0, -1)
    return frame.astype(np.float32), mask, uv_field, cov.astype(np.float32), part.astype(np.int8)


def _render(spec: MotionSpec, model: _Model, background: _Background) -> tuple[np.ndarray, ...]:
    """Frames, masks, the surface-coordinate field (NaN off the mask), the coverage and the part each pixel shows
    (-1 off the mask) of every frame."""
    t_n, h, w = spec.frames, spec.height, spec.width
    grid = _pixel_grid(spec)
    frames = np.empty((t_n, h, w, 3), np.float32)
    masks = np.empty((t_n, h, w), bool)
    uv_field = np.empty((t_n, h, w, 2), np.float32)
    cov_field = np.empty((t_n, h, w), np.float32)
    part_field = np.empty((t_n, h, w), np.int8)
    for t in range(t_n):
        frames[t], masks[t], uv_field[t], cov_field[t], part_field[t] = _render_frame(spec, model, background, t, grid)
    return frames, masks, uv_field, cov_field, part_field


def texture_image(model: _Model) -> np.ndarray:
    """The object's texture, float32 [Ht, Wt, 3]: texel [j, i] is the colour of surface coordinate (i, j)."""
    tw, th = model.texture_size
    u, v = np.meshgrid(np.arange(tw, dtype=np.float64), np.arange(th, dtype=np.float64))
    return np.clip(model.color(np.stack((u, v), -1)), 0.0, 1.0).astype(np.float32)


def make_motion_scene(spec: MotionSpec | str, **kw: Any) -> MotionScene:
    """Render one motion scene: a ``MotionSpec``, or a kind name and ``MotionSpec`` fields (width=..., ...)."""
    spec = MotionSpec(spec, **kw) if isinstance(spec, str) else spec
    model, plate = BUILDERS[spec.kind](spec)
    background = _textures(plate)[0]
    frames, masks, uv, cov, part = _render(spec, model, background)
    tracks = ground_truth_tracks(spec, model, cov, part)
    return MotionScene(spec, frames, masks, uv, tracks, model, background, texture_image(model))


# --- files -------------------------------------------------------------------------------------------------


def _repack_fixed_date(path: Path) -> None:
    """Rewrite the zip (.npz) at ``path`` with every member dated ZIP_DATE: numpy stamps the time of writing,
    which would make two writes of the same clip differ. Copied a block at a time, so a member larger than memory
    (a long 4K clip's surface-coordinate field) is never held whole."""
    tmp = path.with_name(f".{path.name}.tmp")
    with zipfile.ZipFile(path) as z, zipfile.ZipFile(tmp, "w") as dest:
        for member in z.infolist():
            info = zipfile.ZipInfo(member.filename, date_time=ZIP_DATE)
            info.compress_type = member.compress_type
            info.external_attr = 0o644 << 16
            info.file_size = member.file_size  # as writestr sets it: the same zip64 choice
            with z.open(member) as src, dest.open(info, "w") as out:
                while block := src.read(REPACK_BLOCK):
                    out.write(block)
    os.replace(tmp, path)


def part_masks(scene: MotionScene) -> dict[str, np.ndarray]:
    """The object's masks split into the parts ``PART_MASKS`` holds (bool [T, H, W] per part name: the pixels of the
    object whose true surface coordinate is on the part); empty for a scene of one part."""
    return _part_masks(scene.model, scene.uv, scene.masks)


def _part_masks(model: _Model, uv: np.ndarray, masks: np.ndarray) -> dict[str, np.ndarray]:
    """``part_masks`` of a surface-coordinate field and its masks: every frame's, or one frame's."""
    if not isinstance(model, LimbsJump):
        return {}
    part = np.full(masks.shape, -1, np.int64)
    known = np.isfinite(uv).all(-1)
    part[known] = model.part_of(uv[known])
    return {name: np.isin(part, ids) & masks for name, ids in LIMBS_PARTS.items()}


def _clip_folders(out: Path, parts: list[str]) -> tuple[Path, Path, Path, dict[str, Path]]:
    """The clip folder's frame, mask, rough-mask and part-mask folders, made and emptied of an earlier clip's
    frames (a longer one's would otherwise be read as part of this one)."""
    frames_dir, masks_dir, rough_dir = out / "frames", out / "masks", out / ROUGH_MASKS
    part_dirs = {name: out / PART_MASKS / name for name in parts}
    for d in (frames_dir, masks_dir, rough_dir, *part_dirs.values()):
        d.mkdir(parents=True, exist_ok=True)
        for old in d.iterdir():
            if _FRAME_NAME.match(old.name):
                old.unlink()
    return frames_dir, masks_dir, rough_dir, part_dirs


def _finish_clip(out: Path, masks_dir: Path, rough_dir: Path, model: _Model, tracks: Tracks, uv: np.ndarray,
                 kind: str) -> None:  # fmt: skip
    """What follows the frames: the rough roto, the texture, the tracks and the surface-coordinate field."""
    write_degraded(masks_dir, rough_dir, ROUGH_RECIPE)
    texture8 = np.clip(np.rint(texture_image(model) * 255.0), 0, 255).astype(np.uint8)
    cv2_write(out / TEXTURE_PNG, cv2.cvtColor(texture8, cv2.COLOR_RGB2BGR))
    save_tracks(out / TRACKS_FILE, tracks)
    np.savez_compressed(out / GT_UV_NPZ, uv=uv, kind=np.asarray(kind))
    for name in (TRACKS_FILE, GT_UV_NPZ):
        _repack_fixed_date(out / name)


def write_motion_clip(scene: MotionScene, folder: str | Path) -> Path:
    """Write ``scene`` as a clip folder the ``clips`` bench reads: ``frames/00000.png ...`` (8-bit sRGB),
    ``masks/00000.png ...`` (0/255), ``masks_rough/`` (the same masks degraded by ROUGH_RECIPE), a scene of several
    parts ``masks_parts/PART/`` (``part_masks``), ``texture.png``
    (8-bit, the object's texture), ``tracks_tapvid.npz`` and ``gt_uv.npz`` (``uv`` float32 [T, H, W, 2], NaN off
    the object; ``kind``). Frame files of an earlier, longer clip there are removed; the same scene gives the
    same bytes. Returns the folder."""
    out = Path(folder)
    parts = part_masks(scene)
    frames_dir, masks_dir, rough_dir, part_dirs = _clip_folders(out, list(parts))
    write_pngs(scene.frames, frames_dir, {masks_dir: scene.masks, **{part_dirs[n]: m for n, m in parts.items()}})
    _finish_clip(out, masks_dir, rough_dir, scene.model, scene.tracks, scene.uv, scene.spec.kind)
    return out


def write_motion_spec(spec: MotionSpec, folder: str | Path) -> Path:
    """The clip folder ``write_motion_clip`` writes of ``make_motion_scene(spec)``, byte for byte, rendered and
    written one frame at a time: memory holds one frame, the coverage of the tracks' query frames and the
    surface-coordinate field in a file beside the clip (removed once it is in ``gt_uv.npz``), so a 300-frame 1080p
    or a 4K plate is written on a machine whose memory holds a few frames. Returns the folder."""
    out = Path(folder)
    model, plate = BUILDERS[spec.kind](spec)
    background = _textures(plate)[0]
    parts = list(LIMBS_PARTS) if isinstance(model, LimbsJump) else []
    frames_dir, masks_dir, rough_dir, part_dirs = _clip_folders(out, parts)
    keep = set(query_frames(spec))
    cov: dict[int, np.ndarray] = {}
    part: dict[int, np.ndarray] = {}
    field_path = out / f".{GT_UV_NPZ}.field"
    uv = np.lib.format.open_memmap(field_path, "w+", np.float32, (spec.frames, spec.height, spec.width, 2))
    try:
        grid = _pixel_grid(spec)
        for t in range(spec.frames):
            frame, mask, uv[t], cov_t, part_t = _render_frame(spec, model, background, t, grid)
            if t in keep:
                cov[t], part[t] = cov_t, part_t
            masks_t = {masks_dir: mask[None]}
            masks_t |= {part_dirs[n]: m[None] for n, m in _part_masks(model, uv[t], mask).items()}
            write_pngs(frame[None], frames_dir, masks_t, first=t)
        uv.flush()
        tracks = ground_truth_tracks(spec, model, cov, part)
        _finish_clip(out, masks_dir, rough_dir, model, tracks, uv, spec.kind)
    finally:
        del uv
        field_path.unlink(missing_ok=True)
    return out


def write_motion_clips(
    root: str | Path,
    width: int = DEFAULT_SIZE[0],
    height: int = DEFAULT_SIZE[1],
    frames: int = DEFAULT_FRAMES,
    seed: int = 0,
    kinds: tuple[str, ...] = KINDS,
) -> list[Path]:
    """Every motion scene of ``kinds`` as a clip folder ``root/KIND``, a frame at a time (``write_motion_spec``);
    returns the folders."""
    return [write_motion_spec(MotionSpec(kind, width, height, frames, seed), Path(root) / kind) for kind in kinds]


__all__ = [
    "GT_UV_NPZ",
    "PART_MASKS",
    "ROUGH_MASKS",
    "TEXTURE_PNG",
    "MotionScene",
    "make_motion_scene",
    "part_masks",
    "texture_image",
    "write_motion_clip",
    "write_motion_clips",
    "write_motion_spec",
]
