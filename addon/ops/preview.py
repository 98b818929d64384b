"""Live Preview: build (or rebuild) the preview plane of the imported export and show it, or hide it."""

from __future__ import annotations

import bpy

from ...engine import contract as C
from .. import compat, preview
from ..core import needs
from ..core import tree_plan as P
from .import_run import IMPORT_ERRORS


class NEURALATLAS_OT_live_preview(bpy.types.Operator):
    """Show the edited plate at the current frame in the 3D viewport (Material Preview or Rendered shading), updated
    as you paint; press again to hide it"""

    bl_idname = "neural_atlas.live_preview"
    bl_label = "Live Preview"
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012 (Blender reads a set)

    @classmethod
    def poll(cls, context):
        need = None if context.scene.neural_atlas.manifest else needs.NO_IMPORT
        if need is not None:
            cls.poll_message_set(need)
        return need is None

    def execute(self, context):
        scene = context.scene
        if preview.is_shown(scene):
            preview.hide(scene)
            self.report({"INFO"}, "live preview hidden")
            return {"FINISHED"}
        props = scene.neural_atlas
        manifest_path = bpy.path.abspath(props.manifest)
        try:
            manifest = C.load_manifest(manifest_path)
            plan = P.plan_tree(manifest, manifest_path, props.filter_type, None, compat.colorspace_names())
            edits = {P.edit_image_name(layer) for layer in plan.layers}
            missing = sorted(name for name in edits if bpy.data.images.get(name) is None)
            if missing:
                raise ValueError(f"{', '.join(missing)} missing: import the atlas again ({manifest_path})")
            preview.build(scene, plan, manifest, manifest_path, props.filter_type)
        except IMPORT_ERRORS as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, "live preview: view it in Material Preview or Rendered shading")
        return {"FINISHED"}


classes = (NEURALATLAS_OT_live_preview,)
