"""The one driver of engine jobs (``core.jobs``): Fit Atlas, Find Masks, Estimate Time and Set up engine.

The pattern of Blender's own extension manager (bl_pkg): the child process speaks JSON lines, and the operator
polls it on a timer. ``invoke`` (the UI) is modal: a timer event every ``POLL_SECONDS`` steps the job and
redraws the panel; only the Cancel button stops it. ESC passes through (it stops playback, leaves paint mode, closes
menus: the artist pressing it means that, not the end of an hour's fit) with one line, once, saying where Cancel is.
``execute`` (background mode, scripts, tests, and ``invoke`` where there is no event loop) blocks, stepping the job
in a loop. Either way the job is in the ``core.running`` table while it runs, and the subclass's ``finish`` reads
its result.

Undo: an operator whose ``finish`` changes the scene (Fit Atlas imports, Find Masks adds a layer) has
``{'REGISTER', 'UNDO'}``; Blender pushes its undo step when ``modal`` returns FINISHED, after the result is in
the scene, so Ctrl+Z takes back that import as one step (the run folder on disk stays; Import Atlas brings it
back) instead of folding it into the artist's next step. Nothing it runs is ever repeated by Blender: its
properties are hidden (no Adjust Last Operation panel, whose change would undo and run ``execute``: a blocking
fit), and Repeat Last is refused (``execute`` would block the UI for the whole job).
"""

from __future__ import annotations

from typing import Any

import bpy

from ..core import engine_process as EP
from ..core import needs, running
from ..core.errors import UserError
from ..core.jobs import Job


class EngineJobOperator:
    """Mixin for an operator that runs an engine job. Subclasses make the job, show its progress, finish it."""

    #: Seconds the blocking path waits before cancelling the job; 0: no limit (the operators' ``timeout``).
    timeout: float = 0.0
    #: The areas redrawn while the job runs.
    redraw_areas: tuple[str, ...] = ("CLIP_EDITOR", "PROPERTIES")
    #: Where the Cancel button of this job is (what ESC's line points to).
    cancel_where = "the Fit Atlas panel (Movie Clip Editor sidebar)"
    _timer: Any = None
    _job: Job | None = None
    _esc_said = False

    # --- what a subclass provides ---------------------------------------------------------------------------
    def make_job(self, context: Any) -> Job:
        """The job (not started); raises UserError with what the artist can fix."""
        raise NotImplementedError

    @classmethod
    def job_key(cls, context: Any) -> str:
        """What the job runs for in ``core.running``: one job at a time per key (the scene's name)."""
        return context.scene.name

    @classmethod
    def poll(cls, context: Any) -> bool:
        # the live job, not the saved flag: a .blend saved during a fit must not block the next one
        return context.scene is not None and not running.is_running(cls.job_key(context))

    def show(self, context: Any, job: Job) -> None:
        """Put the job's progress where the artist sees it (called after every step)."""
        props = context.scene.neural_atlas
        props.progress = job.fraction
        props.status = job.status_text()

    def set_running(self, context: Any, on: bool) -> None:
        context.scene.neural_atlas.running = on

    def finish(self, context: Any, job: Job, result: EP.JobResult) -> set[str]:
        """Report the result and apply it to the scene; the operator's return value."""
        raise NotImplementedError

    # --- the driver ------------------------------------------------------------------------------------------
    def execute(self, context: Any) -> set[str]:
        options = getattr(self, "options", None)
        if options is not None and (options.is_repeat or options.is_repeat_last):
            self.report({"WARNING"}, f"{self.bl_label} is not repeated: press its button (it runs with progress)")
            return {"CANCELLED"}
        job = self._begin(context)
        if job is None:
            return {"CANCELLED"}
        try:
            EP.run_blocking(job, self.timeout or None, lambda: self.show(context, job))
        finally:
            self.set_running(context, False)
        return self._end(context, job)

    def invoke(self, context: Any, event: Any) -> set[str]:
        if bpy.app.background:
            return self.execute(context)  # no event loop: the blocking path
        job = self._begin(context)
        if job is None:
            return {"CANCELLED"}
        self._job = job
        wm = context.window_manager
        self._timer = wm.event_timer_add(EP.POLL_SECONDS, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context: Any, event: Any) -> set[str]:
        job = self._job
        assert job is not None
        if event.type == "ESC" and not self._esc_said:
            self._esc_said = True  # said once: ESC pressed to stop playback again and again needs no more lines
            self.report({"INFO"}, needs.esc_text(self.bl_label, self.cancel_where))
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        more = job.step()
        self.show(context, job)
        for window in context.window_manager.windows:
            for area in window.screen.areas:
                if area.type in self.redraw_areas:
                    area.tag_redraw()
        if more:
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self._timer)
        return self._end(context, job)

    def _begin(self, context: Any) -> Job | None:
        """Make, register and start the job; None (reported) when it cannot start."""
        try:
            job = self.make_job(context)
            running.add(self.job_key(context), job)
        except (UserError, RuntimeError, OSError) as exc:
            self.fail(context, str(exc))
            return None
        self.set_running(context, True)
        try:
            job.start()
        except OSError as exc:
            self._forget(context)
            self.fail(context, f"cannot start: {exc}")
            return None
        return job

    def _end(self, context: Any, job: Job) -> set[str]:
        self._forget(context)
        assert job.result is not None
        return self.finish(context, job, job.result)

    def _forget(self, context: Any) -> None:
        running.remove(self.job_key(context))
        self.set_running(context, False)

    def fail(self, context: Any, message: str) -> None:
        """An error the artist sees in the panel and as a report."""
        context.scene.neural_atlas.status = message
        self.report({"ERROR"}, message)
