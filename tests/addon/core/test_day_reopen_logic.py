"""The logic behind what survives a reopened, moved and relinked shot (no bpy): a plate found where the scene's plate
clip is after a relink, the frames a render takes from the export, the run folder and current frame an import sets,
and when the frame paint's "is there paint" answer may be reused."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
from fake_export import FRAMES, make_export
from neural_atlas.addon.core import frame_paint as FP
from neural_atlas.addon.core import frames as F
from neural_atlas.addon.core import render_job as RJ
from neural_atlas.addon.core import run_files
from neural_atlas.addon.core import tree_plan as P

from engine import contract as C


def _moved_without_plate(tmp_path: Path) -> tuple[Path, Path]:
    """An export whose manifest names its plate relative to itself (as ``engine export`` writes it), its run folder
    then moved on its own; (the moved manifest, the plate folder that stayed)."""
    manifest = make_export(tmp_path / "shot")
    data = json.loads(manifest.read_text())
    data["clip"]["frame_files"] = [os.path.relpath(p, manifest.parent) for p in data["clip"]["frame_files"]]
    for layer in data["layers"]:
        layer["edit_layer"] = os.path.relpath(layer["edit_layer"], manifest.parent)
    manifest.write_text(json.dumps(data))
    shutil.move(str(tmp_path / "shot" / "run"), str(tmp_path / "run"))
    return tmp_path / "run" / "exports" / "v001" / "manifest.json", tmp_path / "shot" / "plate"


def test_a_relinked_run_finds_its_plate_where_the_plate_clip_is(tmp_path):
    moved, plate = _moved_without_plate(tmp_path)
    m = C.load_manifest(str(moved))
    with pytest.raises(P.PlanError, match="plate frame does not exist"):
        P.plan_tree(m, str(moved))
    known = str(plate / f"{FRAMES[0]:05d}.png")
    plan = P.plan_tree(m, str(moved), known_plate=known)
    assert plan.plate.filepath == os.path.normpath(known)
    # a clip whose folder holds no file of that name is no help: the manifest's line stands
    with pytest.raises(P.PlanError, match="plate frame does not exist"):
        P.plan_tree(m, str(moved), known_plate=str(tmp_path / "elsewhere" / "00003.png"))


def test_the_scenes_plate_clip_is_the_plate_even_where_the_manifest_names_another(tmp_path):
    """One plate per shot: the manifest's plate is there (another shot folder's copy, say), but the scene's plate
    clip shows a plate elsewhere: the clip's is read; where the clip's folder lacks the frame, the plan says so
    rather than reading the manifest's."""
    manifest = make_export(tmp_path)
    other = tmp_path / "other"
    other.mkdir()
    (other / f"{FRAMES[0]:05d}.png").write_bytes(b"")
    plan = P.plan_tree(C.load_manifest(str(manifest)), str(manifest), known_plate=str(other / "x.png"))
    assert plan.plate.filepath == str(other / f"{FRAMES[0]:05d}.png")
    shutil.rmtree(other)
    with pytest.raises(P.PlanError, match=f"{other / f'{FRAMES[0]:05d}.png'}: plate frame does not exist"):
        P.plan_tree(C.load_manifest(str(manifest)), str(manifest), known_plate=str(other / "x.png"))


def test_a_render_takes_the_exported_frames_and_names_the_others():
    assert RJ.exported_only(RJ.frame_list(1, 8), (3, 5)) == ([3, 4, 5], [1, 2, 6, 7, 8])
    assert RJ.exported_only(RJ.frame_list(1, 9, 2), (3, 5)) == ([3, 5], [1, 7, 9])
    assert RJ.exported_only([3, 4], (3, 5)) == ([3, 4], [])
    assert RJ.spans([8, 1, 2, 6, 7]) == "1-2, 6-8" and RJ.spans([4]) == "4"
    assert RJ.outside_note([], (3, 5)) == ""
    note = RJ.outside_note([1, 2, 6], (3, 5))
    assert note == (
        "scene frame(s) 1-2, 6 not rendered: the export has passes for frames 3-5 only (export more frames to "
        "render them)"
    )
    p = RJ.RenderProgress(total=3, note=note)
    for _ in range(3):
        p.add(1.0)
    assert p.report("/out") == f"rendered 3 frame(s) to /out; {note}"
    assert RJ.no_exported_frames((10, 12), (3, 5)).startswith(
        "The scene's range 10-12 holds none of the exported frames 3-5: set the range inside them"
    )


def test_an_import_puts_the_current_frame_inside_the_imported_frames():
    assert F.frame_inside(1, 1001, 1004) == 1001
    assert F.frame_inside(1003, 1001, 1004) == 1003
    assert F.frame_inside(2000, 1001, 1004) == 1001


def test_the_run_folder_of_an_imported_manifest(tmp_path):
    manifest = make_export(tmp_path)
    assert run_files.imported_run_dir(str(manifest)) == os.path.realpath(tmp_path / "run")
    loose = tmp_path / "loose" / "manifest.json"
    loose.parent.mkdir()
    loose.write_text("{}")
    assert run_files.imported_run_dir(str(loose)) is None  # not a run folder's export: the Run Folder is left alone


@pytest.mark.parametrize(
    ("painted", "was_unsaved", "unsaved", "age", "holds"),
    [
        (True, False, True, 9.0, True),  # a brush only adds paint
        (False, False, False, 9.0, True),  # untouched since
        (False, False, True, 0.0, False),  # the first stroke since: read again at once
        (False, True, True, 0.1, True),  # strokes going on: reused a moment
        (False, True, True, 0.6, False),
        (False, True, False, 0.0, False),  # saved since
    ],
)
def test_a_no_paint_answer_is_dropped_by_the_first_stroke(painted, was_unsaved, unsaved, age, holds):
    assert FP.painted_answer_holds(painted, was_unsaved, unsaved, age, 0.5) is holds
