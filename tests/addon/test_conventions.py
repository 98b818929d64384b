"""Blender's conventions for the add-on's operators (bpy 4.5 and 5.0): an undo step where an operator changes the
scene and none where it only writes files or runs a process; a poll on every operator that needs something (the
button greyed, the line saying why, the same line for a script); the engine operators never repeated by Blender;
the Engine Settings field in the Fit Atlas panel."""

from __future__ import annotations

import os
import re
import shutil
from types import SimpleNamespace

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from helpers import RecordingLayout, as_operator  # noqa: E402
from neural_atlas.addon import ops, ui  # noqa: E402
from neural_atlas.addon.core import needs, running  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402
from neural_atlas.addon.ops import fit as fit_ops  # noqa: E402

#: Operators that change the scene: one undo step each.
UNDO = {
    "fit",
    "refine",
    "find_masks",
    "layer_add",
    "layer_remove",
    "scribble_layers",
    "import_run",
    "paint_setup",
    "paint_layer",
    "float_edits",
    "frame_paint_start",
    "relink",
    "live_preview",
}
#: Operators that write files, run or stop a process, or change the preferences: no undo step (the reason is a
#: comment beside each one's bl_options).
NO_UNDO = {
    "estimate",
    "cancel",
    "setup_engine",
    "cancel_setup",
    "copy_setup_command",
    "check_engine",
    "submit_farm",
    "save_edits",
    "render",
    "frame_paint_land",
    "render_cancel",
    "carry_paint",
}
#: The engine job operators (ops/driver.py): run modal from their buttons.
JOBS = ("fit", "refine", "find_masks", "estimate", "setup_engine", "submit_farm", "frame_paint_land", "carry_paint")


def _name(cls) -> str:
    return cls.bl_idname.removeprefix("neural_atlas.")


def test_every_operator_has_its_undo_decision(registered):
    assert {_name(cls) for cls in ops.classes} == UNDO | NO_UNDO  # a new operator must be decided here
    for cls in ops.classes:
        want = {"REGISTER", "UNDO"} if _name(cls) in UNDO else {"REGISTER"}
        assert cls.bl_options == want, cls.bl_idname


def test_engine_jobs_show_no_adjust_last_operation(registered):
    """A visible property would give the Adjust Last Operation panel, whose change undoes and runs ``execute``:
    the whole job again, blocking the UI. Every property of the job operators is hidden."""
    for name in JOBS:
        rna = getattr(bpy.ops.neural_atlas, name).get_rna_type()
        shown = [p.identifier for p in rna.properties if p.identifier != "rna_type" and not p.is_hidden]
        assert shown == [], name


def test_repeat_last_does_not_run_a_fit(blender, tmp_path, monkeypatch):
    """Repeat Last would run ``execute`` (blocking, for the whole fit): refused with one line, no job started."""
    monkeypatch.setenv("NEURAL_ATLAS_ENGINE_PYTHON", str(tmp_path / "never_started"))
    for flags in ((True, False), (False, True)):
        op = as_operator(
            fit_ops.NEURALATLAS_OT_fit,
            resume=False,
            options=SimpleNamespace(is_repeat=flags[0], is_repeat_last=flags[1]),
        )
        assert op.execute(blender.context) == {"CANCELLED"}
        assert op.reports == [({"WARNING"}, "Fit Atlas is not repeated: press its button (it runs with progress)")]
        assert running.jobs() == {} and not blender.context.scene.neural_atlas.running


def _refused(name: str, line: str) -> None:
    """Greyed out (poll False), and a script that calls it anyway gets the poll's line (Blender quotes 200
    characters of it)."""
    op = getattr(bpy.ops.neural_atlas, name)
    assert not op.poll(), name
    with pytest.raises(RuntimeError, match=re.escape(line[:200])):
        op("EXEC_DEFAULT")


def _paint(layer: str) -> None:
    """A stroke's pixels (painting operators cannot run headless)."""
    img = bpy.data.images[P.edit_image_name(layer)]
    px = np.zeros(img.size[0] * img.size[1] * 4, np.float32)
    img.pixels.foreach_get(px)
    px[:8] = (1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 1.0)
    img.pixels.foreach_set(px)
    img.update()


def test_polls_without_an_import(blender):
    for name in ("render", "save_edits", "float_edits", "paint_setup"):
        _refused(name, needs.NO_IMPORT)
    _refused("cancel", needs.NOTHING_RUNNING)
    _refused("cancel_setup", needs.SETUP_NOT_RUNNING)
    _refused("layer_remove", needs.NO_LAYER)
    _refused("scribble_layers", needs.NO_CLIP)
    assert bpy.ops.neural_atlas.layer_add.poll() and bpy.ops.neural_atlas.import_run.poll()


def test_polls_follow_the_import_the_paint_and_the_files(blender, tmp_path):
    manifest = X.make_export(tmp_path)
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    ops_ = bpy.ops.neural_atlas
    assert ops_.render.poll() and ops_.float_edits.poll() and ops_.paint_setup.poll()
    _refused("save_edits", needs.NOTHING_TO_SAVE)  # nothing painted yet
    _paint("Foreground")
    assert ops_.save_edits.poll()
    assert ops_.save_edits("EXEC_DEFAULT") == {"FINISHED"}
    _refused("save_edits", needs.NOTHING_TO_SAVE)  # saved

    # the passes gone from disk (a run folder cleaned): Render is greyed and names the missing file
    passes = bpy.path.abspath(bpy.data.images[P.PASSES_IMAGE].filepath)
    moved = tmp_path / "moved_passes"
    shutil.move(os.path.dirname(passes), moved)
    _refused("render", needs.PASSES_GONE + os.path.normpath(passes))
    shutil.move(moved, os.path.dirname(passes))
    assert ops_.render.poll()
    bpy.data.images.remove(bpy.data.images[P.PASSES_IMAGE])
    _refused("render", needs.NO_PASSES)

    assert ops_.float_edits("EXEC_DEFAULT") == {"FINISHED"}  # both layers become EXRs (and the passes come back)
    _refused("float_edits", needs.ALL_FLOAT)
    assert ops_.render.poll()
    os.remove(manifest)
    _refused("render", needs.MANIFEST_GONE + str(manifest))


def test_polls_of_layers_and_scribbles(blender, tmp_path):
    props = blender.context.scene.neural_atlas
    props.layers.add()
    assert bpy.ops.neural_atlas.layer_remove.poll()
    assert bpy.ops.neural_atlas.layer_remove("EXEC_DEFAULT") == {"FINISHED"} and len(props.layers) == 0
    _refused("layer_remove", needs.NO_LAYER)
    X.write_png(tmp_path / "clip" / "0001.png", np.zeros((8, 8, 4), np.uint8))
    props.clip = bpy.data.movieclips.load(str(tmp_path / "clip" / "0001.png"))
    assert bpy.ops.neural_atlas.scribble_layers.poll()


def test_import_is_one_undo_step(blender, tmp_path):
    """Ctrl+Z takes back an import (tree, canvases, the scene's manifest) in one step, Ctrl+Shift+Z brings it back;
    a Save Edits (no undo step) leaves the step alone."""
    manifest = X.make_export(tmp_path)
    bpy.ops.ed.undo_push(message="before")  # background mode starts without an undo history
    # an operator called from Python pushes its undo step only when asked (the UI always asks)
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", True, filepath=str(manifest)) == {"FINISHED"}
    props = blender.context.scene.neural_atlas
    assert props.manifest and "NA_Canvas_Foreground" in bpy.data.objects
    _paint("Foreground")
    assert blender.ops.neural_atlas.save_edits("EXEC_DEFAULT", True) == {"FINISHED"}
    assert bpy.ops.ed.undo() == {"FINISHED"}
    props = bpy.context.scene.neural_atlas
    assert props.manifest == "" and "NA_Canvas_Foreground" not in bpy.data.objects
    assert bpy.ops.ed.redo() == {"FINISHED"}
    props = bpy.context.scene.neural_atlas
    assert props.manifest == str(manifest) and "NA_Canvas_Foreground" in bpy.data.objects


def test_overrides_field_is_drawn_under_the_preset(blender):
    """The field the docs and the engine's messages name ("the panel's Engine Settings field")."""
    calls = RecordingLayout().draw(ui.NEURALATLAS_PT_fit, blender.context)
    drawn = [a[1] for name, a, _ in calls if name == "prop"]
    assert "overrides" in drawn and drawn.index("overrides") == drawn.index("preset") + 1
    assert blender.context.scene.neural_atlas.bl_rna.properties["overrides"].name == "Engine Settings"
