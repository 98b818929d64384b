"""The engine jobs the operators drive: one state machine for all of them. No bpy here.

A job runs its commands one after another into one log, each only once the one before succeeded, and is
driven by ``start()`` then ``step()`` until it returns False (from a modal operator's timer in the UI, or by
``engine_process.run_blocking`` in background mode); ``cancel()`` stops the running command. Its ``result``
is then the last command's, as each kind of job reads it:

- ``FitJob``: ``engine fit`` (or ``fit --resume``), then ``engine export``; the result names the manifest.
- ``RefineJob``: ``engine fit --refine``, ``engine export``, then ``engine realign`` (the paint carried over).
- ``MasksJob``: ``engine masks`` into a fresh folder; what it found comes from the log's ``masks`` event.
- ``EstimateJob``: ``engine estimate --json``; the rows per preset come from the log.
- ``CarryJob``: ``engine realign --from`` another fit of the plate, measured; how much paint landed from the log.
- ``engine_setup.SetupJob``: create the engine's environment, then pip-install its requirements.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass

from ...engine import contract as C  # type: ignore[import-not-found]
from . import engine_commands as EC
from . import engine_process as EP
from . import estimate, progress
from .errors import UserError
from .run_files import RunFiles, png_files


@dataclass(frozen=True)
class Command:
    """One engine command of a job: what the status line calls it, and its argv."""

    label: str
    argv: list[str]


class Job:
    """Commands run in turn into ``log_path``; ``result`` once ``step()`` has returned False."""

    #: what the status line says before the first progress message, and once Cancel was pressed
    idle_text = "starting…"
    cancel_text = "cancelling…"
    #: what the whole-job ETA covers, as the status line names it ("ETA 3m10s for the whole fit")
    whole = "job"

    def __init__(
        self, commands: list[Command], log_path: str, env: dict[str, str] | None = None, keep_log: bool = False
    ):
        self.commands = commands
        self.log_path = log_path
        self.env = env
        #: append to the log (a resumed fit continues its log) instead of starting it afresh
        self.keep_log = keep_log
        self.index = -1
        self.process: EP.EngineJob | None = None
        self.result: EP.JobResult | None = None
        self.cancelling = False

    @property
    def label(self) -> str:
        """The running command's label ('' before the start)."""
        return self.commands[self.index].label if 0 <= self.index < len(self.commands) else ""

    @property
    def state(self) -> progress.JobState:
        return self.process.state if self.process is not None else progress.JobState()

    @property
    def fraction(self) -> float:
        return self.state.fraction

    def start(self) -> None:
        os.makedirs(os.path.dirname(self.log_path) or ".", exist_ok=True)
        if not self.keep_log and os.path.exists(self.log_path):
            os.remove(self.log_path)  # the add-on's own log of the previous run
        self._run(0)

    def step(self) -> bool:
        """Poll; start the next command when one succeeds. True while there is more to do."""
        if self.result is not None:
            return False
        assert self.process is not None, "start() the job first"
        if self.process.step():
            return True
        result = self.process.result()
        if result.status == EP.STATUS_OK and self.index + 1 < len(self.commands):
            self._run(self.index + 1)
            return True
        self.result = self.finish(result)
        return False

    def cancel(self) -> None:
        self.cancelling = True
        if self.process is not None:
            self.process.cancel()

    def status_text(self) -> str:
        if self.cancelling:
            return self.cancel_text
        if self.process is None:
            return self.idle_text
        st = self.state
        return st.summary(self.whole) if st.total or st.job_stage else (st.message or self.idle_text)

    def finish(self, result: EP.JobResult) -> EP.JobResult:
        """The job's result from its last command's (each kind reads what it needs)."""
        return result

    def _run(self, index: int) -> None:
        self.index = index
        self.process = EP.EngineJob(self.commands[index].argv, self.log_path, env=self.env).start()


def _last_fraction(log_path: str) -> float:
    """The whole-job fraction of the last training message in a fit's log (0.0: none)."""
    found = 0.0
    for line in progress.read_log(log_path).splitlines():
        msg = C.parse_progress_line(line)
        if msg is None or msg.get("job_fraction") is None:
            continue
        if msg["event"] == C.EVENT_PROGRESS or (msg["event"] == C.EVENT_JOB and msg.get("stage") == "train"):
            found = float(msg["job_fraction"])
    return found


def failed(result: EP.JobResult, message: str) -> EP.JobResult:
    """``result`` turned into a failure saying ``message`` (the command succeeded but did not do its work)."""
    return EP.JobResult(EP.STATUS_FAILED, result.returncode, message, result.log_path)


class FitJob(Job):
    """Fit Atlas: ``engine fit`` (or ``fit --resume``), then ``engine export`` of the run."""

    cancel_text = "cancelling: writing a checkpoint…"
    whole = "fit"

    def __init__(
        self,
        python: str,
        run_dir: str,
        clip: Callable[[], EC.ClipInputs] | None,
        preset: str,
        sets: list[str],
        follow_flow: bool = True,
    ):
        """``clip`` gathers the inputs (rasterising masks and scribbles) once the Run Folder is known to be free;
        None resumes the fit in ``run_dir``. ``follow_flow``: the export's (``EC.export_argv``)."""
        files = RunFiles(run_dir)
        self.run_dir = run_dir
        if clip is None:
            if not files.has_fit():
                raise UserError(f"nothing to resume in {run_dir}")
            fit = EC.resume_argv(python, run_dir)
        else:
            if files.has_fit():
                again = "Refine it" if files.has_finished_fit() else "Resume it"
                raise UserError(f"{run_dir} already holds a fit: {again}, or choose another Run Folder")
            fit = EC.fit_argv(python, clip(), run_dir, preset, sets)
        commands = [Command("fit", fit), Command("export", EC.export_argv(python, run_dir, follow_flow))]
        super().__init__(commands, files.fit_log, EC.engine_env(), keep_log=clip is None)
        self.manifest: str | None = None
        #: a resume's bar starts where the stopped fit's was (its last whole-job fraction in the log), before the
        #: engine has said anything
        self.resumed_from = 0.0 if clip is not None else _last_fraction(files.fit_log)

    def can_resume(self) -> bool:
        return RunFiles(self.run_dir).has_fit()

    #: the fit command's last whole-job fraction (the engine's, which leaves the export's share to it); None before
    #: the export starts, or from an engine that sends no whole-job fraction
    fit_fraction: float | None = None

    @property
    def fraction(self) -> float:
        """The whole fit's: the fit command's own, then the export's frames over the share the fit left to it (an
        engine without whole-job fractions: each command's own steps, as before)."""
        st = self.state
        if self.label == "export" and self.fit_fraction is not None:
            return self.fit_fraction + (1.0 - self.fit_fraction) * (st.job_fraction or 0.0)
        return max(self.resumed_from, st.fraction) if self.label == "fit" else st.fraction

    def status_text(self) -> str:
        if self.label == "export" and not self.cancelling:
            st = self.state
            if st.job_stage == "export":
                return st.summary(self.whole)
            return f"exporting passes {st.step}/{st.total}" if st.total else "exporting passes…"
        return super().status_text()

    def _run(self, index: int) -> None:
        if self.process is not None:
            self.fit_fraction = self.process.state.job_fraction
        super()._run(index)

    def finish(self, result: EP.JobResult) -> EP.JobResult:
        if self.label == "export" and result.status == EP.STATUS_OK:
            self.manifest = result.manifest
            if not self.manifest:
                return failed(result, "export wrote no manifest")
        return result


class RefineJob(FitJob):
    """Refine: ``engine fit --refine`` of the finished fit, ``engine export``, then ``engine realign``, which carries
    the edit layers from the export they were painted on onto the new one; the result names the new manifest."""

    def __init__(self, python: str, run_dir: str, steps: int, preset: str | None = None, follow_flow: bool = True):
        """``steps`` more steps (0: on to ``preset``'s budget); ``preset``: its schedule (None: the fit's own);
        ``follow_flow``: the export's (``EC.export_argv``)."""
        files = RunFiles(run_dir)
        if not files.has_finished_fit():
            raise UserError(f"{run_dir} holds no finished fit to refine (Fit Atlas first, or Resume it)")
        if steps <= 0 and not preset:
            raise UserError("Refine needs a number of steps, or a preset to refine with")
        self.run_dir = run_dir
        commands = [
            Command("fit", EC.refine_argv(python, run_dir, steps, preset)),
            Command("export", EC.export_argv(python, run_dir, follow_flow)),
            Command("realign", EC.realign_argv(python, run_dir)),
        ]
        Job.__init__(self, commands, files.fit_log, EC.engine_env(), keep_log=True)
        self.manifest: str | None = None
        # the bar starts at 0: the finished fit's log ends at 1, and the refine's steps are a new stretch of work
        self.resumed_from = 0.0

    def status_text(self) -> str:
        if self.label == "realign" and not self.cancelling:
            return "carrying the paint over to the refined fit…"
        return super().status_text()

    def finish(self, result: EP.JobResult) -> EP.JobResult:
        if self.label == "realign" and result.status == EP.STATUS_OK:
            self.manifest = result.manifest
            if not self.manifest:
                return failed(result, "realign printed no manifest")
        return result


class MasksJob(Job):
    """Find Masks: ``engine masks PLATE --out RUN/auto_masks --frames A:B`` into a fresh folder."""

    idle_text = "finding what moves…"

    def __init__(self, python: str, run_dir: str, plate: str, first: int, last: int):
        """``first``, ``last``: the plate's frame numbers."""
        if last <= first:
            raise UserError("Find Masks needs at least two frames: the foreground is found by what moves")
        files = RunFiles(run_dir)
        self.out_dir = files.fresh_auto_masks()
        #: the folder is new (``discard`` removes it again)
        self.created = not os.path.exists(self.out_dir)
        argv = EC.masks_argv(python, plate, self.out_dir, first, last)
        super().__init__([Command("masks", argv)], files.masks_log, EC.engine_env())
        #: what the search found (None: the engine ended before saying) and its one-line summary
        self.found: bool | None = None
        self.summary = ""

    def finish(self, result: EP.JobResult) -> EP.JobResult:
        events = progress.logged_events(self.log_path, C.EVENT_MASKS)
        if events:
            self.found, self.summary = bool(events[-1].get("found")), str(events[-1].get("message", ""))
        return result

    def mask_files(self) -> list[str]:
        return png_files(self.out_dir)

    def discard(self) -> None:
        """Remove the (empty) masks this search wrote into its fresh folder, and the folder if it made it."""
        for path in self.mask_files():
            os.remove(path)
        if self.created and os.path.isdir(self.out_dir) and not os.listdir(self.out_dir):
            os.rmdir(self.out_dir)


class EstimateJob(Job):
    """Estimate Time: ``engine estimate --json``, a few timed steps of every preset on this clip."""

    idle_text = "timing the presets…"
    whole = "estimate"

    def __init__(self, python: str, run_dir: str, clip: EC.ClipInputs, sets: list[str]):
        argv = EC.estimate_argv(python, clip, sets)
        super().__init__([Command("estimate", argv)], RunFiles(run_dir).estimate_log, EC.engine_env())
        #: preset -> {"seconds", "psnr", "unavailable"}: the engine's estimate
        self.rows: estimate.EngineRows = {}

    def finish(self, result: EP.JobResult) -> EP.JobResult:
        self.rows = estimate.parse_engine_estimate(progress.read_log(self.log_path), C.ESTIMATE_TAG)
        if result.status == EP.STATUS_OK and not self.rows:
            return failed(result, "the engine printed no estimate")
        return result


class CarryJob(Job):
    """Carry Paint: ``engine realign MANIFEST --from SOURCE --measure`` (``EC.carry_argv``): the paint of another fit of
    the same plate laid onto this fit's edit layers; ``report`` (the engine's measure: ``landed``, ``iou``, the layers
    changed) once it has finished."""

    idle_text = "carrying the paint over…"

    def __init__(self, python: str, manifest: str, source: str, run_dir: str):
        self.manifest, self.source = manifest, source
        argv = EC.carry_argv(python, manifest, source)
        super().__init__([Command("carry", argv)], RunFiles(run_dir).carry_log, EC.engine_env())
        self.report: dict | None = None

    def finish(self, result: EP.JobResult) -> EP.JobResult:
        if result.status == EP.STATUS_OK:
            self.report = carry_report(self.log_path)
            if self.report is None:
                return failed(result, "realign printed no measure")
        return result


def carry_report(log_path: str) -> dict | None:
    """The measure ``realign --measure`` printed (its last JSON line holding ``realigned``); None without one."""
    found = None
    for line in progress.read_log(log_path).splitlines():
        if line.startswith("{") and '"realigned"' in line:
            try:
                found = json.loads(line)
            except ValueError:
                continue
    return found


def carry_text(source: str, report: dict) -> str:
    """The status line once the paint was carried: which layers took it and how much of it landed."""
    done = report.get("realigned", {})
    layers = ", ".join(report.get("layers") or []) or "no layer"
    return (
        f"paint carried from {source}: {done.get('landed', 0.0):.0%} of its pixels landed on this fit "
        f"({layers}; IoU {done.get('iou', 0.0):.2f} over {done.get('frames', 0)} frames)"
    )
