"""Submit to Farm: the panel's clip as a shots file, sent by the engine to a Flamenco Manager or written as an
OpenJD bundle (``core.farm``). The engine runs out of process, as for Fit Atlas (``driver``)."""

from __future__ import annotations

from typing import Any

import bpy
from bpy.props import FloatProperty

from .. import preferences
from ..core import engine_process as EP
from ..core import farm as FM
from ..core.errors import UserError
from ..core.jobs import Job
from ..core.run_files import RunFiles
from . import scene_inputs as I
from .driver import EngineJobOperator


class NEURALATLAS_OT_submit_farm(EngineJobOperator, bpy.types.Operator):
    """Send the clip, its masks and preset to the farm chosen in the preferences, which fills the Run Folder"""

    # a Flamenco Manager job, or an OpenJD bundle for Deadline Cloud; Import Atlas reads the Run Folder as after Fit

    bl_idname = "neural_atlas.submit_farm"
    bl_label = "Submit to Farm"
    # no UNDO: it hands the clip to a farm (a job sent, a bundle written) and sets a status line; an undo cannot
    # take a job back from the Manager
    bl_options = {"REGISTER"}  # noqa: RUF012 (Blender reads a set)

    timeout: FloatProperty(name="Timeout", default=0.0, options={"SKIP_SAVE", "HIDDEN"}, description="0: none")

    @classmethod
    def poll(cls, context: Any) -> bool:
        props = getattr(context.scene, "neural_atlas", None)
        if props is None or props.clip is None:
            cls.poll_message_set("Choose the clip to submit")
            return False
        if not preferences.engine_python(context):
            cls.poll_message_set("Set up the engine in the add-on's preferences")
            return False
        refusal = preferences.farm_refusal(context)
        if refusal:  # the greyed button's tooltip says why
            cls.poll_message_set(refusal)
            return False
        return super().poll(context)

    def make_job(self, context: Any) -> FM.FarmJob:
        refusal = preferences.farm_refusal(context)
        if refusal:  # poll says so too; this holds for a call that skips poll
            raise UserError(refusal)
        props = context.scene.neural_atlas
        settings = preferences.farm_settings(context)
        if settings.kind == FM.FARM_FLAMENCO:
            FM.check_manager_url(settings.manager_url)  # before the masks are rasterised
        python, files = I.engine_python(context), RunFiles(I.run_dir(props))
        shot = I.farm_shot(props, files)
        shots = FM.write_shots_file(shot, files.shots_file)
        bundle = FM.fresh_bundle_dir(settings, files.run_dir, shot.name) if settings.kind == FM.FARM_OPENJD else None
        return FM.FarmJob(python, settings, shots, files.farm_log, bundle)

    def show(self, context: Any, job: Job) -> None:
        context.scene.neural_atlas.farm_status = job.status_text()

    def set_running(self, context: Any, on: bool) -> None:
        pass  # the fit's progress bar stays the fit's; the farm's one line is farm_status

    def fail(self, context: Any, message: str) -> None:
        context.scene.neural_atlas.farm_status = message
        self.report({"ERROR"}, message)

    def finish(self, context: Any, job: FM.FarmJob, result: EP.JobResult) -> set[str]:
        props = context.scene.neural_atlas
        props.farm_status = result.message
        if result.status != EP.STATUS_OK:
            self.report({"ERROR"}, f"Submit to Farm: {result.message} (log: {job.log_path})")
            return {"CANCELLED"}
        self.report({"INFO"}, result.message)
        return {"FINISHED"}


classes = (NEURALATLAS_OT_submit_farm,)
