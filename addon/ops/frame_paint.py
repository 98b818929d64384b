"""Paint on a plate frame: Paint on Frame (a transparent plate-sized image to paint over frame N) and Land Paint on
Atlases (``engine project-frame`` as a modal engine job, then the edit layers reloaded and the frame paint cleared).

The paths, the frame checks and the refusals are ``core.frame_paint``; the job is ``core.project_job``. The frame
paint is ``tree_plan.FRAME_PAINT_IMAGE``, an 8-bit RGBA image saved as ``RUN/edits/frames/frame.<NNNNN>.png`` (sRGB,
straight alpha, like a PNG edit layer); its ``frame_paint.FRAME_PROP`` custom property is the plate frame. Where the
live preview plane (``tree_plan.PREVIEW_OBJECT``) exists, its material's "FramePaint" image node shows it over the
composite and becomes the active paint slot, so the artist paints over the plate in Texture Paint mode; the Image
Editor paints it too.
"""

from __future__ import annotations

import os
import time
from typing import Any

import bpy
import numpy as np

from ...engine import contract as C
from .. import compositor, edit_layers, preview_plane
from ..core import engine_process as EP
from ..core import frame_paint as FP
from ..core import needs, running, unsaved_paint
from ..core import preview_plan as V
from ..core import tree_plan as P
from ..core.errors import UserError
from ..core.project_job import ProjectFrameJob
from . import scene_inputs as I
from .driver import EngineJobOperator
from .paint import edit_images

#: The preview material's image node that shows the frame paint over the composite.
PREVIEW_NODE = V.FRAME_PAINT_NODE
#: Seconds a poll's "no paint" answer is reused while the frame paint holds unsaved strokes (the poll runs on every
#: redraw; reading a plate's pixels each time would slow painting down). A "yes" stays until Paint on Frame or Land
#: forget it; a "no" given before the first stroke is dropped by that stroke (the image becomes unsaved).
PAINTED_CACHE_SECONDS = 0.5
#: Frame paint -> (when, its pointer, painted, unsaved then).
_painted_cache: dict[str, tuple[float, int, bool, bool]] = {}
#: Paint on Frame and Land while an engine job runs for the scene (one job at a time; Land reads the frame paint).
JOB_RUNNING = "An engine job is running for this scene: wait for it, or Cancel it"


def frame_paint_image() -> Any:
    return bpy.data.images.get(P.FRAME_PAINT_IMAGE)


def painted_frame(img: Any) -> int | None:
    """The plate frame ``img`` was started on (None: not a frame paint)."""
    if img is None:
        return None
    frame = img.get(FP.FRAME_PROP)
    return int(frame) if isinstance(frame, int) else None


def alpha_max(img: Any) -> float:
    """The largest alpha in ``img`` (0 for an empty image)."""
    w, h = img.size
    if not w or not h:
        return 0.0
    px = np.empty(w * h * img.channels, np.float32)
    img.pixels.foreach_get(px)
    return float(px[img.channels - 1 :: img.channels].max()) if img.channels == 4 else 1.0


def has_paint(img: Any, cached: bool = False) -> bool:
    """Whether the frame paint holds some paint; ``cached``: an earlier answer will do when it still holds
    (``FP.painted_answer_holds``)."""
    now = time.monotonic()
    key = img.name_full
    hit = _painted_cache.get(key)
    if cached and hit is not None and hit[1] == img.as_pointer():
        when, _, painted, dirty = hit
        if FP.painted_answer_holds(painted, dirty, img.is_dirty, now - when, PAINTED_CACHE_SECONDS):
            return painted
    painted = FP.has_paint(alpha_max(img))
    _painted_cache[key] = (now, img.as_pointer(), painted, bool(img.is_dirty))
    return painted


def forget_painted() -> None:
    """Forget every answer of ``has_paint`` (another file was loaded: its images are others)."""
    _painted_cache.clear()


def _blank_png(path: str, size: tuple[int, int]) -> None:
    """A fully transparent 8-bit RGBA PNG of ``size`` at ``path`` (written whole or not at all)."""
    w, h = size
    tmp = bpy.data.images.new(f"{P.PREFIX}tmp_frame_paint", w, h, alpha=True, float_buffer=False)
    try:
        tmp.pixels.foreach_set(np.zeros(w * h * 4, np.float32))
        tmp.filepath_raw = path
        tmp.file_format = "PNG"
        os.makedirs(os.path.dirname(path), exist_ok=True)
        edit_layers.save_atomically(tmp, path)
    finally:
        bpy.data.images.remove(tmp)


def save_frame_paint(img: Any) -> str:
    """Write the frame paint's unsaved strokes to its file (8-bit sRGB PNG, straight alpha); returns the path."""
    path = I.abspath(img.filepath)
    if img.is_dirty:
        img.filepath_raw = path
        img.file_format = "PNG"
        edit_layers.save_atomically(img, path)
    return path


def _keep_unsaved(img: Any) -> None:
    """Save the unsaved paint of an earlier frame paint to its file before it is re-targeted (refused in one line
    when it has no file to go to)."""
    if not img.is_dirty:
        return
    dirty = unsaved_paint.EditImage(img.name, img.filepath, img.packed_file is not None, img.source == "GENERATED")
    line = unsaved_paint.refusal(FP.START_LABEL, [dirty])
    if line:
        raise ValueError(line)
    save_frame_paint(img)


def start_frame_paint(context: Any, manifest_path: str, frame: int) -> Any:
    """The frame paint of plate ``frame``: its file loaded (paint started there before and not landed is kept),
    or a new transparent one; an earlier frame paint's unsaved strokes are saved to their file first. What can refuse
    (the frame, the live preview that will show the paint) is checked before anything is made or saved."""
    manifest = C.load_manifest(manifest_path)
    line = FP.frame_refusal(frame, list(manifest["passes"]["frames"]))
    if line:
        raise ValueError(line)
    planned = _preview_plan(context)
    path = FP.paint_file(FP.frames_dir(manifest_path, manifest), frame)
    w, h = (int(v) for v in manifest["passes"]["resolution"])
    img = frame_paint_image()
    if img is not None:
        _keep_unsaved(img)
    if not os.path.isfile(path):
        _blank_png(path, (w, h))
    if img is None or img.source != "FILE":
        if img is not None:
            bpy.data.images.remove(img)
        img = bpy.data.images.load(compositor.blend_path(path), check_existing=False)  # relative where it can be
        img.name = P.FRAME_PAINT_IMAGE
        img.colorspace_settings.name = "sRGB"
    elif I.abspath(img.filepath) != path:
        img.filepath = compositor.blend_path(path)
    img.reload()  # what the file holds (a frame paint started before stays as it was painted)
    img.alpha_mode = "STRAIGHT"
    img[FP.FRAME_PROP] = frame
    _painted_cache.pop(img.name_full, None)
    show_frame_paint(context, img, planned)
    return img


def _preview_plan(context: Any) -> Any:
    """The live preview's plan when its plane has no node for the frame paint yet (a preview built before the frame
    paint existed), else None; planning raises what the rebuild would, before anything is made."""
    obj = bpy.data.objects.get(P.PREVIEW_OBJECT)
    if obj is None or any(
        s.material is not None and s.material.node_tree is not None and PREVIEW_NODE in s.material.node_tree.nodes
        for s in obj.material_slots
    ):
        return None
    return preview_plane.plan_rebuild(context.scene)


def show_frame_paint(context: Any, img: Any, planned: Any = None) -> None:
    """The frame paint as what the brush paints: the preview plane's "FramePaint" node (its active paint slot), and
    the image every Image Editor shows. ``planned``: the preview's plan when it needs that node (``_preview_plan``)."""
    obj = bpy.data.objects.get(P.PREVIEW_OBJECT)
    if planned is not None:
        # a preview built before the frame paint existed has no node for it
        obj = preview_plane.rebuild(context.scene, planned)
    for slot in obj.material_slots if obj is not None else ():
        mat = slot.material
        node = mat.node_tree.nodes.get(PREVIEW_NODE) if mat is not None and mat.node_tree is not None else None
        if node is None:
            continue
        if node.image != img:
            node.image = img
        mat.node_tree.nodes.active = node  # the active image node is the texture-paint slot
        images = list(mat.texture_paint_images)
        if img in images:
            mat.paint_active_slot = images.index(img)
    wm = context.window_manager
    for window in wm.windows if wm is not None else ():
        for area in window.screen.areas:
            if area.type == "IMAGE_EDITOR":
                area.spaces.active.image = img


def _need_start(context) -> str | None:
    props = getattr(context.scene, "neural_atlas", None)
    if context.scene is not None and running.is_running(context.scene.name):
        return JOB_RUNNING  # Land may be reading the frame paint's file
    return FP.start_need(props.manifest if props is not None else "")


def _need_land(context, cached: bool = True) -> str | None:
    """What Land lacks; ``cached``: an earlier answer about the paint will do (the poll's redraws)."""
    props = getattr(context.scene, "neural_atlas", None)
    img = frame_paint_image()
    frame = painted_frame(img)
    painted = frame is not None and has_paint(img, cached=cached)
    return FP.land_need(props.manifest if props is not None else "", frame, painted)


class NEURALATLAS_OT_frame_paint_start(bpy.types.Operator):
    """Paint over the plate at the current frame, on a clear layer that Land Paint on Atlases puts on the atlases"""

    bl_idname = "neural_atlas.frame_paint_start"
    bl_label = FP.START_LABEL
    # an undo step: it adds (or re-targets) the frame paint image; its file stays on disk
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012 (Blender reads a set)

    @classmethod
    def poll(cls, context):
        return needs.poll(cls, _need_start(context))

    def execute(self, context):
        need = _need_start(context)
        if need:  # poll says so; this holds for a call that skips poll
            self.report({"ERROR"}, need)
            return {"CANCELLED"}
        frame = context.scene.frame_current
        try:
            img = start_frame_paint(context, compositor.imported_manifest(context.scene), frame)
        except (ValueError, OSError) as exc:  # ManifestError, a frame without passes, unsaved paint with no file
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        where = "the preview plane (Texture Paint)" if bpy.data.objects.get(P.PREVIEW_OBJECT) else "the Image Editor"
        self.report({"INFO"}, f"paint over frame {frame} in {img.name} ({where}), then {FP.LAND_LABEL}: {img.filepath}")
        return {"FINISHED"}


class NEURALATLAS_OT_frame_paint_land(EngineJobOperator, bpy.types.Operator):
    """Put the paint laid on this frame onto the atlases of the layers it covers, so it shows on every frame"""

    # the previous edit layers are kept in RUN/edits/history (engine project-frame writes the new ones)

    bl_idname = "neural_atlas.frame_paint_land"
    bl_label = FP.LAND_LABEL
    # no UNDO: it rewrites the edit layer files (the previous ones kept in edits/history/), which an undo cannot take
    # back, and the frame paint it clears is kept on disk (edits/frames/landed/)
    bl_options = {"REGISTER"}  # noqa: RUF012 (Blender reads a set)

    redraw_areas = ("CLIP_EDITOR", "PROPERTIES", "VIEW_3D", "IMAGE_EDITOR")
    cancel_where = "the Paint & Render panel (Movie Clip Editor sidebar)"

    @classmethod
    def poll(cls, context) -> bool:
        if not super().poll(context):
            cls.poll_message_set(JOB_RUNNING)
            return False
        return needs.poll(cls, _need_land(context))

    def make_job(self, context) -> ProjectFrameJob:
        need = _need_land(context, cached=False)  # the pixels as they are now, not the poll's last answer
        img = frame_paint_image()
        frame = painted_frame(img)
        if need or frame is None:  # poll says so; this holds for a call that skips poll
            raise UserError(need or FP.NO_FRAME_PAINT)
        python = I.engine_python(context)
        try:
            path = save_frame_paint(img)
            # project-frame composites OVER the edit layer files: unsaved atlas paint goes to them first
            edit_layers.save_before_reload(self.bl_label)
        except (ValueError, C.RunLocked) as exc:  # no file for some paint; a run folder in use
            raise UserError(str(exc)) from None
        return ProjectFrameJob(python, compositor.imported_manifest(context.scene), frame, path)

    def finish(self, context, job: ProjectFrameJob, result: EP.JobResult) -> set[str]:
        props = context.scene.neural_atlas
        props.log_path = job.log_path
        if result.status != EP.STATUS_OK:
            props.status = f"{self.bl_label}: {result.message}"
            level = "WARNING" if result.status == EP.STATUS_CANCELLED else "ERROR"
            self.report({level}, f"{props.status} (log: {job.log_path})")
            return {"CANCELLED"}
        if not job.landed:
            props.status = f"{self.bl_label}: the paint of frame {job.frame} fell on no layer; it is kept"
            self.report({"WARNING"}, props.status)
            return {"CANCELLED"}
        notes = reload_landed(job.landed)
        kept = clear_frame_paint(frame_paint_image(), job.paint)
        props.progress = 1.0
        props.status = f"landed frame {job.frame} on {', '.join(job.landed)}; previous edit layers in edits/history"
        self.report({"INFO"}, f"{props.status}; the frame paint is kept as {kept}")
        for note in notes:
            self.report({"WARNING"}, note)
        return {"FINISHED"}


def reload_landed(landed: dict[str, str]) -> list[str]:
    """Reload the edit images whose files the paint landed in (so the atlases, the tree and every frame show it);
    returns a line for each that could not be: one painted while the paint landed (reloading would drop those
    strokes: Save Edits would then write them over the landed paint, which stays in edits/history), or a file no
    edit image shows."""
    by_file = {os.path.normpath(I.abspath(img.filepath)): img for img in edit_images() if img.filepath}
    notes = []
    for layer, path in landed.items():
        img = by_file.get(os.path.normpath(path))
        if img is None:
            notes.append(f"{layer}: the paint landed in {path}, which no edit image shows: import the atlas again")
        elif img.is_dirty:
            notes.append(f"{img.name} was painted while the paint landed: not reloaded; its landed file is {path}")
        else:
            img.reload()
    return notes


def clear_frame_paint(img: Any, path: str) -> str:
    """Keep the landed frame paint file as ``landed/frame.<NNNNN>.<stamp>.png`` (never deleted) and start the frame
    paint afresh, transparent, so the next frame starts clean; returns where it is kept."""
    kept = FP.landed_file(path)
    os.makedirs(os.path.dirname(kept), exist_ok=True)
    os.replace(path, kept)
    if img is None or I.abspath(img.filepath) != os.path.normpath(path):
        return kept  # the image shows another file: nothing of it landed
    if img.is_dirty:
        # strokes made while the paint landed: saved where the frame paint was, to land next (not cleared)
        save_frame_paint(img)
        return kept
    w, h = img.size
    _blank_png(path, (w, h))
    img.reload()
    _painted_cache.pop(img.name_full, None)
    return kept


classes = (NEURALATLAS_OT_frame_paint_start, NEURALATLAS_OT_frame_paint_land)
