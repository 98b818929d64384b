"""The operators that run the engine for a scene: Fit Atlas, Find Masks, Estimate Time, and Cancel.

Each makes a job (``core.jobs``) from the scene (``scene_inputs``) and lets the driver run it; its ``finish``
turns the result into the scene's state and a report.
"""

from __future__ import annotations

import json
from typing import Any

import bpy
from bpy.props import BoolProperty, FloatProperty

from ..core import engine_process as EP
from ..core import estimate, needs, progress, running
from ..core import frames as F
from ..core import tree_plan as P
from ..core.errors import UserError
from ..core.jobs import EstimateJob, FitJob, MasksJob
from ..core.run_files import RunFiles
from . import scene_inputs as I
from .driver import EngineJobOperator
from .import_run import IMPORT_ERRORS, import_manifest

#: The Movie Clip the found masks are loaded as, for checking (Blender numbers repeats: NA_AutoMasks.001).
AUTO_MASKS_CLIP = f"{P.PREFIX}AutoMasks"


def _clip_poll(cls: Any, context: Any, has_clip: bool, line: str) -> bool:
    """The driver's poll (no job of this scene running), then the clip (``needs.clip_need``): greyed out, saying to
    choose the clip, instead of a button that refuses when pressed."""
    if not EngineJobOperator.poll.__func__(cls, context):  # type: ignore[attr-defined]
        return False
    return needs.poll(cls, needs.clip_need(has_clip, line))


def _timeout() -> Any:
    """The blocking path's limit in seconds, after which the job is cancelled (scripts, tests; 0: none)."""
    return FloatProperty(name="Timeout", default=0.0, options={"SKIP_SAVE", "HIDDEN"}, description="0: none")


def done_text(layers: list[str], parts: tuple[int, str] | None) -> str:
    """The status line once Fit Atlas imported its export: the layers, and where Find Parts split the object, which
    layers its parts are and the matte of the whole object."""
    text = f"done: {len(layers)} layers in the compositor ({', '.join(layers)})"
    if parts is None or parts[0] < 2:
        return text
    found = ", ".join([f"{layers[1]} (the largest)", *layers[2:]])  # the search numbers the parts largest first
    return f"{text}; {progress.split_text(parts[0])}: {found}, together the {P.FOREGROUNDS_MATTE} matte"


class NEURALATLAS_OT_fit(EngineJobOperator, bpy.types.Operator):
    """Fit layered neural atlases to the clip with the engine, then import the result"""

    bl_idname = "neural_atlas.fit"
    bl_label = "Fit Atlas"
    # its import is one undo step, pushed when it finishes (the driver's docstring)
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012 (Blender reads a set)

    # hidden: a visible property would give Adjust Last Operation, which undoes the import and runs the fit again
    resume: BoolProperty(
        name="Resume", default=False, options={"SKIP_SAVE", "HIDDEN"}, description="Continue the stopped fit"
    )
    timeout: _timeout()

    @classmethod
    def poll(cls, context) -> bool:
        # a fit to resume needs no clip (it continues from its checkpoint): the poll cannot tell Fit from Resume
        props = getattr(context.scene, "neural_atlas", None)
        ready = props is not None and (props.clip is not None or props.can_resume)
        return _clip_poll(cls, context, ready, needs.NO_FIT_CLIP)

    def make_job(self, context) -> FitJob:
        props = context.scene.neural_atlas
        python, files = I.engine_python(context), RunFiles(I.run_dir(props))
        clip = None if self.resume else lambda: I.clip_inputs(props, files)
        return FitJob(python, files.run_dir, clip, props.preset, I.sets(props), props.follow_flow)

    def finish(self, context, job: FitJob, result: EP.JobResult) -> set[str]:
        props = context.scene.neural_atlas
        props.log_path = job.log_path
        props.can_resume = job.can_resume()
        if result.status == EP.STATUS_OK and job.manifest:
            try:
                plan = import_manifest(context, job.manifest, action="Fit Atlas")
            except (*IMPORT_ERRORS, RuntimeError) as exc:
                props.status = f"import failed: {exc}"
                self.report({"ERROR"}, f"{props.status} (log: {job.log_path})")
                return {"CANCELLED"}
            props.progress = 1.0
            props.status = props.fit_result = done_text(plan.layers, progress.parts_finding(job.log_path))
            props.can_resume = False
            self.report({"INFO"}, f"Fit Atlas done; imported {job.manifest}")
            return {"FINISHED"}
        props.status = result.message
        level = "WARNING" if result.status == EP.STATUS_CANCELLED else "ERROR"
        self.report({level}, f"Fit Atlas {result.status}: {result.message} (log: {job.log_path})")
        return {"CANCELLED"}


class NEURALATLAS_OT_find_masks(EngineJobOperator, bpy.types.Operator):
    """Find the moving object's masks from its motion and add them as a foreground layer to check before fitting"""

    bl_idname = "neural_atlas.find_masks"
    bl_label = "Find Masks"
    # the layer and the masks clip it adds are one undo step, pushed when it finishes (the driver's docstring)
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012 (Blender reads a set)

    timeout: _timeout()

    @classmethod
    def poll(cls, context) -> bool:
        props = getattr(context.scene, "neural_atlas", None)
        return _clip_poll(cls, context, props is not None and props.clip is not None, needs.NO_MASKS_CLIP)

    def make_job(self, context) -> MasksJob:
        props = context.scene.neural_atlas
        python = I.engine_python(context)
        if props.clip is None:
            raise UserError("choose the clip to find masks in")
        run_dir = I.run_dir(props)
        plate, first_number = I.clip_plate(props.clip)
        first, last = I.clip_range(props)
        return MasksJob(python, run_dir, plate, *F.plate_numbers(first, last, props.clip.frame_start, first_number))

    def finish(self, context, job: MasksJob, result: EP.JobResult) -> set[str]:
        props = context.scene.neural_atlas
        props.log_path = job.log_path
        problem = self._problem(job, result)
        if problem is not None:
            level, props.status, report = problem
            self.report({level}, f"{report} (log: {job.log_path})")
            return {"CANCELLED"}
        files = job.mask_files()
        summary = job.summary or f"{len(files)} masks"
        layer = props.layers.add()
        layer.source = "FOLDER"
        layer.folder = job.out_dir
        props.layer_index = len(props.layers) - 1
        # the masks as a clip of their own, to scrub through in the clip editor (the plate stays the fitted clip)
        check = bpy.data.movieclips.load(files[0], check_existing=False)
        check.name = AUTO_MASKS_CLIP
        check.colorspace_settings.name = "Non-Color"
        props.progress = 1.0
        props.status = f"Find Masks: {summary}; check them (clip {check.name}) before fitting"
        self.report({"INFO"}, f"Find Masks: {summary} -> foreground layer {len(props.layers)} ({job.out_dir})")
        return {"FINISHED"}

    @staticmethod
    def _problem(job: MasksJob, result: EP.JobResult) -> tuple[str, str, str] | None:
        """(report level, status, report) when the search added no layer; masks it wrote are discarded."""
        if result.status == EP.STATUS_CANCELLED:
            job.discard()  # nothing to resume: a search starts over
            status = "Find Masks: cancelled. The layers are unchanged"
            return "WARNING", status, status
        if result.status != EP.STATUS_OK:
            return "ERROR", f"Find Masks: {result.message}", f"Find Masks {result.status}: {result.message}"
        files = job.mask_files()
        if not files:
            status = f"Find Masks: the engine wrote no masks to {job.out_dir}"
            return "ERROR", status, status
        if job.found is False:
            job.discard()
            status = f"Find Masks: {job.summary or f'{len(files)} masks'}. The layers are unchanged"
            return "WARNING", status, status
        return None


class NEURALATLAS_OT_estimate(EngineJobOperator, bpy.types.Operator):
    """Time a few steps of every preset on this clip with the engine (replaces the documented estimate)"""

    bl_idname = "neural_atlas.estimate"
    bl_label = "Estimate Time"
    # no UNDO: it measures, and only the panel's estimate line changes (an undo step would take back a measurement,
    # not an edit)
    bl_options = {"REGISTER"}  # noqa: RUF012 (Blender reads a set)

    timeout: _timeout()

    @classmethod
    def poll(cls, context) -> bool:
        props = getattr(context.scene, "neural_atlas", None)
        return _clip_poll(cls, context, props is not None and props.clip is not None, needs.NO_ESTIMATE_CLIP)

    def make_job(self, context) -> EstimateJob:
        props = context.scene.neural_atlas
        python, files = I.engine_python(context), RunFiles(I.run_dir(props))
        return EstimateJob(python, files.run_dir, I.clip_inputs(props, files, with_scribbles=False), I.sets(props))

    def finish(self, context, job: EstimateJob, result: EP.JobResult) -> set[str]:
        props = context.scene.neural_atlas
        if result.status != EP.STATUS_OK:
            props.status = f"estimate {result.status}: {result.message}"
            self.report({"ERROR"}, f"{props.status} (log: {job.log_path})")
            return {"CANCELLED"}
        props.estimate_json = json.dumps(job.rows)
        props.status = estimate.estimate_text(props.preset, job.rows, 0.0)
        self.report({"INFO"}, props.status)
        return {"FINISHED"}


class NEURALATLAS_OT_cancel(bpy.types.Operator):
    """Stop the engine; a fit writes a checkpoint that Resume continues from"""

    bl_idname = "neural_atlas.cancel"
    bl_label = "Cancel"
    # no UNDO: it stops a process; the job's operator reports the end (an undo cannot restart an engine)
    bl_options = {"REGISTER"}  # noqa: RUF012 (Blender reads a set)

    @classmethod
    def poll(cls, context) -> bool:
        return needs.poll(cls, needs.cancel_need(context.scene is not None and running.is_running(context.scene.name)))

    def execute(self, context):
        job = running.get(context.scene.name)
        if job is None:  # poll says so; this holds for a call that skips poll
            context.scene.neural_atlas.running = False
            return {"CANCELLED"}
        job.cancel()
        context.scene.neural_atlas.status = job.cancel_text
        return {"FINISHED"}


classes = (NEURALATLAS_OT_fit, NEURALATLAS_OT_find_masks, NEURALATLAS_OT_estimate, NEURALATLAS_OT_cancel)
