"""Where the artist works (bpy 4.5 and 5.0): painting happens in the 3D viewport (Texture Paint on a canvas) and in
the Image Editor, so Paint & Render is in those editors' sidebars too, beside the Movie Clip Editor's: the same
panel, one class per editor, drawing the same buttons; Paint Layer picks the layer painted in both editors.

``draw()`` never runs headless (no region is drawn): it is called with a recording layout."""

from __future__ import annotations

import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from helpers import RecordingLayout  # noqa: E402
from neural_atlas.addon import edit_layers, ui  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402

#: The paint-side buttons every Paint & Render panel shows once an atlas is imported.
PAINT_SIDE = {
    "neural_atlas.paint_layer",
    "neural_atlas.save_edits",
    "neural_atlas.live_preview",
    "neural_atlas.frame_paint_start",
    "neural_atlas.frame_paint_land",
    "neural_atlas.render",
}


def _drawn(panel_cls, context) -> tuple[list[tuple[str, tuple, dict]], list[str], list[str]]:
    """What ``panel_cls`` draws: (the calls, the operators, the properties)."""
    calls = RecordingLayout().draw(panel_cls, context)
    return calls, [a[0] for n, a, _ in calls if n == "operator"], [a[1] for n, a, _ in calls if n == "prop"]


def test_paint_and_render_is_in_the_3d_viewport_and_the_image_editor(blender, tmp_path):
    """A Paint & Render panel is registered for the Movie Clip Editor, the 3D viewport and the Image Editor sidebars,
    in the same tab, and each draws the same operators and settings, one Paint Layer button per imported layer."""
    spaces = {getattr(bpy.types, cls.bl_idname).bl_space_type for cls in ui.PAINT_PANELS}
    assert spaces == {"CLIP_EDITOR", "VIEW_3D", "IMAGE_EDITOR"}
    for cls in ui.PAINT_PANELS:
        registered = getattr(bpy.types, cls.bl_idname)
        assert (registered.bl_region_type, registered.bl_category, registered.bl_label) == (
            "UI",
            ui.NEURALATLAS_PT_fit.bl_category,
            "Paint & Render",
        )
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(X.make_export(tmp_path))) == {"FINISHED"}
    drawn = [_drawn(cls, blender.context) for cls in ui.PAINT_PANELS]
    clip_ops, clip_props = drawn[0][1], drawn[0][2]
    assert clip_ops.count("neural_atlas.paint_layer") == 2  # Background, Foreground
    assert set(clip_ops) >= PAINT_SIDE and "filter_type" in clip_props
    for _, ops, props in drawn[1:]:
        assert ops == clip_ops and props == clip_props


def test_paint_layer_makes_the_layer_the_one_painted(blender, tmp_path):
    """Paint Layer: the layer's canvas becomes the active, only selected canvas (Texture Paint paints it), every
    Image Editor shows its edit image (Paint mode paints it), and the panel presses that layer's button."""
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(X.make_export(tmp_path))) == {"FINISHED"}
    screen = blender.context.window.screen
    area = screen.areas[0]
    area.type = "IMAGE_EDITOR"
    for layer in ("Foreground", "Background"):
        assert blender.ops.neural_atlas.paint_layer("EXEC_DEFAULT", layer=layer) == {"FINISHED"}
        active = blender.context.view_layer.objects.active
        assert active.name == edit_layers.canvas_name(layer)
        selected = {o.name for o in blender.context.view_layer.objects if o.select_get()}
        assert selected == {edit_layers.canvas_name(layer)}
        assert area.spaces.active.image == bpy.data.images[P.edit_image_name(layer)]
        assert edit_layers.painted_layer(blender.context) == layer
        calls = RecordingLayout().draw(ui.NEURALATLAS_PT_edit_view3d, blender.context)
        pressed = [
            kw.get("text")
            for n, a, kw in calls
            if n == "operator" and a[0] == "neural_atlas.paint_layer" and kw.get("depress")
        ]
        assert pressed == [layer]
    with pytest.raises(RuntimeError, match="no edit layer 'Sky' is imported: Import Atlas first"):
        blender.ops.neural_atlas.paint_layer("EXEC_DEFAULT", layer="Sky")
