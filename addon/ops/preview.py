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


def rebuild_shown(scene) -> str:
    """The live preview built again where it is shown (a new Preview Size, a relinked plate): '' when done or when
    none is shown; else hidden, and the line saying why."""
    if not preview_plane.is_shown(scene):
        return ""
    try:
        preview_plane.rebuild(scene)
    except IMPORT_ERRORS as exc:
        preview_plane.hide(scene)
        return f"live preview hidden: {exc}"
    return ""


def show_at_new_size(scene) -> str:
    """After the panel's Preview Size changed: the preview on screen built again at the new size (its files written
    where they are missing; the paint, the edit images and every file the artist made untouched), '' when done or
    when none is shown (the next Live Preview builds at the new size); else hidden, and the line saying why (also the
    panel's status)."""
    line = rebuild_shown(scene)
    if line:
        scene.neural_atlas.status = line
        print(f"Neural Atlas: {line}")
    return line


classes = (NEURALATLAS_OT_live_preview,)
