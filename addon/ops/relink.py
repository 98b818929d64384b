"""Relink Run Folder: after the run folder moved, point every image, clip and setting the import made at the new
place (the path maths is ``core.relink``). Nothing is reloaded from the new place over unsaved paint: an edit
image with paint not yet saved keeps its pixels and only learns where its file now is (Save Edits writes there)."""

from __future__ import annotations

import os
from typing import Any

import bpy
from bpy.props import StringProperty

from ...engine import contract as C
from .. import compositor, preferences
from ..core import needs, relink
from ..core import tree_plan as P
from .preview import rebuild_shown
from .scene_inputs import abspath

#: What the file browser lists: manifests, and the plate's frames or movie.
PLATE_EXTENSIONS = ("png", "jpg", "jpeg", "exr", "tif", "tiff", "dpx", "mov", "mp4", "mkv", "avi")
PLATE_AND_MANIFEST = ";".join([C.MANIFEST_NAME, *(f"*.{e}" for e in PLATE_EXTENSIONS)])


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


def _chosen_manifest(chosen: str) -> str:
    """The manifest the file chosen names (``core.relink.find_manifest``), loaded to check it; ValueError (one line)
    when it names none (a plate's frame or movie, a folder without an export)."""
    if os.path.isfile(chosen) and not chosen.lower().endswith(".json"):
        raise ValueError(relink.NO_MANIFEST + chosen)
    new = relink.find_manifest(chosen)
    C.load_manifest(new)  # ManifestError: one line naming the file and the fix
    return new


def _moved_plate(chosen: str, not_manifest: str) -> str | tuple[str]:
    """The plate clip pointed at the plate's new place ``chosen`` (``core.relink.plate_choice``): (its new file,), or
    the error line (``not_manifest``'s where ``chosen`` is a manifest, or the scene has no plate clip from a file)."""
    clip = bpy.data.movieclips.get(P.PLATE_CLIP)
    if clip is None or not _from_file(clip) or chosen.lower().endswith(".json"):
        return not_manifest
    try:
        new = relink.plate_choice(chosen, abspath(clip.filepath), clip.source == "SEQUENCE")
    except ValueError as exc:
        return str(exc)
    start = clip.frame_start
    clip.filepath = compositor.blend_path(new)
    clip.frame_start = start
    return (new,)


def _tell_export(context: Any, manifest_path: str) -> str:
    """The export at ``manifest_path`` told where the scene's plate clip is (``core.relink.plate_sync``), so
    ``engine render`` and its ``.nk`` read the plate the scene shows: the report's line about it."""
    clip = bpy.data.movieclips.get(P.PLATE_CLIP)
    plate = abspath(clip.filepath) if clip is not None and _from_file(clip) else ""
    if not plate or not os.path.isfile(plate):
        return "the plate is not on disk: choose its new place with Relink"
    try:
        target = relink.plate_sync(manifest_path, C.load_manifest(manifest_path)["clip"], plate)
    except ValueError as exc:
        return f"the export still reads its plate elsewhere: {exc}"
    if target is None:
        return f"the export reads the plate at {os.path.dirname(plate) if clip.source == 'SEQUENCE' else plate}"
    return relink.tell_export(preferences.engine_python(context), manifest_path, target)


class NEURALATLAS_OT_relink(bpy.types.Operator):
    """Point the imported atlas's images, plate and settings at the run folder's or the plate's new place"""

    bl_idname = "neural_atlas.relink"
    bl_label = "Relink Run Folder"
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012 (Blender reads a set)

    filepath: StringProperty(
        subtype="FILE_PATH",
        options={"SKIP_SAVE"},
        description="The moved export's manifest.json or run folder, or the moved plate (a frame of it, or the movie)",
    )
    filter_glob: StringProperty(default=PLATE_AND_MANIFEST, options={"HIDDEN"}, description="The files to list")

    @classmethod
    def poll(cls, context):
        props = getattr(context.scene, "neural_atlas", None)
        return needs.poll(cls, needs.relink_need(props.manifest if props is not None else ""))

    def execute(self, context):
        old = compositor.imported_manifest(context.scene)
        if not old:  # poll says so; this holds for a call that skips poll
            self.report({"ERROR"}, needs.NO_IMPORT)
            return {"CANCELLED"}
        chosen = abspath(self.filepath)
        try:
            new = _chosen_manifest(chosen)
        except ValueError as exc:
            moved = _moved_plate(chosen, str(exc))
            if isinstance(moved, str):
                self.report({"ERROR"}, moved)
                return {"CANCELLED"}
            new, line, missing = old, f"the plate clip now shows {moved[0]}", False
        else:
            links = scene_links(context)
            plan = relink.plan_relink(links, old, new)
            apply(context, plan, links)
            line, missing = relink.message(plan), bool(plan.missing)
        told = _tell_export(context, new)
        shown = rebuild_shown(context.scene)
        warn = missing or told.startswith(("the export still", "the plate is not")) or bool(shown)
        self.report({"WARNING" if warn else "INFO"}, "; ".join(s for s in (line, told, shown) if s))
        return {"FINISHED"}

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}


classes = (NEURALATLAS_OT_relink,)
