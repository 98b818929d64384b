"""Relink Run Folder: after the run folder moved, point every image, clip and setting the import made at the new
place (the path maths is ``core.relink``). Nothing is reloaded from the new place over unsaved paint: an edit
image with paint not yet saved keeps its pixels and only learns where its file now is (Save Edits writes there)."""

from __future__ import annotations

import os
from typing import Any

import bpy
from bpy.props import StringProperty

from ...engine import contract as C
from .. import compositor
from ..core import needs, relink
from ..core import tree_plan as P
from .render import imported_manifest
from .scene_inputs import abspath


def _from_file(block: Any) -> bool:
    return bool(block.filepath) and getattr(block, "packed_file", None) is None and block.source != "GENERATED"


def _ours(collection: Any) -> list[Any]:
    return [b for b in collection if b.name.startswith(P.PREFIX) and _from_file(b)]


def scene_links(context: Any) -> list[relink.Link]:
    """Every path the import (and the panel's settings) hold: the add-on's images and clips (``NA_`` names), the
    imported manifest, the Run Folder and each foreground layer's mask folder."""
    props = context.scene.neural_atlas
    links = [relink.Link(img.name, "image", abspath(img.filepath)) for img in _ours(bpy.data.images)]
    links += [relink.Link(clip.name, "clip", abspath(clip.filepath)) for clip in _ours(bpy.data.movieclips)]
    if props.manifest:
        links.append(relink.Link("Manifest", "prop", abspath(props.manifest)))
    if props.run_dir and (bpy.data.filepath or not props.run_dir.startswith(relink.BLEND_PREFIX)):
        links.append(relink.Link("Run Folder", "prop", abspath(props.run_dir), required=False))
    for i, layer in enumerate(props.layers):
        if layer.source == "FOLDER" and layer.folder:
            links.append(relink.Link(f"Foreground {i + 1} folder", "prop", abspath(layer.folder), required=False))
    return links


def _folder(path: str) -> str:
    """A folder setting as Blender's folder fields keep it: ending in a separator."""
    return path if path.endswith(("/", os.sep)) else path + "/"


def apply(context: Any, plan: relink.RelinkPlan, links: list[relink.Link]) -> None:
    """Write the plan's new paths into the datablocks and settings, relative to the .blend where they can be."""
    props = context.scene.neural_atlas
    for link in links:
        new = plan.moves.get(link.name)
        if new is None:
            continue
        stored = compositor.blend_path(new)
        if link.kind == "image":
            img = bpy.data.images[link.name]
            if img.is_dirty:
                img.filepath_raw = stored  # no reload: the unsaved paint stays, and is saved to the new place
            else:
                img.filepath = stored  # reloads from the new place
        elif link.kind == "clip":
            clip = bpy.data.movieclips[link.name]
            start = clip.frame_start
            clip.filepath = stored
            clip.frame_start = start
        elif link.name == "Manifest":
            props.manifest = stored
        elif link.name == "Run Folder":
            props.run_dir = _folder(stored)
        else:  # "Foreground N folder"
            index = int(link.name.split()[1]) - 1
            props.layers[index].folder = _folder(stored)


class NEURALATLAS_OT_relink(bpy.types.Operator):
    """Point the imported atlas's images, plate and settings at the run folder's new place"""

    bl_idname = "neural_atlas.relink"
    bl_label = "Relink Run Folder"
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012 (Blender reads a set)

    filepath: StringProperty(
        subtype="FILE_PATH", options={"SKIP_SAVE"}, description="The moved export's manifest.json, or its run folder"
    )
    filter_glob: StringProperty(default=C.MANIFEST_NAME, options={"HIDDEN"}, description="The files to list")

    @classmethod
    def poll(cls, context):
        props = getattr(context.scene, "neural_atlas", None)
        return needs.poll(cls, needs.relink_need(props.manifest if props is not None else ""))

    def execute(self, context):
        old = imported_manifest(context)
        if not old:  # poll says so; this holds for a call that skips poll
            self.report({"ERROR"}, needs.NO_IMPORT)
            return {"CANCELLED"}
        try:
            new = relink.find_manifest(abspath(self.filepath))
            C.load_manifest(new)  # ManifestError: one line naming the file and the fix
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        links = scene_links(context)
        plan = relink.plan_relink(links, old, new)
        apply(context, plan, links)
        self.report({"WARNING" if plan.missing else "INFO"}, relink.message(plan))
        return {"FINISHED"}

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}


classes = (NEURALATLAS_OT_relink,)
