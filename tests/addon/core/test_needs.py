"""What each operator needs (``core.needs``): the line of each missing thing, None when ready."""

from __future__ import annotations

from neural_atlas.addon.core import needs


def test_render_needs_an_import_whose_manifest_and_passes_exist():
    on_disk = {"/run/exports/v001/manifest.json", "/run/exports/v001/passes/atlas.01001.exr"}
    manifest, passes = sorted(on_disk)
    assert needs.render_need("", passes, on_disk.__contains__) == needs.NO_IMPORT
    assert needs.render_need("/moved/manifest.json", passes, on_disk.__contains__) == (
        needs.MANIFEST_GONE + "/moved/manifest.json"
    )
    assert needs.render_need(manifest, None, on_disk.__contains__) == needs.NO_PASSES
    gone = "/run/exports/v002/passes/atlas.01001.exr"
    assert needs.render_need(manifest, gone, on_disk.__contains__) == needs.PASSES_GONE + gone
    assert needs.render_need(manifest, passes, on_disk.__contains__) is None


def test_render_need_reads_the_disk_by_default(tmp_path):
    manifest, passes = tmp_path / "manifest.json", tmp_path / "atlas.01001.exr"
    manifest.write_text("{}")
    assert needs.render_need(str(manifest), str(passes)) == needs.PASSES_GONE + str(passes)
    passes.write_bytes(b"")
    assert needs.render_need(str(manifest), str(passes)) is None


def test_render_needs_the_edit_layers_on_disk():
    """A missing edit layer would render as nothing (the bare plate): the line names the first missing file."""
    manifest, passes = "/run/exports/v001/manifest.json", "/run/exports/v001/passes/atlas.01001.exr"
    edits = ["/run/edits/Background.png", "/run/edits/Foreground.exr"]
    on_disk = {manifest, passes, *edits}
    assert needs.render_need(manifest, passes, on_disk.__contains__, edits) is None
    on_disk.discard(edits[1])
    assert needs.render_need(manifest, passes, on_disk.__contains__, edits) == needs.EDIT_GONE + edits[1]
    on_disk.discard(passes)  # the passes are named first: without them nothing renders
    assert needs.render_need(manifest, passes, on_disk.__contains__, edits) == needs.PASSES_GONE + passes
    assert needs.render_need(manifest, None, on_disk.__contains__, edits) == needs.NO_PASSES


def test_save_edits_needs_edit_layers_with_unsaved_paint():
    assert needs.save_edits_need(0, 0) == needs.NO_IMPORT
    assert needs.save_edits_need(2, 0) == needs.NOTHING_TO_SAVE
    assert needs.save_edits_need(2, 1) is None


def test_float_edits_needs_an_import_with_an_8_bit_edit_layer():
    assert needs.float_edits_need("", ["/run/edits/Foreground.png"]) == needs.NO_IMPORT
    assert needs.float_edits_need("/m.json", []) == needs.NO_IMPORT
    assert needs.float_edits_need("/m.json", ["/e/Background.EXR", "/e/Foreground.exr"]) == needs.ALL_FLOAT
    assert needs.float_edits_need("/m.json", ["/e/Background.exr", "//edits/Foreground.png"]) is None


def test_the_small_needs():
    assert needs.paint_setup_need(0) == needs.NO_IMPORT and needs.paint_setup_need(1) is None
    assert needs.cancel_need(False) == needs.NOTHING_RUNNING and needs.cancel_need(True) is None
    assert needs.cancel_need(False, needs.SETUP_NOT_RUNNING) == needs.SETUP_NOT_RUNNING
    assert needs.layer_remove_need(0) == needs.NO_LAYER and needs.layer_remove_need(2) is None
    assert needs.scribble_layers_need(False) == needs.NO_CLIP and needs.scribble_layers_need(True) is None


def test_lines_fit_in_blenders_poll_error():
    """Blender quotes at most 200 characters of a poll's line in the RuntimeError a script gets."""
    fixed = [v for k, v in vars(needs).items() if k.isupper() and isinstance(v, str)]
    assert fixed and all(len(line) < 120 for line in fixed)


def test_esc_says_where_cancel_is():
    line = needs.esc_text("Fit Atlas", "the Fit Atlas panel (Movie Clip Editor sidebar)")
    assert line == (
        "Fit Atlas keeps running (ESC does not stop it): press Cancel in the Fit Atlas panel (Movie Clip Editor "
        "sidebar) to stop it"
    )
