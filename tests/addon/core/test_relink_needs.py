"""The lines of a moved shot and of the clip operators (``core.needs``, no bpy): Render refuses a missing plate
(it would render black) and a missing atlas after the manifest, passes and edit layers; the panel's moved line; Relink
needs an import; Fit Atlas, Find Masks and Estimate Time need the panel's clip."""

from __future__ import annotations

from neural_atlas.addon.core import needs


def test_render_needs_the_plate_and_the_atlases_too():
    manifest, passes, edit, atlas, plate = "/r/m.json", "/r/p/00001.exr", "/r/e/F.png", "/r/a/F.png", "/p/1.png"
    on_disk = {manifest, passes, edit, atlas, plate}

    def need(exists=on_disk.__contains__, plate_file=plate):
        return needs.render_need(manifest, passes, exists, [edit], plate_file=plate_file, atlas_files=[atlas])

    assert need() is None
    assert need(plate_file=None) == needs.NO_PLATE
    assert need((on_disk - {plate}).__contains__) == needs.PLATE_GONE + plate
    assert need((on_disk - {atlas}).__contains__) == needs.ATLAS_GONE + atlas
    assert need((on_disk - {atlas, edit}).__contains__) == needs.EDIT_GONE + edit  # the edit layer named first
    assert need((on_disk - {manifest, plate}).__contains__) == needs.MANIFEST_GONE + manifest
    assert needs.render_need(manifest, passes, on_disk.__contains__) is None  # plate '' (not given): not checked
    for line in (needs.PLATE_GONE, needs.ATLAS_GONE, needs.MANIFEST_GONE, needs.PASSES_GONE):
        assert "Relink Run Folder" in line and len(line) < 120  # room for the path in Blender's 200 characters


def test_the_moved_line_and_relink():
    on_disk = {"/r/m.json", "/r/p.exr"}.__contains__
    assert needs.moved_need("/r/m.json", "/r/p.exr", on_disk) is None
    assert needs.moved_need("/gone/m.json", "/r/p.exr", on_disk) == needs.MANIFEST_GONE + "/gone/m.json"
    assert needs.moved_need("/r/m.json", "/gone/p.exr", on_disk) == needs.PASSES_GONE + "/gone/p.exr"
    assert needs.moved_need("", None, on_disk) == needs.NO_IMPORT
    plate_gone = needs.moved_need("/r/m.json", "/r/p.exr", on_disk, plate_file="/gone/1.png")
    assert plate_gone == needs.PLATE_GONE + "/gone/1.png"
    assert needs.moved_need("/r/m.json", "/r/p.exr", on_disk, plate_file="") is None  # not checked
    assert needs.relink_need("") == needs.NO_IMPORT and needs.relink_need("//run/m.json") is None


def test_the_clip_operators_need_a_clip():
    assert needs.clip_need(True) is None
    assert needs.clip_need(False) == needs.NO_FIT_CLIP == "Choose the clip to fit in the Fit Atlas panel"
    assert needs.clip_need(False, needs.NO_MASKS_CLIP) == needs.NO_MASKS_CLIP
