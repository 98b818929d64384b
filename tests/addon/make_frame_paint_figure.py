"""Make docs/images/addon_frame_paint.png: paint laid on one plate frame, landed on the atlases, on every frame.

A synthetic clip fitted through the add-on (headless, as ``make_figure.py``), then Paint on Frame at frame N, a stroke
written into ``NA_FramePaint`` over the object (painting operators cannot run headless: the stroke is its pixels),
Land Paint on Atlases (``engine project-frame``) and Render Edited Clip. Left to right: plate frame N with the stroke
laid over it, the render at frame N, the render at two other frames (the paint moved with the object).

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

from engine.data.synthetic import SceneSpec, make_scene, write_scene  # noqa: E402

#: The frame painted on, and the other frames shown.
N, OTHERS = 5, (0, 11)
#: The stroke's colour (sRGB, opaque) and how it is laid: a band through the object, and a dot on it.
COLOUR = (1.0, 0.85, 0.1, 1.0)


def main(out_png: Path) -> None:
    addon.register()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    work = Path(tempfile.mkdtemp(prefix="na_frame_paint_"))
    write_scene(make_scene(SceneSpec(width=192, height=108, frames=12)), work / "clip")
    os.environ["NEURAL_ATLAS_ENGINE_PYTHON"] = os.environ.get("NEURAL_ATLAS_ENGINE_PYTHON", sys.executable)
    props = bpy.context.scene.neural_atlas
    props.clip = bpy.data.movieclips.load(str(work / "clip" / "frames" / "00000.png"))
    layer = props.layers.add()
    layer.source = "FOLDER"
    layer.folder = str(work / "clip" / "masks")
    props.preset = "draft"
    props.run_dir = str(work / "run")
    t0 = time.monotonic()
    assert bpy.ops.neural_atlas.fit("EXEC_DEFAULT") == {"FINISHED"}, props.status
    t_fit = time.monotonic() - t0
    props.filter_type = "nearest"

    bpy.context.scene.frame_set(N)
    assert bpy.ops.neural_atlas.frame_paint_start("EXEC_DEFAULT") == {"FINISHED"}
    img = bpy.data.images["NA_FramePaint"]
    read = blender_read_rgba8(bpy)
    mask = read(work / "clip" / "masks" / f"{N:05d}.png")[..., 0] > 127
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

    plate = read(work / "clip" / "frames" / f"{N:05d}.png")
    laid = plate.copy()
    laid[stroke] = np.round(np.array(COLOUR) * 255).astype(np.uint8)
    tiles = [laid] + [read(work / "render" / f"edit.{f:05d}.png") for f in (N, *OTHERS)]
    gap = np.full((h, 4, 4), 255, np.uint8)
    row = np.concatenate([x for t in tiles for x in (t, gap)][:-1], axis=1)
    row[..., 3] = 255
    write_png(out_png, row)
    print(f"wrote {out_png}: fit {t_fit:.0f} s, land {t_land:.1f} s ({props.manifest})")
    addon.unregister()


def _stroke(mask: np.ndarray) -> np.ndarray:
    """A band across the object's middle and a dot above it, both inside its mask (rows top-first)."""
    ys, xs = np.nonzero(mask)
    cy, cx = int(ys.mean()), int(xs.mean())
    yy, xx = np.mgrid[0 : mask.shape[0], 0 : mask.shape[1]]
    band = np.abs(yy - cy) <= 2
    dot = np.hypot(yy - (cy - 8), xx - cx) <= 3.5
    return (band | dot) & mask


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "images" / "addon_frame_paint.png")
    sys.stdout.flush()
    os._exit(0)
