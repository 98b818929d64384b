"""A farm: one plan of a sequence's shots, run by the schedulers studios already have (``engine farm``): its
commands, the shots file's keys, and the Flamenco job type and API it submits to."""

from __future__ import annotations

VERB_FARM = "farm"  # farm plan|openjd|dask|flamenco SHOTS ...: see docs/farm.md
FARM_PLAN = "plan"  # farm plan SHOTS [--json]: every task's engine arguments and dependencies
FARM_OPENJD = "openjd"  # farm openjd SHOTS --out BUNDLE_DIR: an Open Job Description bundle (Deadline Cloud)
FARM_DASK = "dask"  # farm dask SHOTS --scheduler tcp://HOST:PORT: the plan's tasks on a Dask cluster
FARM_FLAMENCO = "flamenco"  # farm flamenco SHOTS --manager URL: one job per shot on a Flamenco Manager
FARM_COMMANDS: tuple[str, ...] = (FARM_PLAN, FARM_OPENJD, FARM_DASK, FARM_FLAMENCO)


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
    "follow_flow",  # false: export --no-follow-flow (default true: export's own default)
    "pass_precision",  # export --pass-precision: compact | full (default: export's own, compact)
    "stmap",  # true: export --stmap, an STMap copy of each layer's UV in the pass files (default false)
)
SHOT_REQUIRED_KEYS: tuple[str, ...] = ("name", "plate")
#: A shot's name: letters, digits, ``-`` and ``_``, starting with a letter or digit, at most this long: it names the
#: shot's tasks, its run folder and (with a kind: ``sh010-atlases``) an OpenJD step, whose names hold 64 characters.
SHOT_NAME_MAX = 48
SHOT_KEYS: tuple[str, ...] = (
    *SHOT_REQUIRED_KEYS,
    "masks",  # mask folders, one per foreground layer
    "auto_masks",  # true: find the moving objects (a masks task before the fit)
    "auto_parts",  # false: fit --no-auto-parts (one layer); true: --auto-parts; absent: the fit's default
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

#: What ``engine.contract`` re-exports from this module (its own names, not its imports).
__all__ = [
    "FARM_COMMANDS",
    "FARM_DASK",
    "FARM_FLAMENCO",
    "FARM_OPENJD",
    "FARM_PLAN",
    "FLAMENCO_API_CHECK",
    "FLAMENCO_API_SUBMIT",
    "FLAMENCO_JOB_TYPE",
    "FLAMENCO_PYTHON_VARIABLE",
    "SHOTS_DEFAULTS_KEY",
    "SHOTS_LIST_KEY",
    "SHOTS_TAG",
    "SHOTS_VERSION",
    "SHOT_DEFAULT_KEYS",
    "SHOT_KEYS",
    "SHOT_NAME_MAX",
    "SHOT_REQUIRED_KEYS",
    "VERB_FARM",
]
