"""Make docs/images/addon_frame_paint.png: paint laid on one plate frame, landed on the atlases, on every frame.

A synthetic clip (a textured object moving over a panning background) exported with its exact motion as the passes
(``tests/engine/fake_export.py``: what a perfect fit would export, in seconds), imported through the add-on
(headless), then Paint on Frame at frame N, a stroke written into ``NA_FramePaint`` over the object (painting
operators cannot run headless: the stroke is its pixels), Land Paint on Atlases (``engine project-frame``) and Render
Edited Clip. Left to right: plate frame N with the stroke laid over it, the render at frame N, the render at two other
frames (the paint moved with the object).

    .venv/bin/python tests/addon/make_frame_paint_figure.py [OUT_PNG]
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path[:0] = [str(ROOT), str(HERE)]

import bpy  # noqa: E402
import conftest  # noqa: E402,F401  (imports the checkout as the package neural_atlas)
import numpy as np  # noqa: E402
from fake_export import blender_read_rgba8, write_png  # noqa: E402
from neural_atlas import addon  # noqa: E402

from engine.data.synthetic import SceneSpec, SyntheticScene, make_scene  # noqa: E402
from tests.engine.fake_export import make_fake_export  # noqa: E402

#: The frame painted on, and the other frames shown.
N, OTHERS = 5, (0, 11)
#: The stroke's colour (sRGB, opaque): a band through the object's middle.
COLOUR = (1.0, 0.95, 0.1, 1.0)
#: Each tile shown at this many screen pixels per plate pixel (nearest).
ZOOM = 2


def main(out_png: Path) -> None:
    addon.register()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    work = Path(tempfile.mkdtemp(prefix="na_frame_paint_"))
    scene = make_scene(SceneSpec(width=192, height=108, frames=12))
    manifest = _exact_export(scene, work)
    os.environ["NEURAL_ATLAS_ENGINE_PYTHON"] = os.environ.get("NEURAL_ATLAS_ENGINE_PYTHON", sys.executable)
    props = bpy.context.scene.neural_atlas
    props.filter_type = "nearest"
    assert bpy.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}

    bpy.context.scene.frame_set(N)
    assert bpy.ops.neural_atlas.frame_paint_start("EXEC_DEFAULT") == {"FINISHED"}
    img = bpy.data.images["NA_FramePaint"]
    read = blender_read_rgba8(bpy)
    mask = scene.masks[N]
    stroke = _stroke(mask)
    w, h = img.size
    px = np.zeros((h, w, 4), np.float32)
    px[stroke] = COLOUR
    img.pixels.foreach_set(px[::-1].ravel())  # rows bottom-up
    img.update()
    t0 = time.monotonic()
    assert bpy.ops.neural_atlas.frame_paint_land("EXEC_DEFAULT") == {"FINISHED"}, props.status
    t_land = time.monotonic() - t0
    bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(work / "render"), file_format="png")

    plate = read(work / "clip" / f"{N:05d}.png")
    laid = plate.copy()
    laid[stroke] = np.round(np.array(COLOUR) * 255).astype(np.uint8)
    tiles = [laid] + [read(work / "render" / f"edit.{f:05d}.png") for f in (N, *OTHERS)]
    tiles = [t.repeat(ZOOM, 0).repeat(ZOOM, 1) for t in tiles]
    gap = np.full((h * ZOOM, 6, 4), 255, np.uint8)
    row = np.concatenate([x for t in tiles for x in (t, gap)][:-1], axis=1)
    row[..., 3] = 255
    write_png(out_png, row)
    print(f"wrote {out_png}: land {t_land:.1f} s ({props.manifest})")
    addon.unregister()


def _exact_export(scene: SyntheticScene, work: Path) -> Path:
    """The clip's export with its exact motion: the background atlas covers every background point the pan shows,
    the object's atlas its sprite (2 texels per pixel); the object owns its mask."""
    spec = scene.spec
    lo = scene.bg_offset.min(0)
    span = scene.bg_offset.max(0) - lo + np.array([spec.width, spec.height])
    sw, sh = spec.fg_size

    def background(t: int, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ox, oy = scene.bg_offset[t] - lo
        return (xs + ox) / span[0], 1.0 - (ys + oy) / span[1], 1.0 - scene.masks[t].astype(np.float64)

    def sprite(t: int, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ox, oy = scene.fg_offset[t]
        return (xs - ox) / sw, 1.0 - (ys - oy) / sh, scene.masks[t].astype(np.float64)

    bg_size = (int(np.ceil(span[0])), int(np.ceil(span[1])))
    return make_fake_export(work, scene.frames, [(background, bg_size), (sprite, (2 * sw, 2 * sh))])


def _stroke(mask: np.ndarray) -> np.ndarray:
    """A band across the object's middle, inside its mask (rows top-first)."""
    ys, _ = np.nonzero(mask)
    cy = int(ys.mean())
    yy = np.mgrid[0 : mask.shape[0], 0 : mask.shape[1]][0]
    return (np.abs(yy - cy) <= 2) & mask


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "images" / "addon_frame_paint.png")
    sys.stdout.flush()
    os._exit(0)
