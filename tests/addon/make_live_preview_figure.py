"""Make docs/images/addon_live_preview.png: a synthetic clip fitted through the add-on (headless, as make_figure.py),
a checkerboard written into the foreground's edit image (not saved: painting operators cannot run headless, so the
stroke's pixels are written as a brush would leave them) and the live preview rendered with Cycles on the CPU at two
frames. Left to right: the plate at frame A, the preview at frame A, the preview at frame B (the same paint, scrubbed).

    .venv/bin/python tests/addon/make_live_preview_figure.py [OUT_PNG]
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path[:0] = [str(ROOT), str(HERE)]

import bpy  # noqa: E402
import conftest  # noqa: E402,F401  (imports the checkout as the package neural_atlas)
import numpy as np  # noqa: E402
from fake_export import blender_read_rgba8, read_exr_rgba, write_png  # noqa: E402
from make_figure import _checker, fit_synthetic_clip  # noqa: E402
from neural_atlas import addon  # noqa: E402
from neural_atlas.addon import preview_plane  # noqa: E402

FRAMES = (0, 11)


def _srgb8(linear: np.ndarray) -> np.ndarray:
    c = np.clip(linear, 0.0, 1.0)
    enc = np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)
    return np.round(enc * 255).astype(np.uint8)


def main(out_png: Path) -> None:
    work = fit_synthetic_clip("na_live_figure_")
    img = bpy.data.images["NA_Edit_Foreground"]
    w, h = img.size
    img.pixels.foreach_set(_checker(w, h).ravel())  # the stroke, unsaved
    img.update()
    scene = bpy.context.scene
    read = blender_read_rgba8(bpy)
    panels = [read(work / "clip" / "frames" / f"{FRAMES[0]:05d}.png")]
    for f in FRAMES:
        rgba = read_exr_rgba(Path(preview_plane.render_frame(scene, f, str(work / f"preview.{f}.exr"))))
        panels.append(np.concatenate([_srgb8(rgba[..., :3]), np.full((*rgba.shape[:2], 1), 255, np.uint8)], -1))
    gap = np.full((panels[0].shape[0], 4, 4), 255, np.uint8)
    row = np.concatenate([panels[0], gap, panels[1], gap, panels[2]], axis=1)
    row[..., 3] = 255
    write_png(out_png, row)
    print(f"wrote {out_png} ({bpy.context.scene.neural_atlas.manifest})")
    addon.unregister()


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "images" / "addon_live_preview.png")
    sys.stdout.flush()
    os._exit(0)
