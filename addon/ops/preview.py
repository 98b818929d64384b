"""Live Preview: build (or rebuild) the preview plane of the imported export and show it, or hide it."""

from __future__ import annotations

import bpy

from .. import preview_plane
from ..core import needs
from .import_run import IMPORT_ERRORS


class NEURALATLAS_OT_live_preview(bpy.types.Operator):
    """Show the edited plate at the current frame in the 3D Viewport, updated as you paint; press again to hide it"""

    # it shows in Material Preview or Rendered shading

    bl_idname = "neural_atlas.live_preview"
    bl_label = "Live Preview"
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012 (Blender reads a set)

    @classmethod
    def poll(cls, context):
        return needs.poll(cls, None if context.scene.neural_atlas.manifest else needs.NO_IMPORT)

    def execute(self, context):
        scene = context.scene
        if preview_plane.is_shown(scene):
            preview_plane.hide(scene)
            self.report({"INFO"}, "live preview hidden")
            return {"FINISHED"}
        try:
            preview_plane.rebuild(scene)
        except IMPORT_ERRORS as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, "live preview: view it in Material Preview or Rendered shading")
        return {"FINISHED"}


classes = (NEURALATLAS_OT_live_preview,)
