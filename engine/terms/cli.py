"""The command line the add-on, a farm and a person drive the engine with: the module ``python -m`` runs, the
verbs and their flags, the presets' step budgets, the exit codes, and the add-on's headless script the engine starts."""

from __future__ import annotations

#: The import name a pip install of the wheel gives the engine (pyproject.toml maps it onto the repository's engine/):
#: ours, so the engine never takes or meets another project's top-level ``engine``.
INSTALLED_MODULE = "neural_atlas"
#: What ``python -m`` runs: the installed name when this engine came from the wheel, else ``engine`` (a checkout, or
#: the extension's bundled engine on the engine Python's PYTHONPATH).
CLI_MODULE = INSTALLED_MODULE if __name__ == f"{INSTALLED_MODULE}.terms.cli" else "engine"
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
#: parts CLIP --mask FOLDER --out FOLDER [--frames FIRST-LAST]: strokes (scribble images) splitting the one masked
#: object into the parts that move apart; last stdout line = the strokes folder, or the line saying nothing was split
VERB_PARTS = "parts"
VERB_NUKE = "nuke"  # nuke MANIFEST [--out FILE.nk] [--filter ...]: a Nuke script of the edit; last line = its path
#: relink MANIFEST --plate PATH: the export reads its plate at PATH (the manifest's plate paths and the export's own
#: .nk rewritten); one line per file it fixed or left, the manifest's path last
VERB_RELINK = "relink"
RELINK_PLATE_ARG = "--plate"
#: realign MANIFEST [--from vNNN|OLD_MANIFEST] [--layer NAME ...] [--frame-step N] [--measure]: move the edit layers
#: painted against an earlier export of the run onto MANIFEST's mapping (after ``fit --refine``); last line = MANIFEST
VERB_REALIGN = "realign"
#: ``--frames`` of every verb speaks the plate's frame numbers (plate.1010.exr .. plate.1050.exr: 1010-1050; a movie's
#: frames count from 0 or ``fit --start-frame``); run folders keep recording positions (clip.json "frame_range").


#: ``export RUN --into vNNN``: export into that version (a farm's export tasks share one); ``--stage`` splits it
#: into the tasks a farm runs: ``atlases`` (once), ``passes --frames A-B`` (chunks, concurrently), ``publish``
#: (once, when every chunk is done: the version appears with its manifest). Each is idempotent.
EXPORT_INTO_ARG = "--into"
EXPORT_STAGE_ARG = "--stage"
EXPORT_STAGES: tuple[str, ...] = ("atlases", "passes", "publish")
#: Each layer's UV averaged along optical flow where it slips against it, so paint follows a
#: deforming body from frame to frame: on by default. ``--follow-flow`` insists (a run with no flow to follow is
#: refused), ``--no-follow-flow`` exports the UV as fitted. A staged export decides it in its ``atlases`` stage.
EXPORT_FOLLOW_FLOW_FLAG = "--follow-flow"
EXPORT_NO_FOLLOW_FLOW_FLAG = "--no-follow-flow"
#: ``export --pass-precision compact|full`` (``PASS_PRECISIONS``; default compact): the bits the pass files keep.
#: A staged export decides it in its ``atlases`` stage.
EXPORT_PASS_PRECISION_ARG = "--pass-precision"
#: ``export --stmap``: each pass file also holds an STMap copy of each layer's UV (``STMap<Layer>``: R, G = u, v; A =
#: the coverage) for artists who wire Nuke's STMap by hand. Off by default: above ~1000 px wide ZIP cannot share its
#: bytes with the UV pass, so it nearly doubles the file; the Nuke script reads the UV pass itself. A staged export
#: decides it in its ``atlases`` stage.
EXPORT_STMAP_FLAG = "--stmap"
#: ``fit ... --resume-if-started``: a retried farm task: continue the checkpoint of this same fit in RUN_DIR, leave
#: a finished one as it is (exit 0), or start it.
FIT_RESUME_IF_STARTED_FLAG = "--resume-if-started"
#: ``fit --out RUN --refine STEPS [--preset P]``: continue a FINISHED fit for STEPS more steps (with preset P's
#: schedule where the checkpoint allows it), recording first which export the edit layers were painted against
#: (``EDITS_ALIGNED``) so ``realign`` can carry the paint onto the refined fit's next export.
FIT_REFINE_FLAG = "--refine"


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
#: The clip length each preset is tuned for (``FitConfig.batch_frames`` and ``mapping_time_frames``; 0: none): a
#: longer clip draws more pixels a step in proportion, so its steps cost more so (the add-on's documented estimate
#: scales them), and its mappings see a frame's step in time as such a clip's do.
PRESET_CLIP_FRAMES: dict[str, int] = {"draft": 70, "balanced": 70, "final": 70, "paper": 0}
#: The preset of a new fit that names none: `fit` without --preset, a farm shot without ``preset``.
DEFAULT_PRESET = "balanced"

EXIT_OK = 0
EXIT_FAILED = 1  # an engine bug or an unexpected error: the log has the traceback
EXIT_BAD_INPUT = 2  # the user's input is wrong: one line on stderr names the file and the fix
EXIT_CANCELLED = 3  # SIGINT/SIGTERM: one line; nothing half-written is kept; a fit checkpointed: --resume continues
#: The fit diverged (a non-finite loss, gradient or parameter): one line names the step and the likely cause;
#: nothing past the last good checkpoint was saved, so `fit --resume --set lr=...` continues from it.
EXIT_DIVERGED = 4

#: What ``engine.contract`` re-exports from this module (its own names, not its imports).
__all__ = [
    "CLI_MODULE",
    "DEFAULT_PRESET",
    "ESTIMATE_TAG",
    "EXIT_BAD_INPUT",
    "EXIT_CANCELLED",
    "EXIT_DIVERGED",
    "EXIT_FAILED",
    "EXIT_OK",
    "EXPORT_FOLLOW_FLOW_FLAG",
    "EXPORT_INTO_ARG",
    "EXPORT_NO_FOLLOW_FLOW_FLAG",
    "EXPORT_PASS_PRECISION_ARG",
    "EXPORT_STAGES",
    "EXPORT_STAGE_ARG",
    "EXPORT_STMAP_FLAG",
    "FIT_REFINE_FLAG",
    "FIT_RESUME_IF_STARTED_FLAG",
    "HEADLESS_SCRIPT",
    "INSTALLED_MODULE",
    "PRESET_CLIP_FRAMES",
    "PRESET_STEPS",
    "RELINK_PLATE_ARG",
    "VERB_DEMO",
    "VERB_ESTIMATE",
    "VERB_EXPORT",
    "VERB_FIT",
    "VERB_MASKS",
    "VERB_NUKE",
    "VERB_PARTS",
    "VERB_PREVIEW",
    "VERB_PROJECT_FRAME",
    "VERB_REALIGN",
    "VERB_RELINK",
    "VERB_RENDER",
]
