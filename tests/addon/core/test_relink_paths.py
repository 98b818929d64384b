"""The path maths of a moved shot (no bpy): paths relative to the .blend, the old and new roots of a moved run
folder, which links move, which are missing, and the one line Relink reports."""

from __future__ import annotations

import os

import pytest
from neural_atlas.addon.core import relink as R


def test_paths_are_relative_to_the_blend_where_they_can_be():
    assert R.relative_path("/shots/a/run/edits/Fg.png", "/shots/a/scene.blend") == "//run/edits/Fg.png"
    assert R.relative_path("/plates/p.1001.exr", "/shots/a/scene.blend") == "//../../plates/p.1001.exr"
    assert R.relative_path("/shots/a/x.png", "") == "/shots/a/x.png"  # an unsaved .blend: absolute
    assert R.relative_path("//already.png", "/shots/a/scene.blend") == "//already.png"
    assert R.absolute_path("//run/edits/Fg.png", "/copy/scene.blend") == os.path.normpath("/copy/run/edits/Fg.png")
    assert R.absolute_path("/abs/x.png", "/copy/scene.blend") == "/abs/x.png"


def test_the_roots_are_the_manifest_paths_without_their_common_ending():
    old, new = "/a/shot/run/exports/v001/manifest.json", "/b/run/exports/v001/manifest.json"
    assert R.roots(old, new) == ("/a/shot", "/b")
    assert R.roots("/a/run/exports/v001/manifest.json", "/a/run2/exports/v001/manifest.json") == ("/a/run", "/a/run2")
    assert R.roots("/a/m/manifest.json", "/b/n/manifest.json") == ("/a/m", "/b/n")
    assert R.rebase("/a/shot/run/edits/Fg.png", "/a/shot", "/b") == "/b/run/edits/Fg.png"
    assert R.rebase("/a/shot", "/a/shot", "/b") == "/b"
    assert R.rebase("/a/shots/x.png", "/a/shot", "/b") is None  # a sibling folder with the same start is not under


def test_plan_moves_what_is_found_keeps_what_stayed_and_names_what_is_missing():
    old, new = "/a/shot/run/exports/v001/manifest.json", "/b/run/exports/v001/manifest.json"
    on_disk = {new, "/b/run/edits/Fg.png", "/a/shot/plate/p.0001.png"}
    links = [
        R.Link("Manifest", "prop", old),
        R.Link("NA_Edit_Fg", "image", "/a/shot/run/edits/Fg.png"),
        R.Link("NA_Plate", "clip", "/a/shot/plate/p.0001.png"),  # not moved: still where it was
        R.Link("NA_Atlas_Fg", "image", "/a/shot/run/exports/v001/atlases/Fg.png"),  # gone from both
        R.Link("Run Folder", "prop", "/a/shot/neural_atlas", required=False),  # never made: not reported
    ]
    plan = R.plan_relink(links, old, new, on_disk.__contains__)
    assert plan.moves == {"Manifest": new, "NA_Edit_Fg": "/b/run/edits/Fg.png"}
    assert plan.missing == ["NA_Atlas_Fg"]
    assert R.message(plan) == "relinked 2 path(s) from /a/shot to /b; still missing: NA_Atlas_Fg"
    assert R.missing(links, on_disk.__contains__) == ["Manifest", "NA_Edit_Fg", "NA_Atlas_Fg"]


def test_find_manifest_takes_a_manifest_an_export_or_a_run_folders_newest_export(tmp_path):
    run = tmp_path / "run"
    for v in ("v001", "v002", "v010"):
        (run / "exports" / v).mkdir(parents=True)
        (run / "exports" / v / "manifest.json").write_text("{}")
    (run / "exports" / "notes").mkdir()
    newest = str(run / "exports" / "v010" / "manifest.json")
    assert R.find_manifest(str(run)) == newest  # v010 after v002 (by number, not by name)
    assert R.find_manifest(str(run / "exports" / "v002")) == str(run / "exports" / "v002" / "manifest.json")
    assert R.find_manifest(newest) == newest
    with pytest.raises(ValueError, match=r"no manifest\.json there"):
        R.find_manifest(str(tmp_path / "elsewhere"))
