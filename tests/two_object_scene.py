"""Two textured objects crossing on a panning plate, with exact ground truth: the multi-layer (paper Sec. 4.3)
and scribble (Sec. 4.4) tests need two rigid parts whose screen regions overlap.

Built from the textures of ``engine.data.synthetic`` (the same plate and sprites as ``make_scene``), so each
object's texture point has the same colour in every frame that shows it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from engine import contract as C
from engine.data.synthetic import SceneSpec, _Background, _Sprite, _textures, paint_sprite, write_pngs

#: The second object's stripes (lime / violet), so the two objects differ in colour as well as in motion.
SECOND_STRIPES = ((0.55, 0.95, 0.10), (0.35, 0.10, 0.90))
#: The second object's textures are drawn with the scene's seed plus this (another sprite than the first's).
SECOND_SEED_OFFSET = 101


@dataclass(frozen=True)
class TwoObjectSpec:
    """Two textured ellipses on a panning plate whose paths cross: object A passes in front of object B,
    so each occludes (A) or is occluded (B) for a few frames."""

    width: int = 160
    height: int = 96
    frames: int = 12
    bg_velocity: tuple[float, float] = (1.5, 0.4)
    a_start: tuple[float, float] = (38.0, 22.0)  # object A's bounding box top-left at frame 0 (px)
    a_velocity: tuple[float, float] = (4.0, 0.5)
    a_size: tuple[int, int] = (40, 30)
    b_start: tuple[float, float] = (84.0, 42.0)
    b_velocity: tuple[float, float] = (-4.0, -0.3)
    b_size: tuple[int, int] = (36, 34)
    seed: int = 3


@dataclass
class TwoObjectScene:
    """A rendered two-object clip and its ground truth; object 0 is A (in front), object 1 is B."""

    frames: np.ndarray  # float32 [T, H, W, 3]
    masks: np.ndarray  # bool [2, T, H, W]: each object's VISIBLE pixels (as in ``make_scene``; A wins overlaps)
    coverage: np.ndarray  # bool [2, T, H, W]: each object's full silhouette, occluded or not
    offsets: np.ndarray  # float32 [2, T, 2]: object k's top-left; frame (x, y) shows its texture (x-ox, y-oy)
    bg_offset: np.ndarray  # float32 [T, 2]
    spec: TwoObjectSpec

    def object_color(self, k: int, tex_xy: Any) -> np.ndarray:
        """Exact colour of object ``k`` at its texture point(s) ``tex_xy`` ([..., 2]) -> [..., 3]."""
        p = np.asarray(tex_xy, dtype=np.float64)
        return _two_object_textures(self.spec)[1 + k].color(p[..., 0], p[..., 1])

    @property
    def union(self) -> np.ndarray:
        """bool [T, H, W]: pixels of either object (one mask for a two-part object)."""
        return self.masks.any(0)


@lru_cache(maxsize=4)
def _two_object_textures(spec: TwoObjectSpec) -> tuple[_Background, _Sprite, _Sprite]:
    common = dict(width=spec.width, height=spec.height, frames=spec.frames, bg_velocity=spec.bg_velocity)
    background, sprite_a = _textures(SceneSpec(**common, fg_size=spec.a_size, seed=spec.seed))
    _, b = _textures(SceneSpec(**common, fg_size=spec.b_size, seed=spec.seed + SECOND_SEED_OFFSET))
    sprite_b = _Sprite(b.size, b.stripe_freq, b.stripe_phase, b.spots, b.spot_rgb, SECOND_STRIPES)
    return background, sprite_a, sprite_b


def make_two_object_scene(spec: TwoObjectSpec | None = None) -> TwoObjectScene:
    """Render ``spec``: background, then B, then A over it (each anti-aliased like ``make_scene``)."""
    spec = TwoObjectSpec() if spec is None else spec
    background, sprite_a, sprite_b = _two_object_textures(spec)
    t_idx = np.arange(spec.frames, dtype=np.float64)[:, None]
    bg_offset = t_idx * np.asarray(spec.bg_velocity, dtype=np.float64)
    offsets = np.stack(
        [
            np.asarray(start, dtype=np.float64) + t_idx * np.asarray(vel, dtype=np.float64)
            for start, vel in ((spec.a_start, spec.a_velocity), (spec.b_start, spec.b_velocity))
        ]
    )
    ys, xs = np.mgrid[0 : spec.height, 0 : spec.width].astype(np.float64)
    xv, yv = np.arange(spec.width, dtype=np.float64), np.arange(spec.height, dtype=np.float64)
    frames = np.empty((spec.frames, spec.height, spec.width, 3), dtype=np.float32)
    cover = np.empty((2, spec.frames, spec.height, spec.width), dtype=bool)
    for t in range(spec.frames):
        img = background.grid(xv + bg_offset[t, 0], yv + bg_offset[t, 1])
        for k, sprite in ((1, sprite_b), (0, sprite_a)):  # back to front
            cov = paint_sprite(img, sprite, xs - offsets[k, t, 0], ys - offsets[k, t, 1])
            cover[k, t] = cov > C.MASK_THRESHOLD
        frames[t] = img
    visible = cover.copy()
    visible[1] &= ~cover[0]
    return TwoObjectScene(
        frames=frames,
        masks=visible,
        coverage=cover,
        offsets=offsets.astype(np.float32),
        bg_offset=bg_offset.astype(np.float32),
        spec=spec,
    )


def write_two_object_scene(scene: TwoObjectScene, folder: Path, union: bool = False) -> tuple[Path, list[Path]]:
    """Write ``frames/``, and ``masks_a/`` + ``masks_b/`` (or one ``masks/`` of both when ``union``), into a
    fresh folder. Returns (frames_dir, mask_dirs)."""
    folder = Path(folder)
    frames_dir = folder / "frames"
    if union:
        layers = {folder / "masks": scene.union}
    else:
        layers = {folder / "masks_a": scene.masks[0], folder / "masks_b": scene.masks[1]}
    for d in (frames_dir, *layers):
        d.mkdir(parents=True, exist_ok=True)
    write_pngs(scene.frames, frames_dir, layers)
    return frames_dir, list(layers)
