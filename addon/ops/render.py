"""Render Edited Clip: the compositor's result for the imported frames, as EXR, PNG or a movie."""

from __future__ import annotations

import bpy
from bpy.props import EnumProperty, StringProperty

from ...engine import contract as C
from .. import compositor, paint
from ..core import tree_plan as P
from .paint import NO_ATLAS
from .scene_inputs import abspath


class NEURALATLAS_OT_render(bpy.types.Operator):
    """Render the edited clip from the compositor"""

    bl_idname = "neural_atlas.render"
    bl_label = "Render Edited Clip"

    directory: StringProperty(subtype="DIR_PATH", options={"SKIP_SAVE"})
    file_format: EnumProperty(
        items=[("", "Scene setting", ""), ("exr", "EXR", ""), ("png", "PNG", ""), ("movie", "Movie", "")],
        default="",
        options={"SKIP_SAVE"},
    )

    def execute(self, context):
        props = context.scene.neural_atlas
        out = abspath(self.directory or props.render_dir)
        fmt = self.file_format or props.render_format
        if not props.manifest:
            self.report({"ERROR"}, NO_ATLAS)
            return {"CANCELLED"}
        try:
            # the paint is saved first, so the render is of what the artist sees; a run folder in use or a full
            # disk stops the render with the one line that says so (the paint stays unsaved in Blender)
            paint.save_edits()
            space = P.output_colorspace(C.load_manifest(props.manifest)["clip"])
            files = compositor.render(context.scene, out, fmt, space)
        except (RuntimeError, ValueError, OSError, C.RunLocked) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"rendered {len(files)} file(s) to {out}")
        return {"FINISHED"}


classes = (NEURALATLAS_OT_render,)
