"""What the engine's progress lines say: the state a progress bar shows while a command runs, and the events a
finished command left in its log. No bpy here.

The engine prints one JSON object per stdout line for each event (``engine.contract``: stage, progress,
checkpoint, done, cancelled, error, exported, masks); every other line (tqdm, warnings) is noise for the log.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ...engine import contract as C  # type: ignore[import-not-found]

#: Lines of stderr kept in memory for the report (the full text is in the log).
STDERR_TAIL_LINES = 20


@dataclass
class JobState:
    """What the progress bar shows; ``apply`` updates it from each message as it arrives."""

    #: how far it is: step of total, the latest PSNR (dB), the seconds it expects to need still
    step: int = 0
    total: int = 0
    psnr: float | None = None
    eta: float | None = None
    #: the engine's stage ("flow", "train", ...) and what it says about it
    stage: str = ""
    message: str = ""
    #: what it has written: the export's manifest, the fit's metrics; or what went wrong
    manifest: str | None = None
    metrics: dict[str, Any] | None = None
    error: str | None = None
    #: the whole job (``contract.EVENT_JOB``, and the ``job_*`` fields of ``progress``; None from an engine that
    #: does not send them): its fraction (never decreasing) and seconds left, and the running stage's count and
    #: seconds left (flow pairs, training steps, evaluation, export frames)
    job_fraction: float | None = None
    job_eta: float | None = None
    job_stage: str = ""
    stage_done: int = 0
    stage_total: int = 0
    stage_eta: float | None = None
    #: the parts search's finding (``contract.STAGE_PARTS_FIELD``: how many parts the object was split into, 0: none;
    #: None before it has searched) and its message
    parts: int | None = None
    parts_message: str = ""
    #: the last stdout line that is no progress message (pip's "Collecting ...", the path `export` prints)
    last_stdout: str = ""
    stderr_tail: list[str] = field(default_factory=list)

    @property
    def fraction(self) -> float:
        """The whole job's fraction where the engine sends it, else the training steps'."""
        if self.job_fraction is not None:
            return min(1.0, max(0.0, self.job_fraction))
        return min(1.0, self.step / self.total) if self.total > 0 else 0.0

    def apply(self, msg: dict[str, Any]) -> None:
        event = msg["event"]
        if event == C.EVENT_STAGE:
            self.stage = str(msg.get("stage", ""))
            self.message = str(msg.get("message", self.stage))
            if self.stage == C.VERB_PARTS:
                self.parts_message = self.message
                if C.STAGE_PARTS_FIELD in msg:
                    self.parts = int(msg[C.STAGE_PARTS_FIELD])
        elif event == C.EVENT_PROGRESS:
            self.step = int(msg.get("step", self.step))
            self.total = int(msg.get("total", self.total))
            self.psnr = msg.get("psnr", self.psnr)
            self.eta = msg.get("eta", self.eta)
            self._apply_job(msg)
        elif event == C.EVENT_JOB:
            self.job_stage = str(msg.get("stage", self.job_stage))
            self.stage_done = int(msg.get("done", self.stage_done))
            self.stage_total = int(msg.get("total", self.stage_total))
            self.stage_eta = msg.get("stage_eta")
            if self.job_stage == "train":  # the step count moves between the live-PSNR steps too
                self.step, self.total = self.stage_done, self.stage_total
                self.eta = self.stage_eta
            self._apply_job(msg)
        elif event == C.EVENT_DONE:
            self.metrics = msg.get("metrics")
        elif event == C.EVENT_ERROR:
            self.error = str(msg.get("message", "engine error"))
        elif event == C.EVENT_EXPORTED:
            self.manifest = msg.get("manifest", self.manifest)

    def _apply_job(self, msg: dict[str, Any]) -> None:
        if "job_fraction" in msg and msg["job_fraction"] is not None:
            self.job_fraction = max(float(msg["job_fraction"]), self.job_fraction or 0.0)
        if "job_eta" in msg:
            self.job_eta = msg["job_eta"]

    def note_stderr(self, line: str) -> None:
        """Keep the last STDERR_TAIL_LINES non-empty stderr lines (a progress bar's ``\\r`` redraws are skipped)."""
        if line.strip() and "\r" not in line:
            self.stderr_tail.append(line.strip())
            del self.stderr_tail[:-STDERR_TAIL_LINES]

    def summary(self, whole: str = "job") -> str:
        """One line for the progress bar: where the job is (flow pairs, training step and PSNR, evaluation, export
        frames) and its ETA, saying what the ETA covers: ``whole`` ("fit": flow, training, evaluation, export),
        or only the running stage while the whole job's is not measured yet."""
        stage = self.job_stage
        flow_done = stage == "flow" and 0 < self.stage_total <= self.stage_done
        if self.stage == C.VERB_PARTS and stage in ("", "flow"):  # looking for parts, or what it found
            return self.parts_message
        if flow_done and self.stage not in ("", "flow") and self.total == 0:
            text = self.message  # after the flow, before the first step: what the engine says it does
        elif stage == "flow":
            text = f"optical flow {self.stage_done}/{self.stage_total}"
        elif stage == "evaluate":
            text = "evaluating every pixel"
        elif stage == "export":
            text = f"exporting passes {self.stage_done}/{self.stage_total}"
        elif stage == "estimate":
            text = f"timing the presets {self.stage_done}/{self.stage_total}"
        elif self.total > 0:
            text = f"step {self.step}/{self.total}"
            if self.psnr is not None:
                text += f" · {self.psnr:.1f} dB"
        else:
            return self.message or self.stage or "starting…"
        if self.job_eta is not None:
            text += f" · ETA {format_seconds(self.job_eta)} for the whole {whole}"
        elif self.job_fraction is not None and self.stage_eta is not None:
            what = {"train": "training", "evaluate": "evaluation"}.get(stage, f"the {stage}")
            text += f" · ETA {format_seconds(self.stage_eta)} for {what}"
        elif self.job_fraction is None and self.eta is not None:
            text += f" · ETA {format_seconds(self.eta)}"  # an engine without whole-job estimates: training's
        if self.parts is not None and self.parts >= 2:
            text += f" · {split_text(self.parts)}"
        return text


def split_text(parts: int) -> str:
    """What the status line says of a split: the object fitted as ``parts`` layers."""
    return f"Find Parts: the object split into {parts} parts that move apart"


def parts_finding(log_path: str) -> tuple[int, str] | None:
    """The parts search's last finding in a fit's log (a resumed fit's too: its log goes on): (parts, its message);
    None when the fit did not search."""
    found = None
    for msg in logged_events(log_path, C.EVENT_STAGE):
        if msg.get("stage") == C.VERB_PARTS and C.STAGE_PARTS_FIELD in msg:
            found = (int(msg[C.STAGE_PARTS_FIELD]), str(msg.get("message", "")))
    return found


def format_seconds(seconds: float) -> str:
    """``3h05m``, ``1m35s`` or ``42s``."""
    whole = max(0, round(float(seconds)))
    h, rem = divmod(whole, 3600)
    m, s = divmod(rem, 60)
    return f"{h}h{m:02d}m" if h else (f"{m}m{s:02d}s" if m else f"{s}s")


def logged_events(log_path: str, event: str) -> list[dict[str, Any]]:
    """Every progress message of kind ``event`` in a log the add-on wrote (the engine's stdout is copied there);
    [] when the log cannot be read."""
    found = []
    try:
        with open(log_path, encoding="utf-8", errors="replace") as f:
            for line in f:
                msg = C.parse_progress_line(line)
                if msg is not None and msg.get("event") == event:
                    found.append(msg)
    except OSError:
        return []
    return found


def read_log(log_path: str) -> str:
    """A log's text ('' when it cannot be read)."""
    try:
        with open(log_path, encoding="utf-8", errors="replace") as f:
            return f.read()
    except OSError:
        return ""
