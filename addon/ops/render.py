"""Render Edited Clip: the compositor's result for the imported frames, as EXR, PNG or a movie."""

from __future__ import annotations

import bpy
from bpy.props import EnumProperty, StringProperty

from ...engine import contract as C
from .. import compositor, paint
from ..core import needs
from ..core import tree_plan as P
from .paint import edit_images
from .scene_inputs import abspath


def passes_file() -> str | None:
    """The imported passes' first file on disk (None without the passes image)."""
    img = bpy.data.images.get(P.PASSES_IMAGE)
    return abspath(img.filepath) if img is not None and img.filepath else None


def edit_files() -> list[str]:
    """The files of the edit layers the tree shows (a packed one, or one made in Blender, has none to miss)."""
    return [
        abspath(img.filepath)
        for img in edit_images()
        if img.filepath and img.packed_file is None and img.source != "GENERATED"
    ]


def atlas_files() -> list[str]:
    """The files of the imported atlas images (``NA_Atlas_<Layer>``) that come from a file."""
    prefix = P.atlas_image_name("")
    return [
        abspath(img.filepath)
        for img in bpy.data.images
        if img.name.startswith(prefix) and img.filepath and img.packed_file is None and img.source != "GENERATED"
    ]


def plate_file() -> str | None:
    """The imported plate clip's file (None without the clip)."""
    clip = bpy.data.movieclips.get(P.PLATE_CLIP)
    return abspath(clip.filepath) if clip is not None else None


def imported_manifest(context) -> str:
    """The scene's imported manifest, absolute ('' when none; it is stored relative to the .blend where it can)."""
    props = getattr(context.scene, "neural_atlas", None)
    return abspath(props.manifest) if props is not None and props.manifest else ""


def _need(context) -> str | None:
    """What Render lacks (``needs.render_need``), read from the scene: the poll's line, and execute's."""
    return needs.render_need(
        imported_manifest(context),
        passes_file(),
        edit_files=edit_files(),
        plate_file=plate_file(),
        atlas_files=atlas_files(),
    )


class NEURALATLAS_OT_render(bpy.types.Operator):
    """Render the edited clip from the compositor"""

    bl_idname = "neural_atlas.render"
    bl_label = "Render Edited Clip"
    # no UNDO: what it makes is files, which an undo cannot take back; the output settings it sets are put back
    bl_options = {"REGISTER"}  # noqa: RUF012 (Blender reads a set)

    directory: StringProperty(subtype="DIR_PATH", options={"SKIP_SAVE"})
    file_format: EnumProperty(
        items=[("", "Scene setting", ""), ("exr", "EXR", ""), ("png", "PNG", ""), ("movie", "Movie", "")],
        default="",
        options={"SKIP_SAVE"},
    )

    @classmethod
    def poll(cls, context):
        need = _need(context)
        if need:
            cls.poll_message_set(need)
        return need is None

    def execute(self, context):
        props = context.scene.neural_atlas
        out = abspath(self.directory or props.render_dir)
        fmt = self.file_format or props.render_format
        need = _need(context)
        if need:  # poll says so; this holds for a call that skips poll (and for files gone since it ran)
            self.report({"ERROR"}, need)
            return {"CANCELLED"}
        try:
            # the paint is saved first, so the render is of what the artist sees; a run folder in use or a full
            # disk stops the render with the one line that says so (the paint stays unsaved in Blender)
            paint.save_edits()
            space = P.output_colorspace(C.load_manifest(imported_manifest(context))["clip"])
            files = compositor.render(context.scene, out, fmt, space)
        except (RuntimeError, ValueError, OSError, C.RunLocked) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"rendered {len(files)} file(s) to {out}")
        return {"FINISHED"}


classes = (NEURALATLAS_OT_render,)
