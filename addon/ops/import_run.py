"""Import Atlas: an export's manifest -> the compositor tree, the edit layers and their paint canvases."""

from __future__ import annotations

import os
from typing import Any

import bpy
from bpy.props import BoolProperty, StringProperty

from ...engine import contract as C
from .. import compat, compositor, edit_layers, line_up, preview_plane
from ..core import frames as F
from ..core import run_files
from ..core import tree_plan as P
from .scene_inputs import abspath, clip_plate

#: What an import that cannot be done raises, each one line saying what is wrong and what to do: a bad manifest or
#: plan; unsaved paint that cannot be saved first (ValueError), a run folder in use, a full disk.
IMPORT_ERRORS = (C.ManifestError, P.PlanError, ValueError, OSError, C.RunLocked)


def import_manifest(
    context: Any,
    manifest_path: str,
    setup_paint: bool = True,
    edits: dict[str, str] | None = None,
    *,
    set_range: bool = False,
    action: str = "Import Atlas",
) -> P.TreePlan:
    """Read the manifest, build the compositor tree, the paint canvases and the live preview (``edits``: layer ->
    other image; ``set_range``: the scene's range becomes the imported frames even where the artist's lies within
    them).

    Building reloads or replaces the edit images, so unsaved paint is saved to its files first
    (``edit_layers.save_before_reload``; ``action`` names what refuses when it cannot be); a refusal reloads nothing."""
    props = context.scene.neural_atlas
    manifest = C.load_manifest(manifest_path)
    plate = compositor.known_plate(context.scene, manifest_path)
    plan = P.plan_tree(
        manifest, manifest_path, props.filter_type, edits, compat.colorspace_names(), plate, compat.BILINEAR_TAPS
    )
    edit_layers.save_before_reload(action)
    compositor.build(context.scene, plan, set_range)
    if setup_paint:
        edit_layers.setup_canvases(context, plan.layers)
        preview_plane.build(context.scene, plan, manifest, manifest_path, props.filter_type)
    props.manifest = compositor.blend_path(os.path.abspath(manifest_path))  # relative to the .blend where it can be
    props.imported_layers = ", ".join(plan.layers)
    return plan


#: What follow_realigned's import is called in a refusal line.
OPEN_ACTION = "Open"


def follow_realigned(context: Any) -> str | None:
    """After a file is opened: when a refine re-aligned the run's edit layers to a later export than the one the file
    imported (Refine imports it, but the .blend was not saved after), that export is imported, so the paint on disk
    shows through the mapping it was carried onto and never through the old one. Returns the line it said (also the
    panel's status), None when there was nothing to do."""
    props = context.scene.neural_atlas
    if not props.manifest:
        return None
    newer = run_files.realigned_manifest(abspath(props.manifest))
    if newer is None:
        return None
    try:
        import_manifest(context, newer, action=OPEN_ACTION)
    except (*IMPORT_ERRORS, RuntimeError) as exc:
        line = f"the edit layers were re-aligned to {newer} by a refine, which could not be imported: {exc}"
    else:
        line = f"the edit layers were re-aligned by a refine: imported {newer}"
    props.status = line
    print(f"Neural Atlas: {line}")
    return line


def set_run_folder(context: Any, manifest_path: str) -> bool:
    """The panel's Run Folder becomes the imported export's run (``run_files.imported_run_dir``), so Refine continues
    the fit the atlas came from; left alone when it names that folder already or the manifest lies outside a run's
    exports. Whether it changed."""
    props = context.scene.neural_atlas
    run = run_files.imported_run_dir(manifest_path)
    current = os.path.realpath(abspath(props.run_dir)) if props.run_dir else ""
    if run is None or current == os.path.realpath(run):
        return False
    props.run_dir = compositor.blend_path(run).rstrip("/" + os.sep) + "/"  # relative to the .blend where it can be
    return True


def clip_note(context: Any) -> str | None:
    """``frames.clip_offset_note`` for the panel's clip (None: no clip, a movie, or it lines up)."""
    clip = context.scene.neural_atlas.clip
    if clip is None:
        return None
    return F.clip_offset_note(clip.name, clip.frame_start, clip_plate(clip)[1], P.PLATE_CLIP)


def line_up_clip(context: Any) -> str | None:
    """Line Up My Clip (``frames.line_up_offset``): the panel's clip starts at its first file's number and the masks
    of the foreground layers move with it (``line_up``); the fit's own range, in scene frames, moves too. The line
    saying what moved; None when there is nothing to line up."""
    props = context.scene.neural_atlas
    clip = props.clip
    if clip is None:
        return None
    offset = F.line_up_offset(clip.frame_start, clip_plate(clip)[1])
    if offset is None:
        return None
    masks = list(
        {m.name_full: m for m in (lyr.mask for lyr in props.layers if lyr.source == "MASK") if m is not None}.values()
    )
    keys, count = line_up.line_up(context, clip, masks, offset)
    props.frame_start += offset
    props.frame_end += offset
    return (
        f"clip {clip.name!r} starts at scene frame {clip.frame_start}; {count} mask(s), {keys} key(s) moved {offset:+d}"
    )


class NEURALATLAS_OT_import(bpy.types.Operator):
    """Import an exported run (manifest.json): compositor tree, edit layers and paint canvases"""

    bl_idname = "neural_atlas.import_run"
    bl_label = "Import Atlas"
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012 (Blender reads a set)

    filepath: StringProperty(subtype="FILE_PATH", description="The export's manifest.json")
    filter_glob: StringProperty(default=C.MANIFEST_NAME, options={"HIDDEN"}, description="The files to list")
    setup_paint: BoolProperty(
        name="Paint Canvases", default=True, description="Also set up a paint canvas for each layer's atlas"
    )
    set_range: BoolProperty(
        name="Set Scene Range",
        description="Set the scene's range to the imported frames even where the current range lies within them",
        default=False,
    )
    line_up_clip: BoolProperty(
        name="Line Up My Clip",
        description="Start the Fit Atlas panel's clip at its first file's number, so it shows plate frame N at scene "
        "frame N, and move the keys of the foreground layers' masks and of its scribbles by as many frames (they "
        "stay on the object)",
        default=False,
    )

    def execute(self, context):
        try:
            plan = import_manifest(context, abspath(self.filepath), self.setup_paint, set_range=self.set_range)
        except IMPORT_ERRORS as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        set_run_folder(context, abspath(self.filepath))  # the import after Fit Atlas or Refine is of its own run
        scene = context.scene
        kept = (scene.frame_start, scene.frame_end) != (plan.frame_start, plan.frame_end)
        note = f" (scene range {scene.frame_start}-{scene.frame_end} kept)" if kept else ""
        self.report({"INFO"}, f"imported {len(plan.layers)} layers, frames {plan.frame_start}-{plan.frame_end}{note}")
        if self.line_up_clip:
            lined = line_up_clip(context)
            if lined:
                self.report({"INFO"}, lined)
        clip = clip_note(context)
        if clip is not None:
            self.report({"WARNING"}, clip + " (or import with Line Up My Clip)")
        return {"FINISHED"}

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}


classes = (NEURALATLAS_OT_import,)
