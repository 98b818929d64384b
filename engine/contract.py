"""The contract between the engine and the Blender add-on: what crosses the process boundary. Standard library only.

The add-on may import this module and nothing else of ``engine`` (``from ..engine import contract as C``, then
``C.NAME``). It names, explicitly, each term the add-on uses: the CLI verbs, flags and exit codes it runs the engine
with, the run folder's and the export's file names it reads, the manifest it loads, the JSON progress lines it parses,
the run folder's lock, the shots file it writes for a farm, and the requirements (with their exact versions) its
"Set up engine" installs. Each term is defined in its subject module of ``engine/terms/`` (standard library only too),
where the engine's own code takes the terms that stay inside the engine. ``__all__`` is this list;
tests/contract/test_boundaries.py checks it against what the add-on reaches through it, both ways.
"""

from __future__ import annotations

from pathlib import Path

# the command line: the module python -m runs, the verbs and flags the add-on passes, the presets' step budgets, the
# exit codes it reads
from .terms.cli import (
    CLI_MODULE,
    ESTIMATE_TAG,
    EXIT_BAD_INPUT,
    EXIT_CANCELLED,
    EXIT_OK,
    EXPORT_NO_FOLLOW_FLOW_FLAG,
    FIT_REFINE_FLAG,
    PRESET_CLIP_FRAMES,
    PRESET_STEPS,
    RELINK_PLATE_ARG,
    VERB_ESTIMATE,
    VERB_EXPORT,
    VERB_FIT,
    VERB_MASKS,
    VERB_PARTS,
    VERB_PROJECT_FRAME,
    VERB_REALIGN,
    VERB_RELINK,
)

# the clip: its kinds, frame file numbers, rate and working size; masks and scribbles as the add-on draws them
from .terms.clip import (
    CLIP_KINDS,
    DEFAULT_LONG_EDGE,
    FRAME_FILE_DIGITS,
    MASK_THRESHOLD,
    SCRIBBLE_ARG,
    SCRIBBLE_COLOURS,
    SCRIBBLE_FILE_FORMAT,
    SCRIBBLE_TOLERANCE,
    clip_rate,
    sequence_pattern_of,
    working_size,
)

# colour: the colour spaces the records name, and the sRGB transfer
from .terms.colour import COLOUR_RAW, COLOUR_SCENE_LINEAR, COLOUR_SRGB, LEGACY_COLORSPACES, srgb_to_linear

# an export's names the add-on opens: the exports folder, the foreground role, the UV channels, edit layer files;
# and the padding of the frame numbers in the names of outputs numbered by the plate's frames (Render Edited Clip's
# frames, padded as engine render pads them)
from .terms.export_names import (
    EDIT_LAYER_FLOAT_EXT,
    EXPORTS_DIR,
    RENDER_FRAME_PREFIX,
    ROLE_FOREGROUND,
    UV_CHANNELS,
    channel_name,
    edit_layer_file,
    float_edit_layer,
    frame_padding,
)

# the farm: the back ends the add-on submits to and the shots file it writes
from .terms.farm import (
    FARM_FLAMENCO,
    FARM_OPENJD,
    SHOT_KEYS,
    SHOT_NAME_MAX,
    SHOTS_DEFAULTS_KEY,
    SHOTS_LIST_KEY,
    SHOTS_TAG,
    SHOTS_VERSION,
    VERB_FARM,
)

# the run folder's lock: the add-on holds it while it writes into a run folder, and names a busy one
from .terms.lock import RunLocked, run_lock

# the manifest: its file name, loading and checking it
from .terms.manifest import MANIFEST_NAME, ManifestError, load_manifest

# the paths a manifest names, resolved and checked (the plate, the run folder, where edits are written)
from .terms.paths import (
    manifest_run_root,
    read_aligned_export,
    resolve_manifest_path,
    resolve_manifest_write_path,
    resolve_plate_path,
)

# the progress lines the engine prints, as the add-on parses them
from .terms.protocol import (
    EVENT_DONE,
    EVENT_ERROR,
    EVENT_EXPORTED,
    EVENT_JOB,
    EVENT_MASKS,
    EVENT_PROGRESS,
    EVENT_STAGE,
    STAGE_PARTS_FIELD,
    parse_progress_line,
)

# the run folder's files and flags the add-on reads or passes
from .terms.run_folder import AUTO_MASKS_DIR, FIT_NO_AUTO_PARTS_FLAG, RUN_CHECKPOINT, RUN_METRICS

#: The requirement files beside this module (shipped in the wheel and the extension), each read once here. Ranges:
#: the engine's and the farm extra's (pyproject.toml takes its dependencies from the same two files). Exact versions:
#: the constraints file every install here uses (``pip install -r ... -c constraints.txt``).
REQUIREMENTS_FILE = "requirements.txt"
FARM_REQUIREMENTS_FILE = "requirements-farm.txt"
CONSTRAINTS_FILE = "constraints.txt"
CONSTRAINTS_PATH = Path(__file__).with_name(CONSTRAINTS_FILE)


def requirement_lines(name: str) -> tuple[str, ...]:
    """The requirements of one of the files beside this module: its lines less blanks and ``#`` comments (the rule
    setuptools applies to the same files)."""
    text = Path(__file__).with_name(name).read_text(encoding="utf-8")
    return tuple(s for s in (line.strip() for line in text.splitlines()) if s and not s.startswith("#"))


#: The engine's requirements (compatible ranges), which the add-on's Set up engine installs with the constraints.
ENGINE_REQUIREMENTS: tuple[str, ...] = requirement_lines(REQUIREMENTS_FILE)
#: The farm back ends' own requirements (the wheel's ``farm`` extra; the test venv has them).
FARM_REQUIREMENTS: tuple[str, ...] = requirement_lines(FARM_REQUIREMENTS_FILE)

#: What crosses: every term above and this module's requirements.
__all__ = [
    "AUTO_MASKS_DIR",
    "CLIP_KINDS",
    "CLI_MODULE",
    "COLOUR_RAW",
    "COLOUR_SCENE_LINEAR",
    "COLOUR_SRGB",
    "CONSTRAINTS_FILE",
    "CONSTRAINTS_PATH",
    "DEFAULT_LONG_EDGE",
    "EDIT_LAYER_FLOAT_EXT",
    "ENGINE_REQUIREMENTS",
    "ESTIMATE_TAG",
    "EVENT_DONE",
    "EVENT_ERROR",
    "EVENT_EXPORTED",
    "EVENT_JOB",
    "EVENT_MASKS",
    "EVENT_PROGRESS",
    "EVENT_STAGE",
    "EXIT_BAD_INPUT",
    "EXIT_CANCELLED",
    "EXIT_OK",
    "EXPORTS_DIR",
    "EXPORT_NO_FOLLOW_FLOW_FLAG",
    "FARM_FLAMENCO",
    "FARM_OPENJD",
    "FARM_REQUIREMENTS",
    "FARM_REQUIREMENTS_FILE",
    "FIT_NO_AUTO_PARTS_FLAG",
    "FIT_REFINE_FLAG",
    "FRAME_FILE_DIGITS",
    "LEGACY_COLORSPACES",
    "MANIFEST_NAME",
    "MASK_THRESHOLD",
    "PRESET_CLIP_FRAMES",
    "PRESET_STEPS",
    "RELINK_PLATE_ARG",
    "RENDER_FRAME_PREFIX",
    "REQUIREMENTS_FILE",
    "ROLE_FOREGROUND",
    "RUN_CHECKPOINT",
    "RUN_METRICS",
    "SCRIBBLE_ARG",
    "SCRIBBLE_COLOURS",
    "SCRIBBLE_FILE_FORMAT",
    "SCRIBBLE_TOLERANCE",
    "SHOTS_DEFAULTS_KEY",
    "SHOTS_LIST_KEY",
    "SHOTS_TAG",
    "SHOTS_VERSION",
    "SHOT_KEYS",
    "SHOT_NAME_MAX",
    "STAGE_PARTS_FIELD",
    "UV_CHANNELS",
    "VERB_ESTIMATE",
    "VERB_EXPORT",
    "VERB_FARM",
    "VERB_FIT",
    "VERB_MASKS",
    "VERB_PARTS",
    "VERB_PROJECT_FRAME",
    "VERB_REALIGN",
    "VERB_RELINK",
    "ManifestError",
    "RunLocked",
    "channel_name",
    "clip_rate",
    "edit_layer_file",
    "float_edit_layer",
    "frame_padding",
    "load_manifest",
    "manifest_run_root",
    "parse_progress_line",
    "read_aligned_export",
    "requirement_lines",
    "resolve_manifest_path",
    "resolve_manifest_write_path",
    "resolve_plate_path",
    "run_lock",
    "sequence_pattern_of",
    "srgb_to_linear",
    "working_size",
]
