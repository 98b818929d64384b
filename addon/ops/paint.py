"""The edit layers' operators: paint canvases, Paint Layer, Save Edits, and Float Edit Layers."""

from __future__ import annotations

import os

import bpy
from bpy.props import StringProperty

from ...engine import contract as C
from .. import compositor, edit_layers
from ..core import needs, run_files
from ..core import tree_plan as P
from .import_run import import_manifest
from .scene_inputs import abspath

#: What the operators that work on an imported atlas say without one (their polls say it first).
NO_ATLAS = needs.NO_IMPORT


def edit_images() -> list:
    """The imported edit layers' images (``NA_Edit_<Layer>``)."""
    prefix = P.edit_image_name("")
    return [img for img in bpy.data.images if img.name.startswith(prefix)]


class NEURALATLAS_OT_float_edits(bpy.types.Operator):
    """Paint in float: each layer's edit becomes a linear, premultiplied EXR beside its PNG (the engine uses it too)"""

    bl_idname = "neural_atlas.float_edits"
    bl_label = "Float Edit Layers"
    # an undo step: Ctrl+Z puts the PNGs back in the tree and canvases; the EXRs it wrote stay on disk, and are the
    # edit layers from then on (contract.edit_layer_file): Import Atlas shows them again
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012 (Blender reads a set)

    @classmethod
    def poll(cls, context):
        manifest = compositor.imported_manifest(context.scene)
        return needs.poll(cls, needs.float_edits_need(manifest, (img.filepath for img in edit_images())))

    def execute(self, context):
        props = context.scene.neural_atlas
        if not props.manifest:  # poll says so; this holds for a call that skips poll
            self.report({"ERROR"}, NO_ATLAS)
            return {"CANCELLED"}
        made, skipped = [], []
        manifest_path = compositor.imported_manifest(context.scene)
        try:
            manifest = C.load_manifest(manifest_path)
            # the import below reloads every edit image: unsaved paint goes to its file first (a PNG that becomes an
            # EXR too, so its file holds the paint as well as the EXR made from the same pixels does)
            edit_layers.save_before_reload(self.bl_label)
            with run_files.edits_lock(manifest_path, run_files.FLOAT_EDITS_HOLDER):
                for layer in manifest["layers"]:
                    img = bpy.data.images.get(P.edit_image_name(layer["name"]))
                    if img is None or abspath(img.filepath).lower().endswith(C.EDIT_LAYER_FLOAT_EXT):
                        continue  # not imported, or already float
                    run_edit = os.path.normpath(C.resolve_manifest_write_path(manifest_path, layer["edit_layer"]))
                    if abspath(img.filepath) != run_edit:
                        skipped.append(layer["name"])  # another image was given for this layer: not the run's edit
                        continue
                    made.append(edit_layers.make_float_edit(layer["name"], P.float_edit_path(manifest_path, layer)))
            keep = {name: abspath(bpy.data.images[P.edit_image_name(name)].filepath) for name in skipped}
            import_manifest(context, manifest_path, True, keep, action=self.bl_label)  # the tree, canvases: the EXRs
        except (ValueError, OSError, C.RunLocked) as exc:  # ManifestError, PlanError, an existing EXR, a full disk
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        msg = f"{len(made)} float edit layer(s): " + (", ".join(os.path.basename(p) for p in made) or "none")
        if skipped:
            msg += f"; not converted (they use another image than the run's edit layer): {', '.join(skipped)}"
        self.report({"INFO"}, msg)
        return {"FINISHED"}


class NEURALATLAS_OT_save_edits(bpy.types.Operator):
    """Save the painted edit layers to their files in the run folder (PNG or float EXR, as each layer is)"""

    bl_idname = "neural_atlas.save_edits"
    bl_label = "Save Edits"
    # no UNDO: it writes the paint to files, which an undo cannot take back; the .blend's data does not change
    bl_options = {"REGISTER"}  # noqa: RUF012 (Blender reads a set)

    @classmethod
    def poll(cls, context):
        images = edit_images()
        return needs.poll(cls, needs.save_edits_need(len(images), sum(1 for img in images if img.is_dirty)))

    def execute(self, context):
        try:
            saved = edit_layers.save_edits()
        except (ValueError, OSError, C.RunLocked) as exc:  # a run folder in use (one line naming it), a full disk
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"saved {len(saved)} edit layer(s)")
        return {"FINISHED"}


class NEURALATLAS_OT_paint_setup(bpy.types.Operator):
    """A canvas per layer: the edit layer as the active paint slot over the atlas"""

    bl_idname = "neural_atlas.paint_setup"
    bl_label = "Paint Canvases"
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012 (Blender reads a set)

    @classmethod
    def poll(cls, context):
        return needs.poll(cls, needs.paint_setup_need(len(edit_images())))

    def execute(self, context):
        prefix = P.edit_image_name("")
        layers = [img.name.removeprefix(prefix) for img in edit_images()]
        objs = edit_layers.setup_canvases(context, layers)
        self.report({"INFO"}, f"{len(objs)} canvas(es): select one and switch to Texture Paint")
        return {"FINISHED"}


class NEURALATLAS_OT_paint_layer(bpy.types.Operator):
    """Paint this layer: its canvas becomes active in the 3D Viewport and its edit image shows in each Image Editor"""

    bl_idname = "neural_atlas.paint_layer"
    bl_label = "Paint Layer"
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012 (Blender reads a set)

    layer: StringProperty(name="Layer", description="The imported layer to paint")

    @classmethod
    def poll(cls, context):
        return needs.poll(cls, needs.paint_setup_need(len(edit_images())))

    def execute(self, context):
        edit = bpy.data.images.get(P.edit_image_name(self.layer))
        if edit is None:
            self.report({"ERROR"}, f"no edit layer {self.layer!r} is imported: Import Atlas first")
            return {"CANCELLED"}
        canvas = bpy.data.objects.get(edit_layers.canvas_name(self.layer))
        if canvas is None or canvas.name not in context.view_layer.objects:
            canvas = next(iter(edit_layers.setup_canvases(context, [self.layer])), None)
        shown = edit_layers.show_layer(context, self.layer, canvas)
        self.report({"INFO"}, f"painting {self.layer}: its canvas is active, {shown} Image Editor(s) show it")
        return {"FINISHED"}


classes = (
    NEURALATLAS_OT_float_edits,
    NEURALATLAS_OT_save_edits,
    NEURALATLAS_OT_paint_setup,
    NEURALATLAS_OT_paint_layer,
)
