"""One plate per shot (bpy 4.5 and 5.0): the plate the scene's plate clip shows is the plate every operator reads
(Live Preview, Paint on Frame, Render) and the one Relink tells the export (``engine relink``), so ``engine render``
and the export's Nuke script read it too.

- A shot moved whole, then its run folder moved alone and relinked: the manifest names the shot's plate where it now
  is (neither its relative paths nor the paths as at export reached it).
- The plate moved alone: Relink choosing one of its frames points the plate clip there and tells the export.
- Two shot folders, the second's plate deleted after its run moved alone: the panel says the plate is gone in one
  line, and Live Preview, Paint on Frame and Render refuse, instead of reading the first shot's plate that the
  manifest recorded at export."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from helpers import engine_python  # noqa: E402
from neural_atlas.addon import preferences  # noqa: E402
from neural_atlas.addon.core import needs  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402
from test_day_reopen import FRAME, _preview, _relative_manifest  # noqa: E402
from test_relink import _panel, _refused  # noqa: E402

from engine import contract as C  # noqa: E402


@pytest.fixture
def engine(monkeypatch) -> str:
    """The checkout's engine as the add-on's engine Python (Relink runs ``engine relink`` with it)."""
    py = engine_python(C.VERB_RELINK, "numpy")
    monkeypatch.setenv(preferences.ENGINE_PYTHON_ENV, py)
    return py


def _saved_shot(blender, shot: Path) -> tuple[Path, np.ndarray]:
    """``shot/scene.blend`` with ``shot/run`` imported (the manifest's paths relative, as an export writes them):
    (the manifest, the preview at ``FRAME``)."""
    manifest = _relative_manifest(X.make_export(shot))
    assert blender.ops.wm.save_as_mainfile(filepath=str(shot / "scene.blend")) == {"FINISHED"}
    blender.context.scene.neural_atlas.filter_type = P.FILTER_NEAREST
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    assert blender.ops.wm.save_mainfile() == {"FINISHED"}
    return manifest, _preview(shot / "before.exr")


def _reads(manifest: Path) -> str:
    """The plate folder the manifest reads now (``contract.resolve_plate_path``)."""
    return os.path.dirname(C.resolve_plate_path(str(manifest), C.load_manifest(str(manifest))["clip"], 0))


def test_a_shot_moved_then_its_run_moved_alone_tells_the_export_where_the_plate_is(blender, engine, tmp_path):
    manifest, before = _saved_shot(blender, tmp_path / "shot")
    shot = tmp_path / "b" / "shot"
    shot.parent.mkdir()
    shutil.move(str(tmp_path / "shot"), str(shot))
    run = tmp_path / "c" / "run"
    run.parent.mkdir()
    shutil.move(str(shot / "run"), str(run))
    moved = run / manifest.relative_to(tmp_path / "shot" / "run")
    assert not os.path.isdir(_reads(moved))  # neither the relative nor the as-at-export paths reach the plate
    assert bpy.ops.wm.open_mainfile(filepath=str(shot / "scene.blend")) == {"FINISHED"}
    assert bpy.ops.neural_atlas.relink("EXEC_DEFAULT", filepath=str(run)) == {"FINISHED"}
    assert os.path.realpath(_reads(moved)) == os.path.realpath(shot / "plate")
    assert json.loads(moved.read_text())["clip"]["source_absolute"] == os.path.realpath(shot / "plate")
    err = float(np.abs(_preview(tmp_path / "after.exr") - before).max())
    print(f"[bpy {bpy.app.version_string}] shot moved, run moved alone, relinked: preview vs before {err:.1e}")
    assert err <= 1e-6


def test_relink_choosing_a_frame_of_the_moved_plate(blender, engine, tmp_path):
    manifest, before = _saved_shot(blender, tmp_path / "shot")
    plate = tmp_path / "plates" / "shot_plate"
    plate.parent.mkdir()
    shutil.move(str(tmp_path / "shot" / "plate"), str(plate))
    clip_file = os.path.basename(bpy.path.abspath(bpy.data.movieclips[P.PLATE_CLIP].filepath))
    gone = os.path.normpath(str(tmp_path / "shot" / "plate" / clip_file))
    assert needs.PLATE_GONE + gone in _panel()[0]
    _refused("render", needs.PLATE_GONE + gone)
    chosen = plate / f"{X.FRAMES[-1]:05d}.png"  # any frame of it: the clip keeps its own first frame's name
    assert bpy.ops.neural_atlas.relink("EXEC_DEFAULT", filepath=str(chosen)) == {"FINISHED"}
    shown = os.path.normpath(bpy.path.abspath(bpy.data.movieclips[P.PLATE_CLIP].filepath))
    assert shown == os.path.normpath(str(plate / clip_file))
    assert os.path.realpath(_reads(manifest)) == os.path.realpath(plate)
    assert not any(line.startswith(needs.PLATE_GONE) for line in _panel()[0])
    assert float(np.abs(_preview(tmp_path / "after.exr") - before).max()) <= 1e-6

    with pytest.raises(RuntimeError, match="has no plate frame"):  # a folder that is not this plate: nothing changes
        bpy.ops.neural_atlas.relink("EXEC_DEFAULT", filepath=str(tmp_path / "shot" / "scene.blend"))
    assert os.path.normpath(bpy.path.abspath(bpy.data.movieclips[P.PLATE_CLIP].filepath)) == shown


def test_two_shot_folders_each_keep_to_their_own_plate(blender, tmp_path):
    first = tmp_path / "first"
    manifest, _ = _saved_shot(blender, first)
    second = tmp_path / "second"
    shutil.copytree(first, second)
    assert bpy.ops.wm.open_mainfile(filepath=str(second / "scene.blend")) == {"FINISHED"}
    run = tmp_path / "runs" / "run"
    run.parent.mkdir()
    shutil.move(str(second / "run"), str(run))
    shutil.rmtree(second / "plate")
    assert bpy.ops.neural_atlas.relink("EXEC_DEFAULT", filepath=str(run)) == {"FINISHED"}
    moved = run / manifest.relative_to(first / "run")
    assert os.path.realpath(_reads(moved)) == os.path.realpath(first / "plate")  # what the manifest recorded
    clip_file = os.path.normpath(bpy.path.abspath(bpy.data.movieclips[P.PLATE_CLIP].filepath))
    assert clip_file.startswith(str(second))
    lines = [line for line in _panel()[0] if line.startswith(needs.PLATE_GONE)]
    assert lines == [needs.PLATE_GONE + clip_file]
    _refused("render", needs.PLATE_GONE + clip_file)
    bpy.context.scene.frame_set(FRAME)
    for name in ("live_preview", "frame_paint_start"):
        with pytest.raises(RuntimeError, match="plate frame does not exist"):
            getattr(bpy.ops.neural_atlas, name)("EXEC_DEFAULT")
