"""The progress protocol: one JSON object per stdout line, which the add-on, a farm and a script read while a
verb runs."""

from __future__ import annotations

import json
from typing import Any

from .versions import SCHEMA_VERSION

PROGRESS_TAG = "neural_atlas"  # every machine-readable line carries {"neural_atlas": SCHEMA_VERSION, ...}
EVENT_STAGE = "stage"  # {"stage": "flow"|"init"|"train"|"evaluate"|"parts", "message": str}
#: The parts search's finding, on its "parts" stage message once it has searched: how many parts that move apart it
#: split the one object into (0: it moves as one piece, fitted as one layer). The looking message has none.
STAGE_PARTS_FIELD = "parts"
EVENT_PROGRESS = "progress"  # step, total, psnr, elapsed, eta, losses{}; optional job_fraction, job_eta
EVENT_CHECKPOINT = "checkpoint"  # step, path
EVENT_DONE = "done"  # metrics{}; job_fraction 1.0 and job_eta 0.0 (the fit's last message: its job is done)
EVENT_CANCELLED = "cancelled"  # step, checkpoint
EVENT_ERROR = "error"  # message, log
EVENT_EXPORTED = "exported"  # manifest (absolute path of the manifest.json an export wrote)
EVENT_MASKS = "masks"  # found (bool: a moving object was found), folder, message: what `engine masks` did
#: paths: [str], what a verb wrote (export: the manifest; render: the folder; preview: the files; ...), its last
#: message. The same paths follow it as plain lines, one per line, the last lines of stdout (a shell's `tail -n 1`).
EVENT_WRITTEN = "written"
#: How far the whole command is, at every stage (a reader that does not know it skips it as noise):
#: stage ("flow", "train", "evaluate", "export", "estimate"), done and total (the stage's pairs, steps or frames),
#: stage_eta (seconds left in the stage, or null), job_fraction (0..1 of the whole job, never decreasing, a resumed
#: fit's starting where its checkpoint is) and job_eta (seconds left in the whole job, or null while a stage's cost is
#: not measured yet). A fit's job is flow, training, evaluation and the export that follows it: its ``progress`` and
#: ``job`` messages leave the export's share (the add-on shows fit and export as one bar), and its ``done`` closes it
#: at 1.0. Every command that sends fractions ends at 1.0: a fit's ``done``, an export's last ``job``.
EVENT_JOB = "job"
JOB_STAGES = ("flow", "train", "evaluate", "export", "estimate")
EVENTS = (
    EVENT_STAGE,
    EVENT_PROGRESS,
    EVENT_CHECKPOINT,
    EVENT_DONE,
    EVENT_CANCELLED,
    EVENT_ERROR,
    EVENT_EXPORTED,
    EVENT_MASKS,
    EVENT_JOB,
    EVENT_WRITTEN,
)
#: Set (to anything but "") in the environment of every task of an OpenJD bundle (``farm openjd``'s job environment):
#: each verb then also prints its progress as the stdout messages an Open Job Description runner reads (Deadline
#: Cloud's task progress and status): ``openjd_progress: <0..100>`` from the messages' job_fraction (or the command's
#: own steps), ``openjd_status: <message>`` per stage, and ``openjd_progress: 100.0`` as the last line of a verb that
#: succeeded (after the paths it prints).
OPENJD_PROGRESS_ENV = "NEURAL_ATLAS_OPENJD_PROGRESS"


def progress_line(event: str, **fields: Any) -> str:
    """Encode one progress message as a single JSON line (no newline inside)."""
    if event not in EVENTS:
        raise ValueError(f"unknown progress event {event!r}; expected one of {EVENTS}")
    return json.dumps({PROGRESS_TAG: SCHEMA_VERSION, "event": event, **fields}, separators=(",", ":"))


def parse_progress_line(line: str) -> dict[str, Any] | None:
    """Decode a stdout line; None for anything that is not one of our messages (tqdm, warnings, ...)."""
    line = line.strip()
    if not line.startswith("{"):
        return None
    try:
        msg = json.loads(line)
    except json.JSONDecodeError:
        return None
    if not isinstance(msg, dict) or msg.get(PROGRESS_TAG) != SCHEMA_VERSION or msg.get("event") not in EVENTS:
        return None
    return msg


#: What ``engine.contract`` re-exports from this module (its own names, not its imports).
__all__ = [
    "EVENTS",
    "EVENT_CANCELLED",
    "EVENT_CHECKPOINT",
    "EVENT_DONE",
    "EVENT_ERROR",
    "EVENT_EXPORTED",
    "EVENT_JOB",
    "EVENT_MASKS",
    "EVENT_PROGRESS",
    "EVENT_STAGE",
    "EVENT_WRITTEN",
    "JOB_STAGES",
    "OPENJD_PROGRESS_ENV",
    "PROGRESS_TAG",
    "STAGE_PARTS_FIELD",
    "parse_progress_line",
    "progress_line",
]
