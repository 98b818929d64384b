"""The contract between the engine and the Blender add-on. Standard library only.

The add-on may import this module and nothing else of ``engine``: CLI verbs and exit codes, the run
folder's file names, the JSON progress lines the engine prints, and the pinned requirements the add-on's
"Set up engine" installs. Anything that crosses the process boundary is named here, once.
"""

from __future__ import annotations

import json
from typing import Any

ENGINE_VERSION = "0.1.0"

#: Version of every JSON file the engine writes (config, metrics, checkpoints' metadata, progress lines).
SCHEMA_VERSION = 1

#: Pinned requirements of the engine's Python (listed once; run.sh and the add-on install these).
#: torch is pinned exactly: an unpinned torch pulls a multi-GB CUDA build on machines without a GPU;
#: numpy<2 because bpy 4.5/5.0 require it; OpenImageIO 3.0.x because 3.1+ forces numpy 2.
ENGINE_REQUIREMENTS: tuple[str, ...] = (
    "torch==2.13.0",
    "numpy>=1.26,<2",
    "openimageio==3.0.*",
    "OpenEXR==3.5.*",
    "opencv-python-headless>=4.9,<4.12",
    "av>=12",
    "tqdm>=4.66",
)

#: Extra requirements for development and the test suite (same venv).
DEV_REQUIREMENTS: tuple[str, ...] = (
    "pytest>=8",
    "hypothesis>=6.100",
    "ruff>=0.6",
    "matplotlib>=3.8",
    "bpy==4.5.*",  # Blender as a module, for the add-on tests (4.5 LTS; needs numpy<2)
)

# --- CLI -----------------------------------------------------------------------------------------------
CLI_MODULE = "engine"  # run as: python -m engine <verb> ...
VERB_FIT = "fit"
VERB_DEMO = "demo"
VERB_SPEED = "speed"

EXIT_OK = 0
EXIT_FAILED = 1  # an engine bug or an unexpected error: the log has the traceback
EXIT_BAD_INPUT = 2  # the user's input is wrong: one line on stderr names the file and the fix
EXIT_CANCELLED = 3  # SIGINT/SIGTERM: a checkpoint was written, `fit --resume` continues

# --- run folder ------------------------------------------------------------------------------------------
RUN_CONFIG = "config.json"
RUN_METRICS = "metrics.json"
RUN_CHECKPOINT = "checkpoint.pt"
RUN_CLIP = "clip.json"  # what was fitted: source, frame range, sizes, content fingerprint
RUN_LOG = "fit.log"
FLOW_CACHE_DIR = "flow_cache"

# --- progress protocol: one JSON object per stdout line ---------------------------------------------------
PROGRESS_TAG = "neural_atlas"  # every machine-readable line carries {"neural_atlas": SCHEMA_VERSION, ...}
EVENT_STAGE = "stage"  # {"stage": "flow"|"init"|"train"|"evaluate", "message": str}
EVENT_PROGRESS = "progress"  # step, total, psnr, elapsed, eta, losses{}
EVENT_CHECKPOINT = "checkpoint"  # step, path
EVENT_DONE = "done"  # metrics{}
EVENT_CANCELLED = "cancelled"  # step, checkpoint
EVENT_ERROR = "error"  # message, log
EVENTS = (EVENT_STAGE, EVENT_PROGRESS, EVENT_CHECKPOINT, EVENT_DONE, EVENT_CANCELLED, EVENT_ERROR)


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
