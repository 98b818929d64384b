"""The contract between the engine and the Blender add-on. Standard library only.

The add-on may import this module and nothing else of ``engine``: CLI verbs and exit codes, the run
folder's file names, the JSON progress lines the engine prints, and the requirements (with their exact versions) the
add-on's "Set up engine" installs. Anything that crosses the process boundary is named here, once.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path
from typing import Any

ENGINE_VERSION = "0.1.0"

#: Version of every JSON file the engine writes (config, metrics, checkpoints' metadata, progress lines).
SCHEMA_VERSION = 1

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

#: Extra requirements for development and the test suite (same venv).
DEV_REQUIREMENTS: tuple[str, ...] = (
    "pytest>=8",
    "hypothesis>=6.100",
    "ruff>=0.6",
    "matplotlib>=3.8",
    "bpy==4.5.*",  # Blender as a module, for the add-on tests (4.5 LTS; needs numpy<2)
    "mypy==2.4.1",  # type-checks the modules listed in pyproject.toml ([tool.mypy] files)
)

#: The add-on tests run a second time on Blender 5.0, in a second venv (run.sh's .venv-bpy5): one bpy per
#: interpreter, so these are installed beside .venv's bpy 4.5 rather than into it.
BPY5_REQUIREMENTS: tuple[str, ...] = (
    "bpy==5.0.1",
    "numpy<2",
    "OpenEXR==3.5.*",
    "pytest>=8",
)

# --- CLI -----------------------------------------------------------------------------------------------
#: The import name a pip install of the wheel gives the engine (pyproject.toml maps it onto the repository's engine/):
#: ours, so the engine never takes or meets another project's top-level ``engine``.
INSTALLED_MODULE = "neural_atlas"
#: What ``python -m`` runs: the installed name when this engine came from the wheel, else ``engine`` (a checkout, or
#: the extension's bundled engine on the engine Python's PYTHONPATH).
CLI_MODULE = INSTALLED_MODULE if __name__ == f"{INSTALLED_MODULE}.contract" else "engine"
VERB_FIT = "fit"
VERB_DEMO = "demo"
VERB_ESTIMATE = "estimate"  # estimate CLIP [--mask M ...] [--work RUN_DIR] --json: one JSON object on stdout
#: ``estimate --json`` prints {"neural_atlas_estimate": SCHEMA_VERSION, "clip", "frames", "working_size",
#: "device", "prepare_seconds", "presets": [{"preset", "model", "steps", "minutes", "total_seconds",
#: "train_seconds", "expected_psnr" (dB or null), "expected_psnr_note", ...}]}
ESTIMATE_TAG = "neural_atlas_estimate"
VERB_EXPORT = "export"  # export RUN_DIR [--atlas-size N] [--frames FIRST-LAST]; last stdout line = manifest path
VERB_RENDER = "render"  # render MANIFEST [--edit LAYER=IMAGE ...] --out DIR [--format exr|png|plate] [--filter ...]
VERB_PROJECT_FRAME = "project-frame"  # project-frame MANIFEST --frame N --edit IMAGE
VERB_PREVIEW = "preview"  # preview MANIFEST [--out DIR]
VERB_MASKS = "masks"  # masks CLIP --out FOLDER [--frames FIRST-LAST]; last stdout line = the masks folder
VERB_NUKE = "nuke"  # nuke MANIFEST [--out FILE.nk] [--filter ...]: a Nuke script of the edit; last line = its path
#: realign MANIFEST [--from vNNN|OLD_MANIFEST] [--layer NAME ...] [--frame-step N] [--measure]: move the edit layers
#: painted against an earlier export of the run onto MANIFEST's mapping (after ``fit --refine``); last line = MANIFEST
VERB_REALIGN = "realign"
#: ``--frames`` of every verb speaks the plate's frame numbers (plate.1010.exr .. plate.1050.exr: 1010-1050; a movie's
#: frames count from 0 or ``fit --start-frame``); run folders keep recording positions (clip.json "frame_range").

# --- farm: one plan of a sequence's shots, run by the schedulers studios already have ---------------------------
VERB_FARM = "farm"  # farm plan|openjd|dask|flamenco SHOTS ...: see docs/farm.md
FARM_PLAN = "plan"  # farm plan SHOTS [--json]: every task's engine arguments and dependencies
FARM_OPENJD = "openjd"  # farm openjd SHOTS --out BUNDLE_DIR: an Open Job Description bundle (Deadline Cloud)
FARM_DASK = "dask"  # farm dask SHOTS --scheduler tcp://HOST:PORT: the plan's tasks on a Dask cluster
FARM_FLAMENCO = "flamenco"  # farm flamenco SHOTS --manager URL: one job per shot on a Flamenco Manager
FARM_COMMANDS: tuple[str, ...] = (FARM_PLAN, FARM_OPENJD, FARM_DASK, FARM_FLAMENCO)
#: ``export RUN --into vNNN``: export into that version (a farm's export tasks share one); ``--stage`` splits it
#: into the tasks a farm runs: ``atlases`` (once), ``passes --frames A-B`` (chunks, concurrently), ``publish``
#: (once, when every chunk is done: the version appears with its manifest). Each is idempotent.
EXPORT_INTO_ARG = "--into"
EXPORT_STAGE_ARG = "--stage"
EXPORT_STAGES: tuple[str, ...] = ("atlases", "passes", "publish")
#: ``fit ... --resume-if-started``: a retried farm task: continue the checkpoint of this same fit in RUN_DIR, leave
#: a finished one as it is (exit 0), or start it.
FIT_RESUME_IF_STARTED_FLAG = "--resume-if-started"
#: ``fit --out RUN --refine STEPS [--preset P]``: continue a FINISHED fit for STEPS more steps (with preset P's
#: schedule where the checkpoint allows it), recording first which export the edit layers were painted against
#: (``EDITS_ALIGNED``) so ``realign`` can carry the paint onto the refined fit's next export.
FIT_REFINE_FLAG = "--refine"
#: The shots file (TOML or JSON; docs/farm.md): ``{SHOTS_TAG: SHOTS_VERSION, "defaults": {...}, "shots": [...]}``;
#: relative paths are relative to the file. A shot's keys are SHOT_KEYS; "defaults" holds any of
#: SHOT_DEFAULT_KEYS, which a shot may override.
SHOTS_TAG = "neural_atlas_shots"
SHOTS_VERSION = 1
SHOTS_LIST_KEY = "shots"
SHOTS_DEFAULTS_KEY = "defaults"
SHOT_DEFAULT_KEYS: tuple[str, ...] = (
    "preset",  # fit preset (default: balanced)
    "set",  # fit --set KEY=VALUE overrides, a list
    "device",  # fit/export --device (default: auto for fit, cpu for export)
    "atlas_size",  # export --atlas-size
    "export_chunk",  # frames per export-passes task (default 50)
    "render_chunk",  # frames per render task (default 50)
    "render_format",  # render --format: exr | png | plate
    "preview",  # write the export's preview sheets (default true)
)
SHOT_REQUIRED_KEYS: tuple[str, ...] = ("name", "plate")
#: A shot's name: letters, digits, ``-`` and ``_``, starting with a letter or digit, at most this long: it names the
#: shot's tasks, its run folder and (with a kind: ``sh010-atlases``) an OpenJD step, whose names hold 64 characters.
SHOT_NAME_MAX = 48
SHOT_KEYS: tuple[str, ...] = (
    *SHOT_REQUIRED_KEYS,
    "masks",  # mask folders, one per foreground layer
    "auto_masks",  # true: find the moving objects (a masks task before the fit)
    "frames",  # "FIRST-LAST" in the plate's frame numbers
    "colorspace",  # the plate's OCIO colour space
    "fps",  # the plate's rate ("24", "24000/1001")
    "start_frame",  # a movie's first frame number
    "run",  # the run folder (default: runs/<name> beside the shots file)
    "render",  # a folder for the edited frames (no render task without it)
    *SHOT_DEFAULT_KEYS,
)
#: Flamenco: the job type name, the Manager variable that holds the engine's Python on each worker, and the API.
FLAMENCO_JOB_TYPE = "neural-atlas"
FLAMENCO_PYTHON_VARIABLE = "neural_atlas_python"
FLAMENCO_API_CHECK = "/api/v3/jobs/check"
FLAMENCO_API_SUBMIT = "/api/v3/jobs"

#: The other direction: the add-on's one headless entry point, a script run by Blender (``blender -b -P``) or by
#: a Python with the ``bpy`` module, that builds a .blend with the add-on's compositor tree for a manifest and
#: renders it (``--help`` lists its arguments). ``engine demo`` starts it as a separate process to compare
#: Blender's render with its own; the engine never imports bpy or add-on code. Relative to the folder that holds
#: engine/ and addon/ (the checkout, or the installed extension).
HEADLESS_SCRIPT = "addon/headless.py"

#: The presets (``fit --preset``) and their step budgets. engine/config.py builds its presets with these and
#: the add-on's preset menu and documented fallback estimate read them, so the two sides cannot disagree.
#: Each fast budget is sized to its preset's wall-time target on a CPU (docs/accuracy-vs-time.md has the
#: measurements); paper is the reference implementation's step count.
PRESET_STEPS: dict[str, int] = {"draft": 800, "balanced": 6000, "final": 28000, "paper": 400000}

EXIT_OK = 0
EXIT_FAILED = 1  # an engine bug or an unexpected error: the log has the traceback
EXIT_BAD_INPUT = 2  # the user's input is wrong: one line on stderr names the file and the fix
EXIT_CANCELLED = 3  # SIGINT/SIGTERM: one line; nothing half-written is kept; a fit checkpointed: --resume continues
#: The fit diverged (a non-finite loss, gradient or parameter): one line names the step and the likely cause;
#: nothing past the last good checkpoint was saved, so `fit --resume --set lr=...` continues from it.
EXIT_DIVERGED = 4

# --- run folder ------------------------------------------------------------------------------------------
RUN_CONFIG = "config.json"
RUN_METRICS = "metrics.json"
RUN_CHECKPOINT = "checkpoint.pt"
RUN_CLIP = "clip.json"  # what was fitted: source, frame range, sizes, content fingerprint
RUN_LOG = "fit.log"
FLOW_CACHE_DIR = "flow_cache"
#: The scene analysis of a fit (engine.data.scene_analysis.SceneAnalysis as JSON): which components the run computes,
#: and why.
#: {"schema": SCHEMA_VERSION, "components": "auto"|"all", "num_layers": int, "layers_source": SCENE_LAYERS_*,
#:  "background_motion": BG_MOTION_*, "flow": bool, "scribbles": int, "alpha_network": bool,
#:  "active_terms": [str], "reasons": {decision: one line}, "measured": {name: number|null},
#:  "overrides": [str] (what components=all forced on that the analysis would have left off)}
SCENE_FILE = "scene.json"
SCENE_KEYS: tuple[str, ...] = (
    "components",
    "num_layers",
    "layers_source",
    "background_motion",
    "flow",
    "active_terms",
    "reasons",
)
#: Where the layers came from: --mask folders, masks found from motion (--auto-masks), or none (background only).
SCENE_LAYERS_GIVEN = "given"
SCENE_LAYERS_AUTO = "auto"
SCENE_LAYERS_NONE = "none"
#: Background mapping classes: near-identity (tripod), similarity + small residual (pan/zoom), full (deformable).
BG_MOTION_STATIC = "static"
BG_MOTION_PAN_ZOOM = "pan_zoom"
BG_MOTION_DEFORMABLE = "deformable"
BG_MOTIONS: tuple[str, ...] = (BG_MOTION_STATIC, BG_MOTION_PAN_ZOOM, BG_MOTION_DEFORMABLE)
#: ``fit --auto-masks``: find foreground masks from motion, write them to RUN_DIR/auto_masks/ (the artist can
#: check and fix them, then fit again with --mask RUN_DIR/auto_masks), and fit with them.
FIT_AUTO_MASKS_FLAG = "--auto-masks"
AUTO_MASKS_DIR = "auto_masks"

# --- run folder files: their schemas ----------------------------------------------------------------------
# Each JSON file of a run folder carries {"schema": <its version>}, bumped whenever its shape changes; a reader
# refuses any other version (the run was made by another engine: fit again). engine/fit/run_folder.py is the
# one module that reads and writes them, through ``validate_run_file``. Shapes:
#   RUN_CONFIG   {"schema": 1, "config": {FitConfig field: value}}  (engine/config.py documents every field)
#   RUN_CLIP     {"schema": 2, "source": str (absolute), "kind": "sequence"|"movie",
#                 "frame_range": [first, last] (inclusive positions in the source), "frame_numbers": [int],
#                 "frame_files": [str] (absolute; [] for a movie), "native_size": [W, H], "working_size": [W, H],
#                 "fps": float|null, "colorspace": str (the plate's OCIO colour space; "sRGB"|"linear" in runs made
#                 before colour management), "colour_config": str (optional: the OCIO config that names it, $OCIO's
#                 path or "ocio://default"; absent in older runs, see LEGACY_COLORSPACES), "colour_source": str
#                 (optional: how "colorspace" was decided, one of COLOUR_SOURCES; "assumed": nothing said it),
#                 "masks": [str] (absolute folders),
#                 "scribbles": str|null, "layers": int (background + foreground layers of the model),
#                 "fingerprint": str (hash of the fitted frames: a resume refuses a changed clip),
#                 optional (RUN_CLIP_OPTIONAL_FIELDS; a record without them is of square pixels, no exact rate, no
#                 timecode, a movie numbered from 0): "rate": [num, den]|null (exact frame rate, 24000/1001),
#                 "pixel_aspect": number, "timecode": str|null (SMPTE, of the first fitted frame), "start_frame": int
#                 (a movie's number of its first frame), "source_relative", "frame_files_relative", "masks_relative",
#                 "scribbles_relative" (the same paths relative to the run folder, read where the absolute ones are
#                 missing: a run folder moved or mounted elsewhere with its plate)}
#                 Everything `export` needs besides the checkpoint: it never decodes the plate. "frame_range" is in
#                 positions (what `open_clip` takes); "frame_numbers" are the plate's own numbers (what --frames says).
#   RUN_METRICS  {"schema": 1, "psnr": float, "mse": float, "alpha_iou": [float] (one per mask), "steps": int,
#                 "train_seconds": float, "seconds_per_step": float, "preset": str, "model": str, "device": str,
#                 "working_size": [W, H], "frames": int, "engine_version": str, "torch_version": str}
#   SCENE_FILE   {"schema": 1, the fields of RUN_FILE_FIELDS[SCENE_FILE]} (shape above; ``validate_scene`` checks
#                 the copy in a manifest)
#   RUN_CHECKPOINT (torch, loaded with weights_only) {RUN_CHECKPOINT_KEYS}: "schema": RUN_CHECKPOINT_SCHEMA,
#                 "motions": each layer's starting motion and atlas box (fast model; null for the paper model),
#                 "fingerprint": the clip record's, "config": the config's fields as saved (a checkpoint is
#                 compared with clip.json and config.json when loaded: one from another run is refused)
RUN_CONFIG_SCHEMA = SCHEMA_VERSION
RUN_CLIP_SCHEMA = 2
RUN_METRICS_SCHEMA = SCHEMA_VERSION
RUN_SCENE_SCHEMA = SCHEMA_VERSION
RUN_CHECKPOINT_SCHEMA = 2
#: The checkpoint schema before "config" was recorded: still read (a fit made with it resumes and exports), its
#: config taken to be its run's config.json; saved again, it is written as RUN_CHECKPOINT_SCHEMA.
RUN_CHECKPOINT_SCHEMA_WITHOUT_CONFIG = 1
RUN_CHECKPOINT_KEYS: tuple[str, ...] = (
    "schema",
    "model",
    "optim",
    "sched",
    "gen",
    "step",
    "train_seconds",
    "fingerprint",
    "config",
    "motions",
)
#: Field types, in words: "str", "int", "number" (int or float), "bool", "dict", "<type> list", "<type> pair"
#: (a list of two), and "... or null".
RUN_FILE_FIELDS: dict[str, dict[str, str]] = {
    RUN_CONFIG: {"config": "dict"},
    RUN_CLIP: {
        "source": "str",
        "kind": "str",
        "frame_range": "int pair",
        "frame_numbers": "int list",
        "frame_files": "str list",
        "native_size": "int pair",
        "working_size": "int pair",
        "fps": "number or null",
        "colorspace": "str",
        "masks": "str list",
        "scribbles": "str or null",
        "layers": "int",
        "fingerprint": "str",
    },
    RUN_METRICS: {
        "psnr": "number",
        "mse": "number",
        "alpha_iou": "number list",
        "steps": "int",
        "train_seconds": "number",
        "seconds_per_step": "number",
        "preset": "str",
        "model": "str",
        "device": "str",
        "working_size": "int pair",
        "frames": "int",
        "engine_version": "str",
        "torch_version": "str",
    },
    SCENE_FILE: {
        "components": "str",
        "num_layers": "int",
        "layers_source": "str",
        "background_motion": "str",
        "flow": "bool",
        "scribbles": "int",
        "alpha_network": "bool",
        "active_terms": "str list",
        "reasons": "dict",
        "measured": "dict",
        "overrides": "str list",
    },
}
#: Fields of clip.json a record may leave out (written by this engine; checked when present): the plate's timing.
RUN_CLIP_OPTIONAL_FIELDS: dict[str, str] = {
    "rate": "int pair or null",
    "pixel_aspect": "number",
    "timecode": "str or null",
    "start_frame": "int",
    "colour_source": "str",  # how "colorspace" was decided: one of COLOUR_SOURCES
    # the paths relative to the run folder ("/" separated; null: none, another drive), beside the absolute ones: a
    # run folder moved or mounted elsewhere with its plate reads the plate there (engine/fit/run_folder.py)
    "source_relative": "str or null",
    "frame_files_relative": "str or null list",
    "masks_relative": "str or null list",
    "scribbles_relative": "str or null",
}
RUN_FILE_SCHEMAS: dict[str, int] = {
    RUN_CONFIG: RUN_CONFIG_SCHEMA,
    RUN_CLIP: RUN_CLIP_SCHEMA,
    RUN_METRICS: RUN_METRICS_SCHEMA,
    SCENE_FILE: RUN_SCENE_SCHEMA,
}
#: How each file is named in messages.
RUN_FILE_WHAT: dict[str, str] = {
    RUN_CONFIG: "config",
    RUN_CLIP: "clip record",
    RUN_METRICS: "metrics",
    SCENE_FILE: "scene analysis",
}
#: The scene analysis's ``components`` values (engine/config.py's ``components`` field).
RUN_SCENE_COMPONENTS: tuple[str, ...] = ("auto", "all")
RUN_SCENE_LAYERS_SOURCES: tuple[str, ...] = (SCENE_LAYERS_GIVEN, SCENE_LAYERS_AUTO, SCENE_LAYERS_NONE)
#: The fix for a run file of another engine version (a refused schema).
RUN_FILE_OTHER_VERSION_FIX = "fit into a new run folder or use the engine version that made this run"
#: The fix for a run file that is damaged (not JSON, a key missing or of the wrong type).
RUN_FILE_DAMAGED_FIX = "restore it, or fit into a new run folder"
CLIP_KINDS: tuple[str, ...] = ("sequence", "movie")
#: The colour-space values of records made before colour management (no "colour_config" beside them); still read.
COLORSPACES: tuple[str, ...] = ("sRGB", "linear")
#: Colour (docs/colour.md). A clip's "colorspace" is the name of its plate's colour space in the OCIO config named by
#: "colour_config" ($OCIO's path when it was set, else COLOUR_BUILTIN_CONFIG). Records without "colour_config" were
#: made before colour management: their "sRGB"/"linear" mean the built-in config's spaces below (LEGACY_COLORSPACES).
COLOUR_BUILTIN_CONFIG = "ocio://default"
#: Blender's scene-linear space (edit layers, atlas EXRs, the edit composite), in the built-in config's words.
COLOUR_SCENE_LINEAR = "Linear Rec.709 (sRGB)"
#: The sRGB encoding of COLOUR_SCENE_LINEAR (PNG edit layers and atlases; the fit's working encoding).
COLOUR_SRGB = "sRGB Encoded Rec.709 (sRGB)"
#: Data: passes, masks (never converted).
COLOUR_RAW = "Raw"
LEGACY_COLORSPACES: dict[str, str] = {"sRGB": COLOUR_SRGB, "linear": COLOUR_SCENE_LINEAR}
#: The EXR header attribute that names a file's colour space for OCIO readers (OpenImageIO's): passes say COLOUR_RAW.
EXR_COLORSPACE_ATTRIBUTE = "oiio:ColorSpace"
#: The longest colour-space or config name a record may hold (a path to a config file included).
COLOUR_NAME_MAX = 4096
#: How the plate's colour space was decided, recorded beside it as "colour_source" (clip.json and the manifest's
#: clip; absent from runs made before it was kept): named (``--colorspace``), stated by the file's header (an EXR's
#: oiio:ColorSpace tag, ACES or Rec.709 chromaticities, a DPX's linear transfer), chosen by $OCIO's file rules, given
#: by a file type that defines its colour (PNG, JPEG: sRGB), or assumed: nothing said it (a float file read as
#: scene-linear Rec.709; a TIFF, an undeclared DPX or a movie as sRGB), and the fit printed one ``note:`` line.
COLOUR_SOURCE_ASKED = "asked"
COLOUR_SOURCE_FILE = "file"
COLOUR_SOURCE_RULES = "rules"
COLOUR_SOURCE_FORMAT = "format"
COLOUR_SOURCE_ASSUMED = "assumed"
COLOUR_SOURCES: tuple[str, ...] = (
    COLOUR_SOURCE_ASKED,
    COLOUR_SOURCE_FILE,
    COLOUR_SOURCE_RULES,
    COLOUR_SOURCE_FORMAT,
    COLOUR_SOURCE_ASSUMED,
)


def valid_colour_record(colorspace: Any, config: Any) -> bool:
    """A clip record's colour: a legacy value without a config, or a space name with its config (non-empty
    strings, no control characters); whether the config knows the name is the engine's check (OCIO)."""

    def name(v: Any) -> bool:
        return isinstance(v, str) and 0 < len(v) <= COLOUR_NAME_MAX and v.isprintable()

    if config is None:
        return colorspace in COLORSPACES
    return name(colorspace) and name(config)


#: A timecode as the engine records it: ``HH:MM:SS:FF``, ``;`` before the frames for drop-frame.
TIMECODE_PATTERN = r"^\d{2}:[0-5]\d:[0-5]\d[:;]\d{2,3}$"


def timing_problem(clip: dict[str, Any]) -> str | None:
    """What is wrong with a clip record's (or a manifest clip's) optional timing fields, or None: a rate of two
    positive integers, a finite positive pixel aspect ratio, a timecode ``HH:MM:SS:FF`` and a start frame >= 0."""
    rate = clip.get("rate")
    aspect = clip.get("pixel_aspect", 1.0)
    timecode = clip.get("timecode")
    if rate is not None and not (len(rate) == 2 and rate[0] > 0 and rate[1] > 0):
        return f"rate {rate!r} is not a positive fraction [num, den]"
    if not (math.isfinite(aspect) and aspect > 0):
        return f"pixel_aspect {aspect!r} is not a positive number"
    if timecode is not None and re.match(TIMECODE_PATTERN, timecode) is None:
        return f"timecode {timecode[:MANIFEST_QUOTE_CHARS]!r} is not HH:MM:SS:FF"
    if clip.get("start_frame", 0) < 0:
        return "start_frame is negative"
    return None


#: A frame file's number: the digits just before its extension (``plate.1001.exr``, ``plate_0012.png``).
FRAME_FILE_DIGITS = re.compile(r"(\d+)(?=\.[^.]+$)")


def sequence_pattern_of(path: str) -> str | None:
    """The pattern of the image sequence a frame file belongs to, one ``#`` per digit of its number
    (``/plates/plate.1001.exr`` -> ``/plates/plate.####.exr``: the clip argument ``fit`` takes); None for a file
    name without a number before its extension."""
    name = os.path.basename(path)
    m = FRAME_FILE_DIGITS.search(name)
    if m is None:
        return None
    return os.path.join(os.path.dirname(path), f"{name[: m.start()]}{'#' * len(m.group(1))}{name[m.end() :]}")


def clip_rate(clip: dict[str, Any]) -> tuple[int, int] | None:
    """A manifest clip's frame rate as an exact (num, den): its "rate", else its float "fps" as the fraction it
    stands for (23.976... -> 24000/1001, 25.0 -> 25/1); None when it has neither."""
    if clip.get("rate"):
        num, den = clip["rate"]
        return int(num), int(den)
    fps = clip.get("fps")
    if not fps:
        return None
    rate = Fraction(fps).limit_denominator(1001)
    return rate.numerator, rate.denominator


class RunFileError(ValueError):
    """A run-folder file that does not follow its schema: ``problem`` and ``fix``, one line each (the engine
    adds the file's path, as every one-line error does)."""

    def __init__(self, problem: str, fix: str) -> None:
        super().__init__(f"{problem} — {fix}")
        self.problem = problem
        self.fix = fix


def _is_type(value: Any, kind: str) -> bool:
    if kind.endswith(" or null"):
        return value is None or _is_type(value, kind[: -len(" or null")])
    if kind.endswith(" list") or kind.endswith(" pair"):
        item = kind.rsplit(" ", 1)[0]
        ok = isinstance(value, list) and all(_is_type(v, item) for v in value)
        return ok and (kind.endswith(" list") or len(value) == 2)
    if kind == "number":
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind == "int":
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, {"str": str, "bool": bool, "dict": dict}[kind])


def validate_run_file(name: str, data: Any) -> dict[str, Any]:
    """Check a decoded run-folder file (``RUN_CONFIG``, ``RUN_CLIP``, ``RUN_METRICS`` or ``SCENE_FILE``) against its
    schema above; returns it, or raises RunFileError."""
    what = RUN_FILE_WHAT[name]
    if not isinstance(data, dict):
        raise RunFileError(f"{what} is not a JSON object", RUN_FILE_DAMAGED_FIX)
    version = data.get("schema")
    if version != RUN_FILE_SCHEMAS[name]:
        problem = f"{what} schema {version!r} is not supported (this engine writes {RUN_FILE_SCHEMAS[name]})"
        raise RunFileError(problem, RUN_FILE_OTHER_VERSION_FIX)
    for key, kind in RUN_FILE_FIELDS[name].items():
        if key not in data:
            raise RunFileError(f"{what} has no {key!r}", RUN_FILE_DAMAGED_FIX)
        if not _is_type(data[key], kind):
            raise RunFileError(f"{what} {key!r} is not a {kind}: {data[key]!r}", RUN_FILE_DAMAGED_FIX)
    if name == RUN_CLIP:
        for key, kind in RUN_CLIP_OPTIONAL_FIELDS.items():
            if key in data and not _is_type(data[key], kind):
                raise RunFileError(f"{what} {key!r} is not a {kind}: {data[key]!r}", RUN_FILE_DAMAGED_FIX)
        _check_clip_record(data)
    elif name == SCENE_FILE:
        _check_scene_record(data)
    return data


def _check_clip_record(data: dict[str, Any]) -> None:
    """What the clip record's fields say of each other (their types are checked already)."""
    count = len(data["frame_numbers"])
    first, last = data["frame_range"]
    problem = None
    if count < 1 or last - first + 1 != count:
        problem = f"clip record: frame_range {first}..{last} does not span its {count} frames"
    elif data["frame_files"] and len(data["frame_files"]) != count:
        problem = f"clip record lists {len(data['frame_files'])} frame files for {count} frames"
    elif data["kind"] not in CLIP_KINDS or not valid_colour_record(data["colorspace"], data.get("colour_config")):
        problem = f"clip record: unknown kind or colour space {data['kind']!r}, {data['colorspace']!r}"
    elif data.get("colour_source", COLOUR_SOURCE_ASKED) not in COLOUR_SOURCES:
        problem = f"clip record: unknown colour_source {data['colour_source'][:MANIFEST_QUOTE_CHARS]!r}"
    elif data["layers"] < 1 or min(data["native_size"] + data["working_size"]) < 1:
        problem = "clip record: layers and sizes must be positive"
    elif any(len(data.get(f"{k}_relative", data[k])) != len(data[k]) for k in ("frame_files", "masks")):
        problem = "clip record: its relative paths do not match its frame files and masks"
    else:
        problem = timing_problem(data)
        problem = problem and f"clip record: {problem}"
    if problem is not None:
        raise RunFileError(problem, RUN_FILE_DAMAGED_FIX)


def _check_scene_record(data: dict[str, Any]) -> None:
    """What the scene analysis's values must be (their types are checked already): known choices, counts that
    can be, and one line of text or a number per reason and measurement."""
    problem = None
    if data["components"] not in RUN_SCENE_COMPONENTS:
        problem = f"scene analysis: unknown components {data['components']!r}"
    elif data["background_motion"] not in BG_MOTIONS:
        problem = f"scene analysis: unknown background_motion {data['background_motion']!r}"
    elif data["layers_source"] not in RUN_SCENE_LAYERS_SOURCES:
        problem = f"scene analysis: unknown layers_source {data['layers_source']!r}"
    elif data["num_layers"] < 1 or data["scribbles"] < 0:
        problem = "scene analysis: num_layers must be positive and scribbles not negative"
    elif not all(isinstance(v, str) for v in data["reasons"].values()):
        problem = "scene analysis: a reason is not text"
    elif not all(v is None or _is_type(v, "number") for v in data["measured"].values()):
        problem = "scene analysis: a measurement is not a number or null"
    if problem is not None:
        raise RunFileError(problem, RUN_FILE_DAMAGED_FIX)


# --- progress protocol: one JSON object per stdout line ---------------------------------------------------
PROGRESS_TAG = "neural_atlas"  # every machine-readable line carries {"neural_atlas": SCHEMA_VERSION, ...}
EVENT_STAGE = "stage"  # {"stage": "flow"|"init"|"train"|"evaluate", "message": str}
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


# --- export: EXR passes, atlas textures, edit layers, manifest ----------------------------------------------
# A run folder holds any number of exports, each in its own versioned folder that is never rewritten:
#   RUN_DIR/exports/v001/manifest.json, passes/atlas.00000.exr ..., atlases/<Layer>.exr|.png
# and ONE set of edit layers shared by every export of the run (the artist's paint, never overwritten):
#   RUN_DIR/edits/<Layer>.png (+ RUN_DIR/edits/layout.json, the atlas frame each edit layer was painted in)
EXPORTS_DIR = "exports"
EXPORT_VERSION_FORMAT = "v{:03d}"
#: A farm's staged export (``export --into vNNN --stage ...``) is assembled in ``exports/.vNNN`` + this suffix until
#: it is published; the farm plan reads the same name to continue an unfinished one.
EXPORT_CHUNKS_SUFFIX = ".chunks"
EDITS_DIR = "edits"
EDITS_LAYOUT = "layout.json"
#: ``edits/aligned.json``: {"neural_atlas_aligned": 1, "export": "vNNN"}, the export whose mapping the edit layers
#: were painted against (written by ``fit --refine`` when missing, and by ``realign``)
EDITS_ALIGNED = "aligned.json"
EDITS_ALIGNED_TAG = "neural_atlas_aligned"
MANIFEST_NAME = "manifest.json"
#: Version of manifest.json; the add-on refuses a manifest whose version it does not know.
MANIFEST_VERSION = 1
MANIFEST_TAG = "neural_atlas_manifest"  # {"neural_atlas_manifest": MANIFEST_VERSION, ...}

PASSES_DIR = "passes"
ATLASES_DIR = "atlases"
#: Pass files are named by the plate's frame number, padded as the plate's frame files are (``frame_padding``): a
#: plate.1001.exr gives passes/atlas.1001.exr (Blender reads the last digits). A plate with no padding of its own (a
#: movie, frames whose digits vary) gives PASS_FILE_DIGITS digits. The manifest's "pattern" names them: readers
#: take it from there (exports made before the padding followed the plate have five digits).
PASS_FILE_PREFIX = "atlas."
PASS_FILE_DIGITS = 5
PASS_FILE_EXT = ".exr"

#: The single EXR layer of every pass file; Blender's multilayer convention is <layer>.<pass>.<channel>,
#: so one Image node exposes one socket per pass.
EXR_LAYER = "Atlas"
UV_PASS_PREFIX = "UV"  # UV<Layer>: channels U, V, A = u, v (0..1, origin bottom-left), the layer's alpha
ALPHA_PASS_PREFIX = "Alpha"  # Alpha<Layer>: one channel V, the layer's alpha (opacity weight; sums to 1)
#: A UV pass's channels in the order u, v, coverage: Blender's own name for its UV render pass (``UV.U``, ``UV.V``,
#: ``UV.A``), which its Image node gives Map UV as one vector (it orders U, V, A by letter). OpenImageIO takes a channel
#: named "Z" or "*.Z" as depth (its z_channel) and one named "A" or "*.A" as alpha: the coverage is an alpha.
#: Each manifest layer records its "uv_channels" in this order, so an export of either naming reads the same.
UV_CHANNELS: tuple[str, ...] = ("U", "V", "A")
#: The UV pass's channels in exports made before it took Blender's naming (OpenImageIO read their Z as depth).
LEGACY_UV_CHANNELS: tuple[str, ...] = ("X", "Y", "Z")
ALPHA_CHANNELS: tuple[str, ...] = ("V",)
#: The same UV pass for Nuke, Flame and Natron, in the same pass files: per layer a layer with ONE dot in its channel
#: names, STMap<Layer>.R/G/B/A = u, v, 0 and the coverage (the UV pass's A), float32 copies of the same values.
#: Nuke's EXR reader turns every dot but the last into "_" (Atlas.UVForeground.U shows as Atlas_UVForeground.U) and
#: R/G/B/A into red/green/blue/alpha, so these show as STMap<Layer>.red/green/blue/alpha: an RGBA layer whose rg is
#: what STMap reads and whose alpha is the coverage. Blender's Image node skips one-dot names: its passes are unchanged.
STMAP_PASS_PREFIX = "STMap"
STMAP_CHANNELS: tuple[str, ...] = ("R", "G", "B", "A")
#: The Nuke script an export writes next to its manifest (``engine nuke`` writes one anywhere).
NUKE_SCRIPT_NAME = "neural_atlas.nk"

ROLE_BACKGROUND = "background"
ROLE_FOREGROUND = "foreground"

#: Edit layers are RGBA, sRGB-encoded, straight alpha (8-bit PNG: Blender loads it exactly as sRGB).
EDIT_LAYER_EXT = ".png"
#: ...or a float edit layer next to it, RUN_DIR/edits/<Layer>.exr: scene-linear, premultiplied RGBA (what a
#: compositor paints in; no 8-bit quantisation, no sRGB decode). The export only ever creates the PNG, so an
#: EXR beside it is the artist's deliberate choice: when both exist the EXR is used (``edit_layer_file``).
EDIT_LAYER_FLOAT_EXT = ".exr"


def edit_layer_file(edit_layer: str) -> str:
    """The edit layer file in use for a manifest's ``edit_layer`` path (the PNG the export made): its float
    twin ``<same name>.exr`` when that exists, else the path itself. The engine and the add-on both call this,
    so they always read the same paint."""
    if os.path.splitext(edit_layer)[1].lower() == EDIT_LAYER_EXT:
        exr = float_edit_layer(edit_layer)
        if os.path.exists(exr):
            return exr
    return edit_layer


def float_edit_layer(edit_layer: str) -> str:
    """The float twin of an edit layer: ``<same name>.exr`` beside it (whether or not it exists yet)."""
    return os.path.splitext(edit_layer)[0] + EDIT_LAYER_FLOAT_EXT


#: Atlas textures: a float EXR (linear, premultiplied RGBA) and a 16-bit PNG (sRGB, straight alpha).
ATLAS_EXR_EXT = ".exr"
ATLAS_PNG_EXT = ".png"
#: ``export --atlas-size``: texels on an atlas texture's long side (default: the paper's), and the range accepted.
ATLAS_SIZE_DEFAULT = 1000
ATLAS_SIZE_RANGE: tuple[int, int] = (8, 16384)


#: Scribbles (``fit --mask OBJECT --scribbles FOLDER``, paper Sec. 4.4): one image per scribbled frame, named
#: with the frame number like masks (00012.png for frame 00012); frames without a file have no scribbles.
#: An 8-bit pixel whose R, G, B are each within SCRIBBLE_TOLERANCE of SCRIBBLE_COLOURS[k] (and whose alpha,
#: if any, is above SCRIBBLE_ALPHA_CUTOFF) marks foreground layer k+1; anything else (black, transparent) marks
#: nothing. The mask is the whole object; the fit gives it as many foreground layers as the highest colour index used.
SCRIBBLE_ARG = "--scribbles"
SCRIBBLE_COLOURS: tuple[tuple[int, int, int], ...] = (
    (255, 0, 0),  # red -> Foreground1
    (0, 255, 0),  # green -> Foreground2
    (0, 0, 255),  # blue -> Foreground3
    (255, 255, 0),  # yellow -> Foreground4
)
SCRIBBLE_TOLERANCE = 48
SCRIBBLE_ALPHA_CUTOFF = 127  # half of 8-bit full scale: a stroke's soft edge counts where it is mostly opaque
SCRIBBLE_FILE_FORMAT = "{:05d}.png"  # what the add-on writes; the engine reads any numbered png/tif


def layer_name(index: int, num_layers: int) -> str:
    """Layer names used in channel names and file names: Background, Foreground (or Foreground1, 2, ...)."""
    if index == 0:
        return "Background"
    return "Foreground" if num_layers == 2 else f"Foreground{index}"


def uv_pass(layer: str) -> str:
    return f"{UV_PASS_PREFIX}{layer}"


def alpha_pass(layer: str) -> str:
    return f"{ALPHA_PASS_PREFIX}{layer}"


def stmap_pass(layer: str) -> str:
    return f"{STMAP_PASS_PREFIX}{layer}"


def stmap_channel_name(layer: str, channel: str) -> str:
    """Full EXR channel name of a layer's STMap copy, e.g. ``STMapForeground.R`` (one dot: Nuke shows it as is)."""
    return f"{stmap_pass(layer)}.{channel}"


def channel_name(pass_name: str, channel: str) -> str:
    """Full EXR channel name, e.g. ``Atlas.UVForeground.U``."""
    return f"{EXR_LAYER}.{pass_name}.{channel}"


def pass_file_name(frame_number: int, padding: int = PASS_FILE_DIGITS) -> str:
    """``atlas.00012.exr`` for plate frame 12 (``padding`` digits at least)."""
    return pass_pattern(padding).format(frame=frame_number)


def pass_pattern(padding: int) -> str:
    """The manifest's "pattern" of pass files padded to ``padding`` digits: ``atlas.{frame:04d}.exr``."""
    return f"{PASS_FILE_PREFIX}{{frame:0{padding}d}}{PASS_FILE_EXT}"


def blender_pattern(padding: int) -> str:
    """The same pattern as Blender and most compositors write it: ``atlas.####.exr``."""
    return f"{PASS_FILE_PREFIX}{'#' * padding}{PASS_FILE_EXT}"


def frame_padding(frame_files: list[str] | tuple[str, ...], frame_numbers: list[int] | tuple[int, ...]) -> int:
    """The digits a plate's frame files pad their numbers to: 4 for ``plate.1001.exr`` .. (and for ``plate.0998.exr``
    .. ``plate.1001.exr``), 1 for ``f9.png``, ``f10.png``; PASS_FILE_DIGITS for a movie (no files) or names that are
    not the frame number padded one way. What the outputs numbered by the plate's frames follow."""
    digits = []
    for path, number in zip(frame_files, frame_numbers, strict=False):
        m = FRAME_FILE_DIGITS.search(os.path.basename(path))
        if m is None or int(m.group(1)) != number:
            return PASS_FILE_DIGITS
        digits.append(m.group(1))
    if not digits:
        return PASS_FILE_DIGITS
    padding = min(len(d) for d in digits)
    if any(d != f"{n:0{padding}d}" for d, n in zip(digits, frame_numbers, strict=False)):
        return PASS_FILE_DIGITS
    return padding


#: Keys every manifest has (validated by ``validate_manifest``, types included). Paths inside are relative to the
#: manifest's folder, so a run folder moved or mounted elsewhere keeps working (the plate's paths are absolute only
#: where no relative path exists, e.g. on another Windows drive); edit layers must stay inside the run folder
#: (``resolve_manifest_write_path``). Shape:
#: {"neural_atlas_manifest": 1, "engine_version": str, "run_dir": str (the run folder, relative), "created":
#:  ISO-8601 str,
#:  "clip": {"source": str, "kind": "sequence"|"movie", "frame_files": [str] ([] for a movie), "frame_numbers":
#:           [int] (ascending), "first_frame": int, "last_frame": int, "fps": float|None, "resolution": [W, H],
#:           "working_resolution": [W, H], "colorspace": str (the plate's OCIO colour space; "sRGB"|"linear" in
#:           older manifests), "colour_config": str (optional: its OCIO config; absent = LEGACY_COLORSPACES),
#:           "colour_source": str (optional: how the colour space was decided, one of COLOUR_SOURCES),
#:           "masks": [str] (the fit's mask folders; optional), and optional, the plate's timing
#:           (MANIFEST_OPTIONAL_FIELDS; absent: none stated): "rate": [num, den]|None (the exact frame rate, 24000/1001
#:           for 23.976; "fps" is its float), "pixel_aspect": number (2.0: 2x anamorphic), "timecode": str|None (SMPTE
#:           "HH:MM:SS:FF" of first_frame), "start_frame": int (a movie's number of its first frame: frame_numbers are
#:           start_frame + the frame's index), "source_absolute": str and "frame_files_absolute": [str] (optional:
#:           the same plate paths, absolute as at export; where the relative ones name nothing, a run folder moved
#:           alone, ``resolve_plate_path`` takes these)},
#:  "passes": {"dir": str, "pattern": "atlas.{frame:04d}.exr" (padded as the plate's frames: ``pass_pattern``),
#:             "blender_pattern": "atlas.####.exr" (the same for Blender: ``blender_pattern``),
#:             "frames": [int] (plate frame numbers exported, each one of the clip's), "exr_layer": "Atlas",
#:             "resolution": [W, H] (the clip's)},
#:  "layers": [{"name": str (unique), "index": int (its position; 0 is the background), "role":
#:              "background"|"foreground", "uv_pass": str, "alpha_pass": str, "uv_channels": [3 str] (u, v,
#:              coverage: UV_CHANNELS, or LEGACY_UV_CHANNELS in older exports),
#:              "alpha_channels": [str], "atlas_exr": str, "atlas_png": str, "atlas_size": [W, H], "edit_layer": str,
#:              "atlas_box": [u0, v0, u1, v1],
#:              "channels": [full EXR channel names, e.g. "Atlas.UVForeground.U"] (optional: derivable),
#:              "stmap_pass": "STMap<Layer>", "stmap_channels": [4 full EXR channel names] (optional: exports made
#:              before the STMap layers have neither, and their pass files have no STMap layers)}],
#:  "fit": {"preset": str, "model": str, "steps": int, "train_seconds": float, "psnr": float|None,
#:          "alpha_iou": [float]|None (optional)},
#:  "scene": the run's SCENE_FILE (every export writes it; checked by ``validate_scene`` when present)}
#: Field types, in the words of RUN_FILE_FIELDS, per section ("" is the top level).
MANIFEST_FIELDS: dict[str, dict[str, str]] = {
    "": {"engine_version": "str", "run_dir": "str", "created": "str"},
    "clip": {
        "source": "str",
        "kind": "str",
        "frame_files": "str list",
        "frame_numbers": "int list",
        "first_frame": "int",
        "last_frame": "int",
        "fps": "number or null",
        "resolution": "int pair",
        "colorspace": "str",
    },
    "passes": {
        "dir": "str",
        "pattern": "str",
        "blender_pattern": "str",
        "frames": "int list",
        "exr_layer": "str",
        "resolution": "int pair",
    },
    "fit": {"preset": "str", "model": "str", "steps": "int", "train_seconds": "number", "psnr": "number or null"},
}
#: Fields a manifest may leave out, checked when present.
MANIFEST_OPTIONAL_FIELDS: dict[str, dict[str, str]] = {
    "clip": {
        "working_resolution": "int pair",
        "masks": "str list",
        "colour_config": "str",
        "colour_source": "str",
        "rate": "int pair or null",
        "pixel_aspect": "number",
        "timecode": "str or null",
        "start_frame": "int",
        "source_absolute": "str",
        "frame_files_absolute": "str list",
    },
    "fit": {"alpha_iou": "number list or null"},
}
MANIFEST_LAYER_FIELDS: dict[str, str] = {
    "name": "str",
    "index": "int",
    "role": "str",
    "uv_pass": "str",
    "alpha_pass": "str",
    "uv_channels": "str list",
    "alpha_channels": "str list",
    "atlas_exr": "str",
    "atlas_png": "str",
    "atlas_size": "int pair",
    "edit_layer": "str",
    "atlas_box": "number list",
}
MANIFEST_OPTIONAL_LAYER_FIELDS: dict[str, str] = {
    "channels": "str list",
    "stmap_pass": "str",
    "stmap_channels": "str list",
}
MANIFEST_KEYS: tuple[str, ...] = (*MANIFEST_FIELDS[""], "clip", "passes", "layers", "fit")
MANIFEST_CLIP_KEYS: tuple[str, ...] = tuple(MANIFEST_FIELDS["clip"])
MANIFEST_PASSES_KEYS: tuple[str, ...] = tuple(MANIFEST_FIELDS["passes"])
MANIFEST_LAYER_KEYS: tuple[str, ...] = tuple(MANIFEST_LAYER_FIELDS)
MANIFEST_FIT_KEYS: tuple[str, ...] = tuple(MANIFEST_FIELDS["fit"])
#: The largest image side a manifest may give (plate, passes, atlases): it bounds what a reader allocates.
MANIFEST_MAX_SIDE = 1 << 16
#: A value quoted in a manifest error is cut to this many characters (the message stays one short line); a path
#: written through gets more, so the file it names shows.
MANIFEST_QUOTE_CHARS = 40
MANIFEST_QUOTE_PATH_CHARS = 120
#: Channels of a UV pass (u, v, and Z: the layer's alpha where its atlas covers the pixel).
MANIFEST_UV_CHANNEL_COUNT = len(UV_CHANNELS)
#: An atlas box is four numbers: u0, v0, u1, v1.
MANIFEST_BOX_NUMBERS = 4
#: A layer's name is a plain identifier (what ``layer_name`` makes): it becomes file names (``edits/<name>.png``),
#: channel names and node names in Blender and Nuke, where a bracket, quote or newline would be code or a path.
MANIFEST_LAYER_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
#: The longest layer name a manifest may give (a file name and a node name are made of it).
MANIFEST_LAYER_NAME_MAX = 64


class ManifestError(ValueError):
    """A manifest that does not follow this contract (message names what is wrong)."""


def _quote(value: Any, limit: int = MANIFEST_QUOTE_CHARS) -> str:
    """``value`` as a message quotes it: repr, cut to ``limit`` characters (a path keeps its end, the file)."""
    text = repr(value)
    if len(text) <= limit:
        return text
    return "..." + text[3 - limit :] if isinstance(value, str) else text[: limit - 3] + "..."


def _a(kind: str) -> str:
    return f"an {kind}" if kind[0] in "aeiou" else f"a {kind}"


def _check_fields(where: str, record: Any, fields: dict[str, str], optional: dict[str, str]) -> dict[str, Any]:
    """``record`` (the manifest's part ``where``: "clip", "layer 0", "" for the top) is an object holding every key
    of ``fields`` (and maybe those of ``optional``) with its type."""
    name = f"manifest {where}".rstrip()
    if not isinstance(record, dict):
        raise ManifestError(f"{name} is not an object")
    for key, kind in (*fields.items(), *optional.items()):
        if key not in record:
            if key in fields:
                raise ManifestError(f"{name} has no {key!r}")
            continue
        if not _is_type(record[key], kind):
            raise ManifestError(f"{name} field {key!r} is not {_a(kind)}: {_quote(record[key])}")
    return record


def _check_size(where: str, size: list[int], limit: int = MANIFEST_MAX_SIDE) -> None:
    if not all(1 <= side <= limit for side in size):
        raise ManifestError(f"manifest {where} {_quote(size)} is not two sides in 1..{limit}")


def _check_clip(clip: dict[str, Any]) -> None:
    """The clip's fields agree with each other: known kind and colour space, frames ascending, one file each."""
    numbers = clip["frame_numbers"]
    if clip["kind"] not in CLIP_KINDS or not valid_colour_record(clip["colorspace"], clip.get("colour_config")):
        raise ManifestError(
            f"manifest 'clip' has unknown kind or colour space {_quote([clip['kind'], clip['colorspace']])}"
        )
    if clip.get("colour_source", COLOUR_SOURCE_ASKED) not in COLOUR_SOURCES:
        raise ManifestError(f"manifest 'clip' has unknown colour_source {_quote(clip['colour_source'])}")
    if not numbers or numbers[0] < 0 or numbers != sorted(set(numbers)):
        raise ManifestError("manifest 'clip' frame_numbers are not ascending frame numbers >= 0")
    if (clip["first_frame"], clip["last_frame"]) != (numbers[0], numbers[-1]):
        raise ManifestError("manifest 'clip' first_frame and last_frame are not its first and last frame numbers")
    if clip["kind"] == CLIP_KINDS[0] and len(clip["frame_files"]) != len(numbers):
        raise ManifestError(f"manifest 'clip' lists {len(clip['frame_files'])} frame files for {len(numbers)} frames")
    if not clip["source"] or not all(clip["frame_files"]):
        raise ManifestError("manifest 'clip' has an empty path")
    fps = clip["fps"]
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise ManifestError(f"manifest 'clip' fps {_quote(fps)} is not a positive number")
    problem = timing_problem(clip)
    if problem is not None:
        raise ManifestError(f"manifest 'clip' {problem}")
    _check_size("'clip' resolution", clip["resolution"])
    if "working_resolution" in clip:
        _check_size("'clip' working_resolution", clip["working_resolution"])


def _check_passes(passes: dict[str, Any], clip: dict[str, Any]) -> None:
    """Every exported frame is one of the clip's, the passes are the clip's size, and the pattern names a file."""
    frames = passes["frames"]
    if not frames:
        raise ManifestError("manifest 'passes' lists no frames")
    known = set(clip["frame_numbers"])
    unknown = [f for f in frames if f not in known]
    if unknown or len(set(frames)) != len(frames):
        raise ManifestError(f"manifest 'passes' frames {_quote(unknown or frames)} are not distinct frames of the clip")
    if passes["resolution"] != clip["resolution"]:
        raise ManifestError("manifest 'passes' resolution is not the clip's")
    try:
        name = passes["pattern"].format(frame=frames[0])
    except (KeyError, IndexError, ValueError, AttributeError, TypeError):
        name = ""
    if not name or os.path.basename(name) != name or name in (os.curdir, os.pardir) or "\\" in name:
        raise ManifestError(f"manifest 'passes' pattern {_quote(passes['pattern'])} does not name a pass file")
    if not passes["dir"] or not passes["exr_layer"]:
        raise ManifestError("manifest 'passes' has an empty dir or exr_layer")


def is_layer_name(name: str) -> bool:
    """Whether ``name`` may name a layer (``MANIFEST_LAYER_NAME``): the engine's own names always do."""
    return len(name) <= MANIFEST_LAYER_NAME_MAX and MANIFEST_LAYER_NAME.fullmatch(name) is not None


def _check_layer(i: int, layer: Any) -> dict[str, Any]:
    where = f"layer {i}"
    _check_fields(where, layer, MANIFEST_LAYER_FIELDS, MANIFEST_OPTIONAL_LAYER_FIELDS)
    if layer["role"] not in (ROLE_BACKGROUND, ROLE_FOREGROUND):
        raise ManifestError(f"manifest {where} has unknown role {_quote(layer['role'])}")
    if layer["index"] != i:
        raise ManifestError(f"manifest {where} has index {_quote(layer['index'])}")
    if (layer["role"] == ROLE_BACKGROUND) != (i == 0):
        raise ManifestError(f"manifest {where} is a {layer['role']} layer (layer 0 is the background, only it)")
    texts = [layer[k] for k in ("name", "uv_pass", "alpha_pass", "atlas_exr", "atlas_png", "edit_layer")]
    if not all(texts) or not all(layer["uv_channels"] + layer["alpha_channels"]):
        raise ManifestError(f"manifest {where} has an empty name, pass, channel or path")
    if not is_layer_name(layer["name"]):
        raise ManifestError(
            f"manifest {where} name {_quote(layer['name'])} is not a plain name (letters, digits and _, "
            f"at most {MANIFEST_LAYER_NAME_MAX})"
        )
    if len(layer["uv_channels"]) != MANIFEST_UV_CHANNEL_COUNT or not layer["alpha_channels"]:
        raise ManifestError(f"manifest {where} does not name {MANIFEST_UV_CHANNEL_COUNT} UV channels and an alpha one")
    _check_size(f"{where} atlas_size", layer["atlas_size"])
    box = layer["atlas_box"]
    if len(box) != MANIFEST_BOX_NUMBERS or not all(math.isfinite(b) for b in box):
        raise ManifestError(f"manifest {where} atlas_box {_quote(box)} is not four finite numbers")
    return layer


def validate_manifest(data: Any) -> dict[str, Any]:
    """Check a decoded manifest against the schema above, the type of every field included; returns it, or raises
    ManifestError (one line). What passes is safe for the engine and the add-on to read without further checks."""
    if not isinstance(data, dict):
        raise ManifestError("manifest is not a JSON object")
    version = data.get(MANIFEST_TAG)
    if version != MANIFEST_VERSION or isinstance(version, bool):
        raise ManifestError(
            f"manifest version {_quote(version)} is not supported (this engine reads {MANIFEST_VERSION})"
        )
    _check_fields("", data, MANIFEST_FIELDS[""], {})
    for key in MANIFEST_KEYS:
        if key not in data:
            raise ManifestError(f"manifest has no {key!r}")
    for section in ("clip", "passes", "fit"):
        _check_fields(repr(section), data[section], MANIFEST_FIELDS[section], MANIFEST_OPTIONAL_FIELDS.get(section, {}))
    _check_clip(data["clip"])
    _check_passes(data["passes"], data["clip"])
    layers = data["layers"]
    if not isinstance(layers, list) or not layers:
        raise ManifestError("manifest has no layers")
    names = [_check_layer(i, layer)["name"] for i, layer in enumerate(layers)]
    if len(set(names)) != len(names):
        raise ManifestError(f"manifest layer names {_quote(names)} are not unique")
    if data["fit"]["steps"] < 0:
        raise ManifestError("manifest 'fit' steps is negative")
    if "scene" in data:
        validate_scene(data["scene"], len(layers))
    return data


#: Types of a scene record's fields (SCENE_FILE and a manifest's "scene").
SCENE_FIELDS: dict[str, str] = {
    "components": "str",
    "num_layers": "int",
    "layers_source": "str",
    "background_motion": "str",
    "flow": "bool",
    "active_terms": "str list",
    "reasons": "dict",
}


def validate_scene(scene: Any, num_layers: int | None = None) -> dict[str, Any]:
    """Check a scene analysis record (SCENE_FILE, or a manifest's "scene"); raises ManifestError (one line)."""
    if not isinstance(scene, dict):
        raise ManifestError("manifest 'scene' is not an object")
    for key in SCENE_KEYS:
        if key not in scene:
            raise ManifestError(f"manifest 'scene' has no {key!r}")
    if scene["background_motion"] not in BG_MOTIONS:
        raise ManifestError(f"manifest 'scene' has unknown background_motion {_quote(scene['background_motion'])}")
    if num_layers is not None and scene["num_layers"] != num_layers:
        raise ManifestError(
            f"manifest 'scene' says {_quote(scene['num_layers'])} layers but the manifest has {num_layers}"
        )
    if not isinstance(scene["active_terms"], list) or not isinstance(scene["reasons"], dict):
        raise ManifestError("manifest 'scene' active_terms is not a list or reasons is not an object")
    for key, kind in SCENE_FIELDS.items():
        if not _is_type(scene[key], kind):
            raise ManifestError(f"manifest 'scene' field {key!r} is not {_a(kind)}: {_quote(scene[key])}")
    return scene


def load_manifest(path: str) -> dict[str, Any]:
    """Read and validate ``manifest.json``; errors are one line naming the file and the fix."""
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except FileNotFoundError:
        raise ManifestError(f"{path}: no manifest here — run `python -m {CLI_MODULE} export RUN_DIR` first") from None
    except (OSError, ValueError, RecursionError) as exc:  # not JSON, not UTF-8, nested beyond the parser
        raise ManifestError(f"{path}: cannot be read ({type(exc).__name__}) — export the run again") from None
    try:
        return validate_manifest(data)
    except ManifestError as exc:
        raise ManifestError(f"{path}: {exc} — export the run again with this engine") from None


# --- definitions the engine and the add-on share (each computed here, once) ----------------------------------
#: The working resolution's long edge when none is asked for (``fit --set long_edge=N``, the add-on's Working Size).
DEFAULT_LONG_EDGE = 768
#: A mask image's pixel marks foreground above this fraction of full scale.
MASK_THRESHOLD = 0.5


def working_size(width: int, height: int, long_edge: int = DEFAULT_LONG_EDGE) -> tuple[int, int]:
    """Working ``(W, H)``: the long edge scaled to ``long_edge``, aspect kept, never enlarged; each side rounds
    half up (``floor(x + 0.5)``, not Python's half-to-even ``round``). 854x480 -> (768, 432)."""
    if width < 1 or height < 1 or long_edge < 1:
        raise ValueError(f"working_size needs positive sizes, got {width}x{height}, long_edge={long_edge}")
    scale = long_edge / max(width, height)
    if scale >= 1.0:
        return width, height
    return max(1, math.floor(width * scale + 0.5)), max(1, math.floor(height * scale + 0.5))


#: The sRGB transfer function (IEC 61966-2-1): encoded values at or below SRGB_ENCODED_CUTOFF decode through the
#: linear segment (divide by SRGB_SLOPE), the others as ((c + SRGB_OFFSET) / SRGB_SCALE) ** SRGB_GAMMA.
SRGB_ENCODED_CUTOFF = 0.04045
#: Linear values at or below this encode through the linear segment.
SRGB_LINEAR_CUTOFF = 0.0031308
SRGB_SLOPE = 12.92
SRGB_OFFSET = 0.055
SRGB_SCALE = 1.055
SRGB_GAMMA = 2.4


def srgb_to_linear(c: float) -> float:
    """Decode one sRGB-encoded value to linear by the exact IEC formula; values outside [0, 1] extend the curve
    symmetrically. (The engine and Blender decode images by OCIO's float32 form of this curve, which differs by up
    to 2.4e-5: ``engine.io.colour.srgb_to_linear``, docs/colour.md.)"""
    a = abs(c)
    lin = a / SRGB_SLOPE if a <= SRGB_ENCODED_CUTOFF else ((a + SRGB_OFFSET) / SRGB_SCALE) ** SRGB_GAMMA
    return math.copysign(lin, c)


def resolve_manifest_path(manifest_path: str, path: str) -> str:
    """A path written in a manifest, to READ through: relative to the manifest's folder with its symlinks resolved
    (the export computes them from there, so a run folder moved, mounted or linked elsewhere keeps working), then
    normalised; an absolute path (a plate on another drive) is taken as it is: the reader checks it exists."""
    if os.path.isabs(path):
        return path
    folder = os.path.realpath(os.path.dirname(os.path.abspath(manifest_path)))
    return os.path.normpath(os.path.join(folder, path))


#: What makes a file name a sequence pattern (``plate.####.exr``, ``plate.@@@@.exr``, ``plate.%04d.exr``).
SEQUENCE_TOKEN = re.compile(r"[#@]|%0?\d*d")


def _names_something(path: str) -> bool:
    """A file or folder that exists, or a sequence pattern whose folder does."""
    return os.path.exists(path) or (
        SEQUENCE_TOKEN.search(os.path.basename(path)) is not None and os.path.isdir(os.path.dirname(path))
    )


def resolve_plate_path(manifest_path: str, clip: dict[str, Any], index: int | None = None) -> str:
    """The manifest's plate to READ (``index`` None: its ``source``; else ``frame_files[index]``): as
    ``resolve_manifest_path``; where that names nothing but the path as it was at export (``source_absolute``,
    ``frame_files_absolute``) does, that one: a run folder moved alone still finds the plate it left behind."""
    if index is None:
        relative, absolute = clip["source"], clip.get("source_absolute")
    else:
        relative = clip["frame_files"][index]
        kept = clip.get("frame_files_absolute")
        absolute = kept[index] if isinstance(kept, list) and len(kept) == len(clip["frame_files"]) else None
    here = resolve_manifest_path(manifest_path, relative)
    if isinstance(absolute, str) and not _names_something(here) and _names_something(absolute):
        return absolute
    return here


def read_aligned_export(run_dir: str) -> str | None:
    """The export (``vNNN``) the run's edit layers match, as ``edits/aligned.json`` records it; None when there is no
    record. ValueError when the file is there but is not a record."""
    path = os.path.join(run_dir, EDITS_DIR, EDITS_ALIGNED)
    if not os.path.exists(path):
        return None
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
        version = data["export"] if data.get(EDITS_ALIGNED_TAG) == 1 else None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        version = None
    if not isinstance(version, str) or not re.fullmatch(r"v\d{3,}", version):
        raise ValueError(f"{path}: is not an edit-alignment record")
    return version


def manifest_run_root(manifest_path: str) -> str:
    """The run folder a manifest belongs to: RUN_DIR for ``RUN_DIR/exports/vNNN/manifest.json`` (found from where
    the manifest IS, so a run folder moved or mounted elsewhere keeps working), else the manifest's own folder."""
    folder = os.path.dirname(os.path.realpath(manifest_path))
    parent = os.path.dirname(folder)
    if os.path.basename(parent) == EXPORTS_DIR:
        return os.path.dirname(parent)
    return folder


def is_within(path: str, root: str) -> bool:
    """Whether ``path`` is ``root`` or lies below it once every symlink and ``..`` is resolved."""
    real, base = os.path.realpath(path), os.path.realpath(root)
    try:
        return os.path.commonpath([real, base]) == base
    except ValueError:  # different drives (Windows)
        return False


def manifest_write_roots(manifest_path: str) -> tuple[str, ...]:
    """The folders a manifest's paths may be written into: the run folder's ``edits/`` (the edit layers and their
    history) and the export's own folder (its previews); for a manifest outside ``RUN_DIR/exports`` its own
    folder. Never the run's records, its checkpoint or another export."""
    root, own = manifest_run_root(manifest_path), os.path.dirname(os.path.realpath(manifest_path))
    return (own,) if root == own else (os.path.join(root, EDITS_DIR), own)


def resolve_manifest_write_path(manifest_path: str, path: str) -> str:
    """A path written in a manifest, to WRITE through (edit layers, their history, previews): relative to the
    manifest, inside ``manifest_write_roots`` once symlinks and ``..`` are resolved; anything else raises
    ManifestError (one line). A manifest cannot make the engine or the add-on write anywhere else. (An absolute path
    is taken only where it lies there too: manifests written by hand or by older tools.)"""
    fix = "export the run again (a manifest's edit paths are relative and stay inside its run folder)"
    if not isinstance(path, str) or not path:
        raise ManifestError(
            f"{manifest_path}: write path {_quote(path, MANIFEST_QUOTE_PATH_CHARS)} is not a path — {fix}"
        )
    resolved = resolve_manifest_path(manifest_path, path)
    if not any(is_within(resolved, root) for root in manifest_write_roots(manifest_path)):
        where = "is absolute and outside" if os.path.isabs(path) else "leaves"
        quoted = _quote(path, MANIFEST_QUOTE_PATH_CHARS)
        raise ManifestError(
            f"{manifest_path}: write path {quoted} {where} the run folder's edits/ and this export — {fix}"
        )
    return resolved


# --- the run folder's lock ---------------------------------------------------------------------------------
#: Every writer of a run folder (fit, export, project-frame, preview, the add-on's Save Edits) holds an exclusive
#: lock on RUN_DIR/RUN_LOCK for the whole write; the OS releases it when the process ends, however it ends. The
#: file holds the holder's {"pid", "host", "what", "since"} so a second writer's one-line refusal can name it.
RUN_LOCK = ".neural_atlas.lock"
#: The fix printed when a run folder is locked by another process.
RUN_LOCKED_FIX = "wait for it to finish (or stop it), then run this again"


class RunLocked(Exception):
    """Another process holds the run folder's lock: the message names the holder (one line)."""

    def __init__(self, folder: str, holder: dict[str, Any]) -> None:
        self.folder = folder
        self.holder = holder
        who = f"{holder.get('what', 'another process')} (pid {holder.get('pid', '?')} on {holder.get('host', '?')}"
        since = holder.get("since")
        who += f", since {since})" if since else ")"
        super().__init__(f"{folder}: this run folder is in use by {who} — {RUN_LOCKED_FIX}")


#: The fix printed when a file the engine writes in place (the lock, the fit's log) is a link or not a plain file.
IN_PLACE_UNSAFE_FIX = "delete it (the engine makes a new one): the engine never writes through a link"


def in_place_problem(st: os.stat_result) -> str | None:
    """Why a file opened to be written in place (not through a temp file and a rename) must not be written, or
    None: a hard link (truncating or appending would change the other name's file too, outside the run folder
    perhaps) or not a plain file (a pipe, a device). A symbolic link never gets this far: it is opened with
    O_NOFOLLOW."""
    import stat

    if not stat.S_ISREG(st.st_mode):
        return "not a plain file"
    if st.st_nlink > 1:
        return f"a hard link ({st.st_nlink} names for one file)"
    return None


#: Open flags of a file written in place: a symbolic link at the name fails (ELOOP) rather than being followed;
#: non-blocking so a pipe planted there cannot hang the open (no effect on a plain file).
IN_PLACE_FLAGS = getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)


def open_in_place(path: str, flags: int, unsafe: type[Exception], *args: Any) -> int:
    """``os.open(path, flags)`` for a file written in place, never through a link: a symbolic link, a hard link,
    a folder or anything but a plain file at ``path`` raises ``unsafe(*args, path, what_it_is)`` (one line) and
    nothing is written."""
    import errno

    try:
        fd = os.open(path, flags | IN_PLACE_FLAGS, 0o666)
    except OSError as exc:
        if os.path.islink(path) or exc.errno in (errno.ELOOP, errno.EMLINK):
            raise unsafe(*args, path, "a symbolic link") from None
        if os.path.isdir(path):
            raise unsafe(*args, path, "a folder") from None
        raise
    problem = in_place_problem(os.fstat(fd))
    if problem is not None:
        os.close(fd)
        raise unsafe(*args, path, problem)
    return fd


class RunLockUnsafe(RunLocked):
    """RUN_DIR/RUN_LOCK is a symbolic link, a hard link or not a plain file: writing the holder into it would
    truncate and write another file (outside the run folder, perhaps). A ``RunLocked``, so every writer that
    refuses a folder in use in one line (the CLI, exit 2; the add-on's operators) refuses this one the same way."""

    def __init__(self, folder: str, path: str, what: str) -> None:
        Exception.__init__(self, f"{path}: the run folder's lock file is {what} — {IN_PLACE_UNSAFE_FIX}")
        self.folder = folder
        self.holder: dict[str, Any] = {}


#: Run folders this process holds, and how many times (a verb that calls another verb re-enters its lock).
_HELD_LOCKS: dict[str, list[Any]] = {}


def _try_lock(fd: int) -> bool:
    if os.name == "nt":  # pragma: no cover - Windows
        import msvcrt

        try:
            os.lseek(fd, 0, os.SEEK_SET)
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)  # type: ignore[attr-defined]
        except OSError:
            return False
        return True
    import fcntl

    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


def _read_holder(path: str) -> dict[str, Any]:
    try:
        with open(path, "rb") as f:
            f.seek(1)  # byte 0 is the one Windows locks
            data = json.loads(f.read().decode("utf-8") or "{}")
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


@contextlib.contextmanager
def run_lock(folder: str | os.PathLike[str], what: str) -> Iterator[None]:
    """Hold RUN_DIR's exclusive lock for the ``with`` block (creating the folder); raises RunLocked at once when
    another process holds it. Re-entrant within one process. ``what`` names the holder in others' messages."""
    import datetime
    import socket

    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    key = os.path.realpath(folder)
    held = _HELD_LOCKS.get(key)
    if held is not None:
        held[1] += 1
        try:
            yield
        finally:
            held[1] -= 1
        return
    path = os.path.join(folder, RUN_LOCK)
    fd = open_in_place(path, os.O_RDWR | os.O_CREAT, RunLockUnsafe, folder)
    try:
        if not _try_lock(fd):
            raise RunLocked(folder, _read_holder(path))
        since = datetime.datetime.now().astimezone().isoformat(timespec="seconds")
        holder = {"pid": os.getpid(), "host": socket.gethostname(), "what": what, "since": since}
        os.ftruncate(fd, 1)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, b" " + json.dumps(holder).encode("utf-8"))
        _HELD_LOCKS[key] = [fd, 1]
        try:
            yield
        finally:
            del _HELD_LOCKS[key]
    finally:
        os.close(fd)  # closing the descriptor releases the lock
