"""The day's refine step (bpy 4.5 and 5.0), with the real engine on a tiny synthetic clip: a shot folder
(``scene.blend``, ``run``, ``clip``; the run folder relative to the .blend) is fitted, imported, painted and saved;
the folder is copied whole elsewhere and Refine runs in the copy; the original is deleted and the copy moved again.
The refine writes its export into the copy's run, naming the copy's own plate; after the move, Render Edited Clip
equals ``engine render`` of that export, nothing is black, and the stroke is in the re-aligned edit layer, in
Blender and on disk.

Painting operators cannot run headless (docs/blender-compat.md#painting): the stroke is its pixels, written into the
edit image as a brush would. The engine runs in its own interpreter (``helpers.engine_python``); skipped when that
Python has no torch.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from helpers import engine_python, fit_panel, write_tiny_clip  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402
from test_day_reopen import _pixels  # noqa: E402
from test_refine import FAST, _stroke  # noqa: E402

from engine import contract as C  # noqa: E402
from engine.terms.cli import VERB_RENDER  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
TAG = f"[bpy {bpy.app.version_string}]"
#: Blender's render against ``engine render`` of the same export and paint (nearest filter: the same texels).
ENGINE_TOLERANCE = 1e-4


def _renders(out: Path) -> dict[int, np.ndarray]:
    return {int(p.name.split(".")[1]): X.read_exr_rgba(p) for p in sorted(out.glob("edit.*.exr"))}


def _compare(manifest: Path, out: Path) -> tuple[float, float]:
    """Render Edited Clip, then ``engine render`` of ``manifest``; (their largest RGB difference, darkest mean)."""
    assert bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out / "blender"), file_format="exr") == {
        "FINISHED"
    }, bpy.context.scene.neural_atlas.render_status
    py = engine_python(VERB_RENDER, "torch")
    args = [py, "-m", "engine", VERB_RENDER, str(manifest), "--out", str(out / "engine"), "--format", "exr",
            "--filter", P.FILTER_NEAREST, "--no-bar"]  # fmt: skip
    done = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    ours, theirs = _renders(out / "blender"), _renders(out / "engine")
    err = max(float(np.abs(ours[f][..., :3] - theirs[f][..., :3]).max()) for f in ours)
    return err, min(float(img[..., :3].mean()) for img in ours.values())


@pytest.mark.slow
def test_refine_in_a_copied_shot_folder_stays_in_the_copy(blender, tmp_path, monkeypatch):
    py = engine_python(C.VERB_REALIGN, "torch")
    shot = tmp_path / "shot"
    write_tiny_clip(py, shot / "clip")
    monkeypatch.setenv("NEURAL_ATLAS_ENGINE_PYTHON", py)
    assert bpy.ops.wm.save_as_mainfile(filepath=str(shot / "scene.blend")) == {"FINISHED"}
    props = fit_panel(bpy, shot / "clip" / "frames" / "00000.png", shot / "clip" / "masks", shot / "run",
                      overrides=FAST)  # fmt: skip
    props.run_dir = "//run"  # as the file browser gives it with Relative Path on (Blender's default)
    props.filter_type = P.FILTER_NEAREST
    assert bpy.ops.neural_atlas.fit("EXEC_DEFAULT") == {"FINISHED"}, props.status
    painted = _stroke(bpy.data.images[P.edit_image_name("Background")])
    assert bpy.ops.wm.save_mainfile() == {"FINISHED"}  # the paint is saved with the .blend

    copy = tmp_path / "elsewhere" / "shot"
    shutil.copytree(shot, copy)
    assert bpy.ops.wm.open_mainfile(filepath=str(copy / "scene.blend")) == {"FINISHED"}
    props = bpy.context.scene.neural_atlas
    props.refine_steps = 4
    monkeypatch.setenv("NEURAL_ATLAS_ENGINE_PYTHON", py)
    assert bpy.ops.neural_atlas.refine("EXEC_DEFAULT") == {"FINISHED"}, props.status
    refined = copy / "run" / C.EXPORTS_DIR / "v002" / C.MANIFEST_NAME
    assert Path(bpy.path.abspath(props.manifest)).resolve() == refined.resolve(), props.manifest
    assert not (shot / "run" / C.EXPORTS_DIR / "v002").exists()  # the original shot is untouched
    clip = json.loads(refined.read_text())["clip"]
    plate = Path(C.resolve_plate_path(str(refined), clip))  # the copy's own plate (a pattern: its folder)
    assert plate.parent == copy / "clip" / "frames" and Path(clip["source_absolute"]).parent == plate.parent

    # the .blend is not saved after Refine: opened again, it follows the export its paint was re-aligned to
    shutil.rmtree(shot)
    moved = tmp_path / "moved_again" / "shot"
    shutil.move(str(copy), str(moved))
    assert bpy.ops.wm.open_mainfile(filepath=str(moved / "scene.blend")) == {"FINISHED"}
    props = bpy.context.scene.neural_atlas
    assert props.status.startswith("the edit layers were re-aligned by a refine: imported "), props.status
    assert Path(bpy.path.abspath(props.manifest)).resolve() == (moved / refined.relative_to(copy)).resolve()
    passes = bpy.path.abspath(bpy.data.images[P.PASSES_IMAGE].filepath)
    assert Path(passes).resolve().is_relative_to((moved / "run" / C.EXPORTS_DIR / "v002").resolve()), passes
    err, darkest = _compare(moved / "run" / C.EXPORTS_DIR / "v002" / C.MANIFEST_NAME, tmp_path / "renders")
    edit = bpy.data.images[P.edit_image_name("Background")]
    on_disk = X.read_png_rgba8(Path(bpy.path.abspath(edit.filepath)))[::-1][..., 3] / 255.0
    alpha = _pixels(edit)[..., 3]
    kept = float((alpha >= 0.5)[painted].mean())
    print(f"{TAG} refined in a copy, moved again: render vs engine {err:.1e}, darkest {darkest:.3f}, stroke {kept:.3f}")
    assert Path(bpy.path.abspath(edit.filepath)).resolve().is_relative_to(moved.resolve())
    assert err <= ENGINE_TOLERANCE and darkest > 0.05
    assert np.allclose(alpha, on_disk, atol=1 / 255) and kept > 0.8
