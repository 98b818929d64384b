"""Refine: continue the Run Folder's finished fit for more steps (or with a better preset's schedule) and carry the
artist's paint over to it.

The paint is saved to the edit layer files first (``edit_layers.save_before_reload``: the engine reads those files, and
the import at the end reloads the images). The job (``core.jobs.RefineJob``) runs ``fit --refine``, ``export`` (a new
``exports/vNNN``; the earlier exports stay) and ``realign`` (the edit layers moved from the export they were painted
on onto the new mapping, the old ones kept in ``edits/history``); then the new export is imported like a finished
Fit Atlas.

Carry Paint does the same for another fit of the same plate (another Run Folder: a better preset, other masks, Find
Parts on or off): ``realign --from`` that fit's export lays its paint onto the imported fit's edit layers, whatever
layers either has, and says how much of it landed (``core.jobs.CarryJob``).
"""

from __future__ import annotations

import bpy

from ...engine import contract as C
from .. import compositor, edit_layers
from ..core import engine_process as EP
from ..core import needs, relink, running
from ..core.errors import UserError
from ..core.jobs import CarryJob, RefineJob, carry_text
from ..core.run_files import RunFiles
from ..properties import REFINE_SAME_PRESET
from . import scene_inputs as I
from .driver import EngineJobOperator
from .fit import _timeout
from .import_run import IMPORT_ERRORS, import_manifest

#: What names the refine in refusals of unsaved paint.
ACTION = "Refine"


def holds_fit(props) -> bool:
    """Whether the panel's Run Folder holds a fit, finished or stopped (Fit Atlas would refuse to overwrite it)."""
    try:
        return RunFiles(I.run_dir(props)).has_fit()
    except UserError:
        return False


def save_paint_first(action: str) -> None:
    """The edit layers' unsaved paint saved to their files before ``action``'s engine job reads them (and its import
    reloads them); UserError (one line) when some paint cannot be saved, before anything runs."""
    try:
        edit_layers.save_before_reload(action)
    except (ValueError, OSError) as exc:
        raise UserError(f"{action}: {exc}") from None


def finished_fit(props) -> bool:
    """Whether the panel's Run Folder holds a finished fit (False when no Run Folder can be named yet)."""
    try:
        return RunFiles(I.run_dir(props)).has_finished_fit()
    except UserError:
        return False


class NEURALATLAS_OT_refine(EngineJobOperator, bpy.types.Operator):
    """Continue the finished fit for more steps, then carry the paint over to the refined atlases and import them"""

    bl_idname = "neural_atlas.refine"
    bl_label = "Refine"
    # its import is one undo step, pushed when it finishes (the driver's docstring)
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012 (Blender reads a set)

    timeout: _timeout()

    @classmethod
    def poll(cls, context) -> bool:
        if context.scene is None:
            return False
        props = context.scene.neural_atlas
        return needs.poll(cls, needs.refine_need(running.is_running(cls.job_key(context)), finished_fit(props)))

    def make_job(self, context) -> RefineJob:
        props = context.scene.neural_atlas
        python, run_dir = I.engine_python(context), I.run_dir(props)
        preset = None if props.refine_preset == REFINE_SAME_PRESET else props.refine_preset
        job = RefineJob(python, run_dir, props.refine_steps, preset, props.follow_flow)
        save_paint_first(ACTION)
        return job

    def finish(self, context, job: RefineJob, result: EP.JobResult) -> set[str]:
        props = context.scene.neural_atlas
        props.log_path = job.log_path
        if result.status == EP.STATUS_OK and job.manifest:
            try:
                plan = import_manifest(context, job.manifest, action=ACTION)
            except (*IMPORT_ERRORS, RuntimeError) as exc:
                props.status = f"import failed: {exc}"
                self.report({"ERROR"}, f"{props.status} (log: {job.log_path})")
                return {"CANCELLED"}
            props.progress = 1.0
            props.can_resume = False
            props.status = props.fit_result = (
                f"refined: {len(plan.layers)} layers, the paint carried over ({job.manifest})"
            )
            self.report({"INFO"}, f"Refine done; imported {job.manifest}")
            return {"FINISHED"}
        props.can_resume = result.status == EP.STATUS_CANCELLED and job.can_resume()
        props.status = result.message
        level = "WARNING" if result.status == EP.STATUS_CANCELLED else "ERROR"
        self.report({level}, f"Refine {result.status}: {result.message} (log: {job.log_path})")
        return {"CANCELLED"}


#: What the carried paint's reload is called in its lines (``edit_layers.save_before_reload``).
CARRY_ACTION = "Carry Paint"


def carry_source(props, manifest: str) -> str:
    """The manifest Carry Paint takes the paint from: the Paint From setting (a run folder: its newest export's
    manifest; ``core.relink.find_manifest``); UserError (one line) when it names none, or names this fit."""
    if not props.carry_from:
        raise UserError("choose Paint From: another fit of this plate (its run folder, or its manifest.json)")
    try:
        source = relink.find_manifest(I.abspath(props.carry_from))
    except ValueError as exc:
        raise UserError(str(exc)) from None
    if C.manifest_run_root(source) == C.manifest_run_root(manifest):
        raise UserError("Paint From is this fit's own run folder: Refine carries its paint; choose another fit")
    return source


class NEURALATLAS_OT_carry_paint(EngineJobOperator, bpy.types.Operator):
    """Lay the paint of another fit of this plate (Paint From) onto this fit's edit layers, whatever its layers"""

    bl_idname = "neural_atlas.carry_paint"
    bl_label = "Carry Paint"
    # no undo step: it rewrites the edit layer files (their old pixels are in edits/history), which undo cannot restore
    bl_options = {"REGISTER"}  # noqa: RUF012 (Blender reads a set)

    timeout: _timeout()

    @classmethod
    def poll(cls, context) -> bool:
        if context.scene is None or not EngineJobOperator.poll.__func__(cls, context):  # type: ignore[attr-defined]
            return False
        props = context.scene.neural_atlas
        return needs.poll(cls, needs.carry_need(props.manifest, props.carry_from))

    def make_job(self, context) -> CarryJob:
        props = context.scene.neural_atlas
        python, manifest = I.engine_python(context), compositor.imported_manifest(context.scene)
        job = CarryJob(python, manifest, carry_source(props, manifest), C.manifest_run_root(manifest))
        save_paint_first(CARRY_ACTION)
        return job

    def finish(self, context, job: CarryJob, result: EP.JobResult) -> set[str]:
        props = context.scene.neural_atlas
        props.log_path = job.log_path
        if result.status == EP.STATUS_OK and job.report is not None:
            try:
                import_manifest(context, job.manifest, action=CARRY_ACTION)  # the edit layers reloaded
            except (*IMPORT_ERRORS, RuntimeError) as exc:
                props.status = f"import failed: {exc}"
                self.report({"ERROR"}, f"{props.status} (log: {job.log_path})")
                return {"CANCELLED"}
            props.progress = 1.0
            props.status = props.fit_result = carry_text(job.source, job.report)
            self.report({"INFO"}, props.status)
            return {"FINISHED"}
        props.status = result.message
        level = "WARNING" if result.status == EP.STATUS_CANCELLED else "ERROR"
        self.report({level}, f"{CARRY_ACTION} {result.status}: {result.message} (log: {job.log_path})")
        return {"CANCELLED"}


classes = (NEURALATLAS_OT_refine, NEURALATLAS_OT_carry_paint)
