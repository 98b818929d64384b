"""Render Edited Clip: the compositor's result for the imported frames, as EXR, PNG or a movie.

From the button (``invoke``) it is modal: a timer tick renders one frame (``compositor.RenderSession``), the
Paint & Render panel shows "frame k/n · ETA" and a Cancel button, which stops after the frame being rendered
(the finished frames stay). A movie is one file written by one animation render (Blender cannot append a frame
to a movie file): one tick, the panel saying so. ``execute`` (background mode, scripts, tests) runs the same
steps in a loop. Either way the artist's output settings are put back at the end, on a cancel and on an error.
"""

from __future__ import annotations

import time
from typing import Any

import bpy
from bpy.props import EnumProperty, StringProperty

from ...engine import contract as C
from .. import compositor, edit_layers
from ..core import colorspaces, needs
from ..core import render_job as RJ
from ..core import tree_plan as P
from .paint import edit_images
from .scene_inputs import abspath

#: Seconds between two timer ticks: each renders one frame, the UI redraws in between.
RENDER_TICK_SECONDS = 0.05


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


def _need(context) -> str | None:
    """What Render lacks (``needs.render_need``), read from the scene: the poll's line, and execute's."""
    return needs.render_need(
        compositor.imported_manifest(context.scene),
        passes_file(),
        edit_files=edit_files(),
        plate_file=plate_file(),
        atlas_files=atlas_files(),
    )


#: The renders running now, by scene name: the Cancel button reaches the one of its scene, the panel draws its bar.
_RENDERS: dict[str, RenderRun] = {}


class RenderRun:
    """A Render Edited Clip under way: its ``compositor.RenderSession``, the steps left and its progress."""

    def __init__(self, session: compositor.RenderSession):
        self.session = session
        self.steps = session.steps()
        self.progress = RJ.RenderProgress(
            total=len(self.steps),
            movie=session.file_format not in RJ.FRAME_FORMATS,
            frames=len(session.frames()),
            note=RJ.outside_note(session.skipped(), session.exported) if session.exported else "",
        )
        self.cancel_asked = False

    def step(self) -> bool:
        """Render the next step; True while there is more to render (and no Cancel was asked)."""
        if self.cancel_asked:
            self.progress.cancelled = not self.progress.finished
            return False
        if self.progress.finished:
            return False
        t0 = time.perf_counter()
        self.session.render_step(self.steps[self.progress.done])
        self.progress.add(time.perf_counter() - t0)
        return not self.progress.finished


def active_render(scene) -> RenderRun | None:
    """The render running for ``scene`` (None when there is none)."""
    return _RENDERS.get(scene.name) if scene is not None else None


class NEURALATLAS_OT_render(bpy.types.Operator):
    """Render the edited clip from the compositor (frame by frame, with progress and Cancel, from the button)"""

    bl_idname = "neural_atlas.render"
    bl_label = "Render Edited Clip"
    # no UNDO: what it makes is files, which an undo cannot take back; the output settings it sets are put back
    bl_options = {"REGISTER"}  # noqa: RUF012 (Blender reads a set)

    directory: StringProperty(
        subtype="DIR_PATH", options={"SKIP_SAVE"}, description="The folder to write to (empty: the scene's Output)"
    )
    file_format: EnumProperty(
        items=[
            ("", "Scene setting", "The scene's Format"),
            ("exr", "EXR", "Float, linear"),
            ("png", "PNG", "8-bit sRGB"),
            ("movie", "Movie", "H.264 MP4"),
        ],
        default="",
        options={"SKIP_SAVE"},
        description="The file format (empty: the scene's Format)",
    )
    _timer: Any = None
    _run: RenderRun | None = None
    _out = ""

    @classmethod
    def poll(cls, context):
        if active_render(context.scene) is not None:
            cls.poll_message_set("a render of this scene is running: Cancel it or wait")
            return False
        return needs.poll(cls, _need(context))

    def _session(self, context) -> compositor.RenderSession | None:
        """The render's session, the paint saved first; None (reported) when it cannot start."""
        props = context.scene.neural_atlas
        self._out = abspath(self.directory or props.render_dir)
        fmt = self.file_format or props.render_format
        need = _need(context)
        if need:  # poll says so; this holds for a call that skips poll (and for files gone since it ran)
            self.report({"ERROR"}, need)
            return None
        try:
            # the paint is saved first, so the render is of what the artist sees; a run folder in use or a full
            # disk stops the render with the one line that says so (the paint stays unsaved in Blender)
            manifest = C.load_manifest(compositor.imported_manifest(context.scene))
            exported = P.contiguous_frames(list(manifest["passes"]["frames"]))
            clip = manifest["clip"]  # the EXR's colour space and the frames' names (padded as engine render's)
            session = compositor.RenderSession(
                context.scene, self._out, fmt, colorspaces.output_colorspace(clip), exported, RJ.output_template(clip)
            )
            if not session.frames():  # the scene's range lies outside the export: nothing it could render
                scene = context.scene
                raise ValueError(RJ.no_exported_frames((scene.frame_start, scene.frame_end), exported))
            edit_layers.save_edits()
        except (RuntimeError, ValueError, OSError, C.RunLocked) as exc:
            self.report({"ERROR"}, str(exc))
            return None
        return session

    def execute(self, context):
        """The blocking render (background mode, scripts, tests): the same steps as the button's, in one go."""
        session = self._session(context)
        if session is None:
            return {"CANCELLED"}
        run = RenderRun(session)
        try:
            session.begin()
            while run.step():
                pass
        except (RuntimeError, ValueError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        finally:
            session.end()
        line = run.progress.report(self._out)
        context.scene.neural_atlas.render_status = line  # the panel says what the last render did
        self.report({"WARNING" if run.progress.note else "INFO"}, line)
        return {"FINISHED"}

    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)  # no event loop: the blocking path
        started = self.start_modal(context)
        if started == {"RUNNING_MODAL"}:
            context.window_manager.modal_handler_add(self)
        return started

    def start_modal(self, context):
        """``invoke``'s start of the modal render: the session begun, the timer on, the render in the table (``invoke``
        then hands the operator to the window manager, whose timer events call ``modal``)."""
        session = self._session(context)
        if session is None:
            return {"CANCELLED"}
        try:
            session.begin()
        except (RuntimeError, ValueError, OSError) as exc:
            session.end()
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self._run = RenderRun(session)
        _RENDERS[context.scene.name] = self._run
        self._show(context)
        wm = context.window_manager
        self._timer = wm.event_timer_add(RENDER_TICK_SECONDS, window=context.window)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        run = self._run
        assert run is not None
        if event.type != "TIMER":
            return {"PASS_THROUGH"}  # ESC and every other key stay the artist's: Cancel is the panel's button
        try:
            more = run.step()
        except (RuntimeError, ValueError, OSError) as exc:
            self._stop(context)
            self.report({"ERROR"}, f"{exc} (frames rendered so far stay in {self._out})")
            return {"CANCELLED"}
        self._show(context)
        if more:
            return {"PASS_THROUGH"}
        self._stop(context)
        self.report({"WARNING" if run.progress.note else "INFO"}, run.progress.report(self._out))
        return {"CANCELLED"} if run.progress.cancelled else {"FINISHED"}

    def cancel(self, context):
        """Blender ends the operator (the file is closed, Blender quits): the settings go back all the same."""
        self._stop(context)

    def _show(self, context) -> None:
        run = self._run
        if run is None:
            return
        props = context.scene.neural_atlas
        props.render_progress = run.progress.fraction
        props.render_status = run.progress.summary()
        for window in context.window_manager.windows:
            for area in window.screen.areas:
                if area.type in ("CLIP_EDITOR", "PROPERTIES", "IMAGE_EDITOR"):
                    area.tag_redraw()

    def _stop(self, context) -> None:
        if self._timer is not None:
            context.window_manager.event_timer_remove(self._timer)
            self._timer = None
        run, self._run = self._run, None
        if run is None:
            return
        run.session.end()
        _RENDERS.pop(run.session.scene.name, None)
        context.scene.neural_atlas.render_status = run.progress.report(self._out)


class NEURALATLAS_OT_render_cancel(bpy.types.Operator):
    """Stop the render after the frame it is on; the finished frames stay"""

    bl_idname = "neural_atlas.render_cancel"
    bl_label = "Cancel Render"
    bl_options = {"REGISTER"}  # noqa: RUF012 (Blender reads a set): it stops a render, nothing to undo

    @classmethod
    def poll(cls, context) -> bool:
        if active_render(context.scene) is None:
            cls.poll_message_set("no render is running")
            return False
        return True

    def execute(self, context):
        run = active_render(context.scene)
        if run is None:  # poll says so; this holds for a call that skips poll
            return {"CANCELLED"}
        run.cancel_asked = True
        context.scene.neural_atlas.render_status = "cancelling after this frame…"
        return {"FINISHED"}


classes = (NEURALATLAS_OT_render, NEURALATLAS_OT_render_cancel)
