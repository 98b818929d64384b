"""The foreground layers' operators: add and remove a layer, and the clip's scribble annotation layers."""

from __future__ import annotations

import bpy
from bpy.props import IntProperty

from ...engine import contract as C
from .. import scribbles
from ..core import needs


class NEURALATLAS_OT_layer_add(bpy.types.Operator):
    """Add a foreground layer"""

    bl_idname = "neural_atlas.layer_add"
    bl_label = "Add Layer"
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012 (Blender reads a set)

    def execute(self, context):
        props = context.scene.neural_atlas
        props.layers.add()
        props.layer_index = len(props.layers) - 1
        return {"FINISHED"}


class NEURALATLAS_OT_layer_remove(bpy.types.Operator):
    """Remove the selected foreground layer"""

    bl_idname = "neural_atlas.layer_remove"
    bl_label = "Remove Layer"
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012 (Blender reads a set)

    @classmethod
    def poll(cls, context):
        props = getattr(context.scene, "neural_atlas", None)
        return needs.poll(cls, needs.layer_remove_need(len(props.layers) if props is not None else 0))

    def execute(self, context):
        props = context.scene.neural_atlas
        if props.layers:
            props.layers.remove(props.layer_index)
            props.layer_index = max(0, min(props.layer_index, len(props.layers) - 1))
        return {"FINISHED"}


class NEURALATLAS_OT_scribble_layers(bpy.types.Operator):
    """Add annotation layers in the scribble colours to the clip (part 1 red, part 2 green, ...) to draw the parts on"""

    bl_idname = "neural_atlas.scribble_layers"
    bl_label = "Add Scribble Layers"
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012 (Blender reads a set)

    parts: IntProperty(
        name="Parts", default=2, min=2, max=len(C.SCRIBBLE_COLOURS), description="How many parts to draw, a colour each"
    )

    @classmethod
    def poll(cls, context):
        props = getattr(context.scene, "neural_atlas", None)
        return needs.poll(cls, needs.scribble_layers_need(props is not None and props.clip is not None))

    def execute(self, context):
        clip = context.scene.neural_atlas.clip
        if clip is None:  # poll says so; this holds for a call that skips poll
            self.report({"ERROR"}, needs.NO_CLIP)
            return {"CANCELLED"}
        names = scribbles.ensure_scribble_layers(clip, self.parts)
        self.report({"INFO"}, f"scribble layers: {', '.join(names)}; draw on each with the Annotate tool")
        return {"FINISHED"}


classes = (NEURALATLAS_OT_layer_add, NEURALATLAS_OT_layer_remove, NEURALATLAS_OT_scribble_layers)
