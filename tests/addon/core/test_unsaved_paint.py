"""Unsaved paint before a reload (``core.unsaved_paint``): saved to its file, or one line when it has none."""

from __future__ import annotations

from neural_atlas.addon.core import unsaved_paint as U


def _img(name="NA_Edit_Foreground", filepath="/run/edits/Foreground.png", packed=False, generated=False):
    return U.EditImage(name, filepath, packed, generated)


def test_paint_with_a_file_is_saved_not_refused():
    assert U.refusal("Import Atlas", []) is None
    assert U.refusal("Import Atlas", [_img(), _img("NA_Edit_Background", "//edits/Background.exr")]) is None


def test_paint_with_no_file_refuses_in_one_line_naming_the_image_and_the_fix():
    tail = "unpack it or Save As into the run's edits folder, then try again"
    packed = U.refusal("Fit Atlas", [_img(), _img("NA_Edit_Background", packed=True)])
    why = "(it is packed in the .blend)"
    assert packed == f"Fit Atlas would drop the unsaved paint of NA_Edit_Background {why}: {tail}"
    made = U.refusal("Float Edit Layers", [_img(generated=True)])
    assert made == f"Float Edit Layers would drop the unsaved paint of NA_Edit_Foreground (it has no file): {tail}"
    assert U.refusal("Import Atlas", [_img(filepath="")]) == made.replace("Float Edit Layers", "Import Atlas")
    for line in (packed, made):
        assert "\n" not in line and len(line) <= 200  # Blender quotes 200 characters of an operator's line
