"""Make docs/images/addon_before_after.png: a synthetic clip fitted through the add-on (headless, the same
path as the end-to-end test), a checkerboard painted on the foreground atlas and a band on the background
atlas, rendered. Top row: plate frames; bottom row: the edited clip.

    .venv/bin/python tests/addon/make_figure.py [OUT_PNG]
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path[:0] = [str(ROOT), str(HERE)]

import bpy  # noqa: E402
import conftest  # noqa: E402,F401  (imports the checkout as the package neural_atlas)
import numpy as np  # noqa: E402
from fake_export import blender_read_rgba8, write_png  # noqa: E402
from helpers import fit_panel  # noqa: E402
from neural_atlas import addon  # noqa: E402

from engine.data.synthetic import SceneSpec, make_scene, write_scene  # noqa: E402


def fit_synthetic_clip(prefix: str) -> Path:
    """The add-on registered in a fresh scene, a 192x108, 12-frame synthetic clip written into a new temporary
    folder (returned) and fitted through Fit Atlas (draft preset, its masks as a folder layer), then imported."""
    addon.register()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    work = Path(tempfile.mkdtemp(prefix=prefix))
    write_scene(make_scene(SceneSpec(width=192, height=108, frames=12)), work / "clip")
    os.environ["NEURAL_ATLAS_ENGINE_PYTHON"] = os.environ.get("NEURAL_ATLAS_ENGINE_PYTHON", sys.executable)
    props = fit_panel(bpy, work / "clip" / "frames" / "00000.png", work / "clip" / "masks", work / "run")
    assert bpy.ops.neural_atlas.fit("EXEC_DEFAULT") == {"FINISHED"}, props.status
    return work


def main(out_png: Path) -> None:
    work = fit_synthetic_clip("na_figure_")
    for name, painter in (("NA_Edit_Foreground", _checker), ("NA_Edit_Background", _band)):
        img = bpy.data.images[name]
        w, h = img.size
        img.pixels.foreach_set(painter(w, h).ravel())
        img.update()
    bpy.ops.neural_atlas.save_edits("EXEC_DEFAULT")
    bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(work / "render"), file_format="png")
    read = blender_read_rgba8(bpy)
    frames = [0, 5, 11]
    top = [read(work / "clip" / "frames" / f"{f:05d}.png") for f in frames]
    bottom = [read(work / "render" / f"edit.{f:05d}.png") for f in frames]
    gap = np.full((108, 4, 4), 255, np.uint8)
    rows = [np.concatenate([row[0], gap, row[1], gap, row[2]], axis=1) for row in (top, bottom)]
    grid = np.concatenate([rows[0], np.full((4, rows[0].shape[1], 4), 255, np.uint8), rows[1]], axis=0)
    grid[..., 3] = 255
    write_png(out_png, grid)
    print(f"wrote {out_png} ({bpy.context.scene.neural_atlas.manifest})")
    addon.unregister()


def _checker(w: int, h: int) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w]
    on = ((x // max(1, w // 16)) + (y // max(1, h // 16))) % 2 == 0
    px = np.zeros((h, w, 4), np.float32)
    px[on] = (1.0, 0.85, 0.1, 1.0)
    px[~on] = (0.1, 0.2, 0.9, 1.0)
    return px


def _band(w: int, h: int) -> np.ndarray:
    px = np.zeros((h, w, 4), np.float32)
    px[int(0.45 * h) : int(0.55 * h)] = (1.0, 0.1, 0.4, 0.8)
    return px


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "images" / "addon_before_after.png")
    sys.stdout.flush()
    os._exit(0)
