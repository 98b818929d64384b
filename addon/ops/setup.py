"""The preferences' operators: Set up engine (create its environment, install its requirements; only while
Blender's online access is on), Copy Install Command (the same set-up as a command for a terminal) and Check engine
(``python -m engine --version``)."""

from __future__ import annotations

from typing import Any

import bpy
from bpy.props import StringProperty

from .. import preferences
from ..core import engine_process as EP
from ..core import engine_setup as ES
from ..core import needs, running
from ..core.errors import UserError
from ..core.jobs import Job
from .driver import EngineJobOperator

#: ``core.running``'s key for Set up engine: one at a time, whatever the scene.
SETUP_KEY = running.SETUP_KEY


class NEURALATLAS_OT_setup_engine(EngineJobOperator, bpy.types.Operator):
    """Create a Python environment in the extension's user folder and install the engine's requirements"""

    bl_idname = "neural_atlas.setup_engine"
    bl_label = "Set up engine"
    # no UNDO: it changes the preferences (Engine Python), which are not in the undo history
    bl_options = {"REGISTER"}  # noqa: RUF012 (Blender reads a set)

    venv_dir: StringProperty(
        name="Folder", default="", options={"SKIP_SAVE", "HIDDEN"}, description="Where to create the engine's Python"
    )
    timeout = ES.SETUP_TIMEOUT_SECONDS
    redraw_areas = ("PREFERENCES",)
    cancel_where = "the add-on's preferences"
    _label = ""

    @classmethod
    def job_key(cls, context: Any) -> str:
        return SETUP_KEY

    @classmethod
    def poll(cls, context: Any) -> bool:
        refusal = preferences.online_refusal()
        if refusal:
            cls.poll_message_set(" ".join(refusal))  # the greyed button's tooltip says why
            return False
        return super().poll(context)

    def make_job(self, context) -> ES.SetupJob:
        refusal = preferences.online_refusal()
        if refusal:  # poll says so too; this holds for a call that skips poll
            raise UserError(" ".join(refusal))
        return ES.SetupJob(self.venv_dir or preferences.default_venv_dir(), preferences.torch_choice(context))

    def set_running(self, context, on: bool) -> None:
        pass  # the preferences show the job's status line instead

    def show(self, context, job: Job) -> None:
        if job.label != self._label:  # a new command: said once (the blocking path shows nothing else)
            self._label = job.label
            self.report({"INFO"}, f"Set up engine: {job.label}…")
        self._set_status(context, job.status_text())

    def finish(self, context, job: ES.SetupJob, result: EP.JobResult) -> set[str]:
        self._set_status(context, result.message)
        if result.status != EP.STATUS_OK:
            self.report({"WARNING" if result.status == EP.STATUS_CANCELLED else "ERROR"}, result.message)
            return {"CANCELLED"}
        prefs = preferences.addon_prefs(context)
        if prefs is not None:
            prefs.engine_python = job.python
        self.report({"INFO"}, result.message)
        return {"FINISHED"}

    def fail(self, context, message: str) -> None:
        self._set_status(context, message)
        self.report({"ERROR"}, message)

    @staticmethod
    def _set_status(context: Any, text: str) -> None:
        prefs = preferences.addon_prefs(context)
        if prefs is not None:
            prefs.setup_status = text


class NEURALATLAS_OT_cancel_setup(bpy.types.Operator):
    """Stop Set up engine (what it installed so far stays; Set up engine again installs the rest)"""

    bl_idname = "neural_atlas.cancel_setup"
    bl_label = "Cancel"
    bl_options = {"REGISTER"}  # noqa: RUF012 (Blender reads a set): it stops a process, nothing to undo

    @classmethod
    def poll(cls, context: Any) -> bool:
        return needs.poll(cls, needs.cancel_need(running.is_running(SETUP_KEY), needs.SETUP_NOT_RUNNING))

    def execute(self, context):
        job = running.get(SETUP_KEY)
        if job is None:  # poll says so; this holds for a call that skips poll
            return {"CANCELLED"}
        job.cancel()
        NEURALATLAS_OT_setup_engine._set_status(context, job.cancel_text)
        return {"FINISHED"}


class NEURALATLAS_OT_copy_setup_command(bpy.types.Operator):
    """Copy the command that sets up the engine's Python from a terminal (no download from Blender)"""

    bl_idname = "neural_atlas.copy_setup_command"
    bl_label = "Copy Install Command"
    bl_options = {"REGISTER"}  # noqa: RUF012 (Blender reads a set): the clipboard is not undone

    def execute(self, context):
        torch = preferences.torch_choice(context)
        venv_dir = preferences.default_venv_dir()
        context.window_manager.clipboard = ES.manual_setup_command(venv_dir, torch)
        message = (
            f"copied (torch {torch.name}, about {torch.download_gb:g} GB): run it in a terminal, then set Engine "
            f"Python to {ES.venv_python(venv_dir)}"
        )
        NEURALATLAS_OT_setup_engine._set_status(context, message)
        self.report({"INFO"}, message)
        return {"FINISHED"}


class NEURALATLAS_OT_check_engine(bpy.types.Operator):
    """Run `python -m engine --version` with the engine Python"""

    bl_idname = "neural_atlas.check_engine"
    bl_label = "Check engine"
    bl_options = {"REGISTER"}  # noqa: RUF012 (Blender reads a set): it only runs the engine and reports

    def execute(self, context):
        ok, message = ES.check_engine(preferences.engine_python(context))
        self.report({"INFO" if ok else "ERROR"}, message)
        NEURALATLAS_OT_setup_engine._set_status(context, message)
        return {"FINISHED"} if ok else {"CANCELLED"}


classes = (
    NEURALATLAS_OT_setup_engine,
    NEURALATLAS_OT_cancel_setup,
    NEURALATLAS_OT_copy_setup_command,
    NEURALATLAS_OT_check_engine,
)
