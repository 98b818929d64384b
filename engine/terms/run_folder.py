"""The run folder: the names of its files and folders, the scene analysis's choices, the version of each file
(engine/fit/run_files.py declares their shapes) and the checkpoint's keys."""

from __future__ import annotations

from .versions import SCHEMA_VERSION

RUN_CONFIG = "config.json"
RUN_METRICS = "metrics.json"
RUN_CHECKPOINT = "checkpoint.pt"
RUN_CLIP = "clip.json"  # what was fitted: source, frame range, sizes, content fingerprint
RUN_LOG = "fit.log"
FLOW_CACHE_DIR = "flow_cache"
#: The name (before ".npz") of a flow cache file: a SHA-256 in hex of what the flow was computed from (the frames,
#: the flow's settings); clip.json's "flow_key" names the fit's own this way.
FLOW_KEY_PATTERN = "[0-9a-f]{64}"
#: The scene analysis of a fit (engine.data.scene_analysis.SceneAnalysis as JSON): which components the run computes,
#: and why.
#: {"schema": SCHEMA_VERSION, "components": "auto"|"all", "num_layers": int, "layers_source": SCENE_LAYERS_*,
#:  "background_motion": BG_MOTION_*, "flow": bool, "scribbles": int, "alpha_network": bool,
#:  "active_terms": [str], "reasons": {decision: one line}, "measured": {name: number|null},
#:  "overrides": [str] (what components=all forced on that the analysis would have left off)}
SCENE_FILE = "scene.json"
#: The part of it a manifest carries ("scene"), each key with its type: one declaration for both readers.
SCENE_FIELDS: dict[str, str] = {
    "components": "str",
    "num_layers": "int",
    "layers_source": "str",
    "background_motion": "str",
    "flow": "bool",
    "active_terms": "str list",
    "reasons": "dict",
}
SCENE_KEYS: tuple[str, ...] = tuple(SCENE_FIELDS)
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
#: ``fit --mask FOLDER --auto-parts``: split the one object into the parts that move apart (``parts``), strokes
#: written to RUN_DIR/parts/ (checked, fixed or deleted by the artist; used as they are when already there), and
#: fit with them as --scribbles; an object that moves as one piece is fitted as one layer. Without either flag a fit
#: does so wherever it applies (one --mask, no --scribbles or --auto-masks, a fast model, two frames or more);
#: ``--no-auto-parts`` fits the object as one layer.
FIT_AUTO_PARTS_FLAG = "--auto-parts"
FIT_NO_AUTO_PARTS_FLAG = "--no-auto-parts"
AUTO_PARTS_DIR = "parts"

# --- run folder files: their versions -----------------------------------------------------------------------
# Each JSON file of a run folder carries {"schema": <its version>}, bumped whenever its shape changes; a reader
# refuses any other version (the run was made by another engine: fit again). engine/fit/run_files.py declares each
# file's shape (RUN_CONFIG, RUN_CLIP, RUN_METRICS, SCENE_FILE) and checks it; engine/fit/run_folder.py is the one
# module that reads and writes them. The checkpoint:
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
#: The fix for a run file of another engine version (a refused schema).
RUN_FILE_OTHER_VERSION_FIX = "fit into a new run folder or use the engine version that made this run"
#: The fix for a run file that is damaged (not JSON, a key missing or of the wrong type).
RUN_FILE_DAMAGED_FIX = "restore it, or fit into a new run folder"

#: What ``engine.contract`` re-exports from this module (its own names, not its imports).
__all__ = [
    "AUTO_MASKS_DIR",
    "AUTO_PARTS_DIR",
    "BG_MOTIONS",
    "BG_MOTION_DEFORMABLE",
    "BG_MOTION_PAN_ZOOM",
    "BG_MOTION_STATIC",
    "FIT_AUTO_MASKS_FLAG",
    "FIT_AUTO_PARTS_FLAG",
    "FIT_NO_AUTO_PARTS_FLAG",
    "FLOW_CACHE_DIR",
    "FLOW_KEY_PATTERN",
    "RUN_CHECKPOINT",
    "RUN_CHECKPOINT_KEYS",
    "RUN_CHECKPOINT_SCHEMA",
    "RUN_CHECKPOINT_SCHEMA_WITHOUT_CONFIG",
    "RUN_CLIP",
    "RUN_CLIP_SCHEMA",
    "RUN_CONFIG",
    "RUN_CONFIG_SCHEMA",
    "RUN_FILE_DAMAGED_FIX",
    "RUN_FILE_OTHER_VERSION_FIX",
    "RUN_LOG",
    "RUN_METRICS",
    "RUN_METRICS_SCHEMA",
    "RUN_SCENE_SCHEMA",
    "SCENE_FIELDS",
    "SCENE_FILE",
    "SCENE_KEYS",
    "SCENE_LAYERS_AUTO",
    "SCENE_LAYERS_GIVEN",
    "SCENE_LAYERS_NONE",
]
