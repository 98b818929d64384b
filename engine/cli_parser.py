"""The command line's parser: every verb's arguments and help (``build_parser``); the handlers that run them are
``cli_commands``, the options several verbs share ``cli_options``. Building it imports no torch: ``--help`` and
a bad argument answer at once."""

from __future__ import annotations

import argparse
import functools

from . import contract as C
from .cli_options import (
    CLIP_HELP,
    MANIFEST_HELP,
    RAW_HELP,
    add_device,
    add_follow_flow,
    add_layers,
    add_no_bar,
    add_output_options,
    add_plate_frames,
    add_preset,
    add_set,
    add_threads,
    add_verb,
    frame_range,
    frame_rate,
    start_frame,
)
from .terms.cli import (
    DEFAULT_PRESET,
    EXPORT_INTO_ARG,
    EXPORT_PASS_PRECISION_ARG,
    EXPORT_STAGE_ARG,
    EXPORT_STAGES,
    EXPORT_STMAP_FLAG,
    FIT_RESUME_IF_STARTED_FLAG,
    VERB_DEMO,
    VERB_NUKE,
    VERB_PREVIEW,
    VERB_RENDER,
)
from .terms.export_names import (
    ATLAS_SIZE_DEFAULT,
    NUKE_SCRIPT_NAME,
    PASS_PRECISION_COMPACT,
    PASS_PRECISION_FULL,
    PASS_PRECISIONS,
)
from .terms.farm import FARM_DASK, FARM_PLAN
from .terms.run_folder import AUTO_PARTS_DIR, FIT_AUTO_MASKS_FLAG, FIT_AUTO_PARTS_FLAG, FLOW_CACHE_DIR
from .terms.versions import ENGINE_VERSION

DESCRIPTION = """\
Neural Atlas engine: fit layered neural atlases (Kasten et al. 2021) to a clip.

A fit decomposes the clip into a background atlas and one atlas per foreground mask, with a per-pixel
mapping into each atlas and a per-pixel opacity, so paint on an atlas sticks to the object in every frame.
"""

FIT_EPILOG = """\
presets (accuracy vs time on a 2-core CPU at 768x432; see docs/accuracy-vs-time.md):
  draft     fast model, a few minutes: check the decomposition
  balanced  fast model, the default
  final     fast model, the longest budget
  paper     the paper's exact architecture (400k steps: days on a CPU; the baseline)

progress: one JSON object per stdout line ({"neural_atlas": 1, "event": ...}); a bar on stderr.
exit codes: 0 done, 1 engine error, 2 bad input, a full disk or a run folder in use (one line names the file
            and the fix), 3 cancelled by SIGINT/SIGTERM (a checkpoint was written: --resume continues),
            4 the fit diverged: its loss, gradients or parameters became NaN/Inf (one line names the step and
            the likely cause; nothing past the last good checkpoint was kept: --resume --set lr=... continues).
"""


def build_parser(prog: str = f"python -m {C.CLI_MODULE}") -> argparse.ArgumentParser:
    """The engine's command line: every verb, with -q and -v on the engine and on each of them."""
    p = argparse.ArgumentParser(prog=prog, description=DESCRIPTION, formatter_class=RAW_HELP)
    p.add_argument("--version", action="version", version=f"neural-atlas engine {ENGINE_VERSION}")
    sub = p.add_subparsers(dest="verb", metavar="VERB")
    _add_fit_parser(sub)
    _add_demo_parser(sub)
    _add_estimate_parser(sub)
    _add_export_parser(sub)
    _add_render_parser(sub)
    _add_project_frame_parser(sub)
    _add_realign_parser(sub)
    _add_preview_parser(sub)
    _add_masks_parser(sub)
    _add_parts_parser(sub)
    _add_nuke_parser(sub)
    _add_relink_parser(sub)
    _add_farm_parser(sub)
    add_output_options(p)
    return p


@functools.cache
def verb_flags(verb: str) -> dict[str, str]:
    """Each option of ``verb`` (``terms.cli.VERB_*``) by its destination, as this parser declares it (``start_frame``:
    ``--start-frame``): a command line built for the engine (the farm's plan) names the flags from here, so a flag
    renamed here cannot leave a farm task asking for the old one. A pair of flags that share a destination
    (``--auto-parts`` / ``--no-auto-parts``) keeps only the last here: the contract's terms name each of those
    (``FIT_AUTO_PARTS_FLAG``, ...)."""
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    parser = sub.choices[verb]
    return {a.dest: a.option_strings[-1] for a in parser._actions if a.option_strings and a.dest != "help"}


def _add_fit_parser(sub: argparse._SubParsersAction) -> None:
    """``fit``: the plate, its masks and how it is read, the run folder and the config."""
    f = add_verb(
        sub,
        C.VERB_FIT,
        help="fit atlases to a clip",
        epilog=FIT_EPILOG,
        description="Fit a background atlas and one foreground atlas per --mask folder.",
    )
    f.add_argument(
        "clip",
        nargs="?",
        help="image-sequence folder (png/jpg/exr/dpx/tif), sequence pattern (plates/plate.####.exr, plate.%%04d.exr, "
        "plate.1001-1100#.exr) or movie file",
    )
    f.add_argument(
        "--mask",
        action="append",
        default=[],
        metavar="FOLDER",
        help=f"foreground mask sequence, one folder per foreground layer (>{C.MASK_THRESHOLD} = foreground)",
    )
    f.add_argument(
        C.SCRIBBLE_ARG,
        default=None,
        metavar="FOLDER",
        help="split the one --mask object into layers: red/green/... strokes per frame (paper Sec. 4.4)",
    )
    f.add_argument(
        FIT_AUTO_MASKS_FLAG,
        dest="auto_masks",
        action="store_true",
        help=f"no masks: find moving objects (masks written to RUN_DIR/{C.AUTO_MASKS_DIR} for checking) and fit "
        f"them; nothing moving gives a background-only fit. A full set of masks already in RUN_DIR/{C.AUTO_MASKS_DIR} "
        "(written by `masks`, or fixed by hand) is used as it is. Without --mask or this, the fit is background-only",
    )
    f.add_argument(
        FIT_AUTO_PARTS_FLAG,  # and C.FIT_NO_AUTO_PARTS_FLAG, which the action derives from it
        dest="auto_parts",
        action=argparse.BooleanOptionalAction,
        default=None,
        help=f"split the one --mask object into the parts that move apart (a limb swinging across the body), as "
        f"`{C.VERB_PARTS}` then {C.SCRIBBLE_ARG} would; the strokes are written to RUN_DIR/{AUTO_PARTS_DIR} for "
        "checking, and strokes already there (an earlier fit's, or fixed by hand) are used as they are. An object "
        "that moves as one piece is fitted as one layer. Default: on wherever it applies (one --mask, no "
        f"{C.SCRIBBLE_ARG} or {FIT_AUTO_MASKS_FLAG}, a fast preset, two frames or more); {FIT_AUTO_PARTS_FLAG} "
        f"insists (refused where it cannot apply), {C.FIT_NO_AUTO_PARTS_FLAG} fits the object as one layer",
    )
    f.add_argument(
        "--out",
        default=None,
        metavar="RUN_DIR",
        help="run folder (created; a folder that holds a fit takes --resume or --refit; one in use by another "
        "process is refused)",
    )
    add_preset(f, None, f"draft | balanced | final | paper (default: {DEFAULT_PRESET}; not with --resume)")
    add_device(f, "auto")
    _add_fit_plate_options(f)
    _add_fit_run_options(f)


def _add_fit_plate_options(f: argparse.ArgumentParser) -> None:
    """``fit``'s options on how the plate is read (its frames, rate, numbering, colour space) and the config."""
    add_plate_frames(f)
    f.add_argument(
        "--fps",
        type=frame_rate,
        default=None,
        metavar="RATE",
        help="the plate's frame rate (24, 25, 23.976 = 24000/1001): for a sequence whose files state none (EXR and "
        "DPX may); it overrides the files'. Recorded, and used for the movies written from the fit",
    )
    f.add_argument(
        "--start-frame",
        type=start_frame,
        default=None,
        metavar="N",
        help="number a movie's frames from N (e.g. 1001; default 0); a sequence is numbered by its file names",
    )
    f.add_argument(
        "--colorspace",
        default=None,
        metavar="NAME",
        help="the plate's OCIO colour space (a name or alias of $OCIO's config, else of the built-in ACES CG config: "
        "ACEScg, ACEScct, 'sRGB Encoded Rec.709 (sRGB)', 'Linear Rec.709 (sRGB)', ...; default: what the file's header "
        "says (an EXR's oiio:ColorSpace, ACES chromaticities), the config's file rules, else float files scene-linear "
        "Rec.709, integer files and movies sRGB, said in a note: line and recorded as assumed; see docs/colour.md)",
    )
    add_set(f, "override any config field (see --help-config)")


def _add_fit_run_options(f: argparse.ArgumentParser) -> None:
    """``fit``'s options for a run folder that holds a fit (resume, refit, refine), and its output."""
    f.add_argument(
        "--resume",
        action="store_true",
        help="continue the fit in RUN_DIR from its checkpoint, with the clip, masks and config it started with; "
        "--set may change only the schedule (steps, the learning rates, eval_every, eval_pixels, "
        "checkpoint_seconds: see --help-config)",
    )
    f.add_argument(
        "--refit",
        action="store_true",
        help="fit again into RUN_DIR although it holds a fit: its config, clip record, scene, checkpoint and "
        "metrics are replaced; its edit layers (edits/) and earlier exports (exports/) are kept as they are",
    )
    f.add_argument(
        FIT_RESUME_IF_STARTED_FLAG,
        dest="resume_if_started",
        action="store_true",
        help="for a task a farm retries with the same arguments: RUN_DIR without a checkpoint starts the fit; with a "
        "checkpoint of this same fit (the clip, masks, frames and --preset given are the recorded ones, --set "
        "changes only the schedule, as for --resume) continues it; with this fit finished does nothing (exit 0)",
    )
    f.add_argument(
        C.FIT_REFINE_FLAG,
        dest="refine",
        type=int,
        nargs="?",
        const=0,
        default=None,
        metavar="STEPS",
        help="continue the FINISHED fit in RUN_DIR for STEPS more steps (with --preset P: P's learning rates and "
        "schedule, and without STEPS on to P's step budget; a preset the checkpoint was not trained for is refused). "
        "Edit layers and exports are kept; the export the paint was made on is recorded (edits/aligned.json) so "
        f"`{C.VERB_REALIGN}` carries the paint onto the next export",
    )
    add_no_bar(f, "no progress bar on stderr (JSON lines only)")
    f.add_argument("--help-config", action="store_true", help="list every config field and exit")


def _add_demo_parser(sub: argparse._SubParsersAction) -> None:
    """``demo``: the embedded demo clip fitted."""
    d = add_verb(
        sub,
        VERB_DEMO,
        help="fit the embedded demo clip (README command 1)",
        description="Generate the demo plate, fit it, and write a contact sheet. Idempotent.",
    )
    d.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    add_preset(d, "draft", "preset (default: draft)")
    add_set(d, "override a config field")


def _add_estimate_parser(sub: argparse._SubParsersAction) -> None:
    """``estimate``: each preset's fit time on this machine and clip."""
    e = add_verb(
        sub,
        C.VERB_ESTIMATE,
        help="estimated fit time of each preset on this machine and clip",
        description="Time a few training steps of each preset on the clip and multiply by its step budget. Every "
        "preset asked for gets a row; one that cannot fit this clip (paper: exactly one --mask) says why instead.",
    )
    e.add_argument("clip", help=CLIP_HELP)
    e.add_argument("--mask", action="append", default=[], metavar="FOLDER", help="mask folder per foreground layer")
    e.add_argument("--presets", default=None, help="comma-separated (default: every preset)")
    add_plate_frames(e)
    e.add_argument("--calib-seconds", type=float, default=2.0, help="timed seconds per preset and regime")
    e.add_argument("--work", default=None, metavar="RUN_DIR", help="keep the flow cache here (a fit reuses it)")
    add_set(e, "override a config field")
    add_device(e, "auto")
    add_threads(e)
    e.add_argument("--json", action="store_true", help="print one JSON object (contract.ESTIMATE_TAG) instead")


def _add_export_parser(sub: argparse._SubParsersAction) -> None:
    """``export``: a fitted run's passes, atlases, edit layers and manifest (whole, or one stage of it)."""
    x = add_verb(
        sub,
        C.VERB_EXPORT,
        help="write UV + alpha EXR passes, atlas textures, edit layers and a manifest",
        description="Export a fitted run for compositing into RUN_DIR/exports/vNNN (never overwritten), holding "
        "the run folder's lock. Passes are float32 EXR at the plate's native resolution; edit layers (RUN_DIR/edits) "
        "are created once and never overwritten. The manifest's paths are relative to it, so the run folder can move "
        "with its plate. The last line printed is the manifest's path (--stage atlases and passes: the staging "
        "folder).",
    )
    x.add_argument("run", metavar="RUN_DIR", help="the --out folder of a fit")
    x.add_argument(
        "--atlas-size",
        type=int,
        default=None,
        help=f"atlas texture long side in texels (default: {ATLAS_SIZE_DEFAULT}; publish: the staged one)",
    )
    x.add_argument(
        "--frames",
        type=frame_range,
        default=None,
        metavar="FIRST-LAST",
        help="inclusive range of the plate's frame numbers, as for fit (default: every fitted frame; passes: the "
        "chunk to write, default the staged range)",
    )
    add_device(x, "cpu")
    x.add_argument(
        EXPORT_INTO_ARG,
        dest="into",
        default=None,
        metavar="vNNN",
        help=f"export into RUN_DIR/{C.EXPORTS_DIR}/vNNN (its manifest path is known before it runs) rather than the "
        "next free version; already exported there with the same frames and atlas size: nothing to do, the "
        "manifest's path is printed (a retried task succeeds); with others: refused",
    )
    x.add_argument(
        EXPORT_STAGE_ARG,
        dest="stage",
        default=None,
        choices=EXPORT_STAGES,
        help=f"one part of the export {EXPORT_INTO_ARG} vNNN, for a farm: atlases (once, holding the lock: the "
        f"layer frames and atlas textures into {C.EXPORTS_DIR}/.vNNN.chunks), passes --frames A-B (chunks, at once "
        "on several hosts, no lock: frames already written are skipped, a cancel keeps the finished ones), publish "
        "(once every chunk is done: edit layers, manifest and Nuke script, then the folder becomes vNNN). The files "
        "are those of a whole export, byte for byte; each part run again is idempotent",
    )
    add_follow_flow(
        x,
        None,
        "average each layer's UV along optical flow where it slips against it (a body that bends: "
        "legs, a rider; cars moving in the background), so paint follows it from frame to frame; layers that "
        "already follow the flow "
        f"are left as fitted. The flow: the export's own on the plate, or where the plate cannot be read, the fit's "
        f"in RUN_DIR/{FLOW_CACHE_DIR}. On by default where there is flow to follow; this flag "
        f"insists (refused without it). A staged export decides it in its {EXPORT_STAGES[0]} stage",
        "export each layer's UV as fitted (the atlas alone, as exports before the flow was followed)",
    )
    x.add_argument(
        EXPORT_PASS_PRECISION_ARG,
        dest="precision",
        default=None,
        choices=PASS_PRECISIONS,
        help=f"the bits the pass files keep, every channel float32 either way: {PASS_PRECISION_COMPACT} (default) "
        "rounds alpha and coverage down to half float's precision (at most 4.9e-4 off) and u, v to multiples of 2^-17 "
        f"(0.03 texel on a 4096 atlas): half the bytes; {PASS_PRECISION_FULL} keeps every bit the networks give. "
        f"A staged export decides it in its {EXPORT_STAGES[0]} stage",
    )
    x.add_argument(
        EXPORT_STMAP_FLAG,
        dest="stmap",
        action="store_const",
        const=True,
        default=None,
        help="also write each layer's UV as an STMap layer (STMap<Layer>: R, G = u, v; A = coverage) in every pass "
        "file, for an STMap wired by hand in Nuke (the exported Nuke script reads the UV pass itself). Off by "
        "default: at 2K and 4K it nearly doubles each file. A staged export decides it in its "
        f"{EXPORT_STAGES[0]} stage",
    )
    add_no_bar(x)


def _add_render_parser(sub: argparse._SubParsersAction) -> None:
    """``render``: the edited clip from an export's edit layers over the plate."""
    r = add_verb(
        sub,
        VERB_RENDER,
        help="render the edited clip from an export (the paper's edit equations)",
        description="Blend each layer's edit layer (sampled at its UV) over the ORIGINAL plate, layers weighted "
        "by the learned alpha. With every edit layer empty the output is the plate. The frames (and the movie) "
        "appear together once all are written, or none does; --out and --movie may not be the plate's folder, a "
        "mask folder or inside the run folder.",
    )
    r.add_argument("manifest", metavar="MANIFEST", help=MANIFEST_HELP)
    r.add_argument("--edit", action="append", default=[], metavar="LAYER=IMAGE", help="use IMAGE as LAYER's edit")
    r.add_argument(
        "--out",
        required=True,
        metavar="DIR",
        help="folder for the frames (edit.1001.exr ...: numbered as the plate's frames, padded as its files are), "
        "outside the run folder",
    )
    r.add_argument(
        "--name",
        default=None,
        metavar="PATTERN",
        help="the frames' file name, with one frame token: #### (a digit each) or %%04d, and the format's extension "
        "(e.g. shot_v001.####.exr; default: edit. + the plate's padding)",
    )
    r.add_argument(
        "--format",
        default="exr",
        choices=["exr", "png", "plate"],
        help="exr (float: the plate's colour space when scene-linear, else scene-linear Rec.709; default), png "
        "(8-bit sRGB) or plate (the plate's file type, bit depth and colour space: an empty edit gives the plate back)",
    )
    r.add_argument(
        "--depth",
        default=None,
        choices=["16", "32"],
        help="bits per channel of --format exr frames: 16 (half float) or 32 (float); default: the plate's own when it "
        "is an EXR (a half plate gives half frames), else 32",
    )
    r.add_argument("--filter", default="bilinear", choices=["bilinear", "nearest"], help="texture filter")
    r.add_argument(
        "--frames",
        type=frame_range,
        default=None,
        metavar="FIRST-LAST",
        help="only these exported frames (the plate's frame numbers; default: every exported frame): one chunk of a "
        "render several tasks share. Its frames join those other chunks wrote into --out (the files one whole render "
        "writes); a chunk run again writes the same files again. With --movie: a movie of these frames",
    )
    r.add_argument("--movie", default=None, metavar="FILE.mp4", help="also write an H.264 movie")
    add_no_bar(r)


def _add_project_frame_parser(sub: argparse._SubParsersAction) -> None:
    """``project-frame``: paint made on one plate frame landed on the edit layers."""
    pf = add_verb(
        sub,
        C.VERB_PROJECT_FRAME,
        help="land paint made on one frame on the atlases' edit layers",
        description="IMAGE is RGBA paint over plate frame N (transparent where unpainted). The paint goes to the "
        "layers that own each pixel and is composited over their edit layers (the old ones are kept in "
        "edits/history), all together, holding the run folder's lock.",
    )
    pf.add_argument("manifest", metavar="MANIFEST")
    pf.add_argument("--frame", type=int, required=True, metavar="N", help="plate frame number the paint was made on")
    pf.add_argument("--edit", required=True, metavar="IMAGE", help="RGBA paint, the plate's size")
    add_layers(pf)


def _add_realign_parser(sub: argparse._SubParsersAction) -> None:
    """``realign``: edit layers carried from an earlier export onto a refined fit's."""
    ra = add_verb(
        sub,
        C.VERB_REALIGN,
        help="carry the edit layers painted on an earlier export onto a later one's mapping (after fit --refine)",
        description="A refined fit maps the clip onto its atlases a little differently: paint painted against the "
        "earlier export would drift. Pixels each layer owns in both exports pair every new atlas texel with where "
        "it was in the old atlas; the old paint is re-sampled there into the edit layers (the old ones are kept in "
        "edits/history; texels no frame shows in both keep their paint), all together, holding the run folder's lock. "
        "edits/aligned.json then records the export the paint matches: run again, it does nothing. The last line "
        "printed is MANIFEST's path.",
    )
    ra.add_argument(
        "manifest", metavar="MANIFEST", help="the new export's manifest.json (or RUN_DIR: its newest export)"
    )
    ra.add_argument(
        "--from",
        dest="source",
        default=None,
        metavar="vNNN|MANIFEST",
        help="the export the edit layers were painted on (default: the one edits/aligned.json records, which "
        "fit --refine writes; else the export before MANIFEST's); an export of another fit of the same plate "
        "(another run folder: other layers, another preset) has its paint carried onto MANIFEST's edit layers",
    )
    add_layers(ra)
    ra.add_argument(
        "--frame-step", type=int, default=1, metavar="N", help="pair pixels on every N-th shared frame (default: 1)"
    )
    ra.add_argument(
        "--measure",
        action="store_true",
        help="also print (one JSON line on stdout) the paint's placement error against the old export, with and "
        "without re-alignment: mean/max colour difference over painted pixels and the painted areas' IoU",
    )


def _add_preview_parser(sub: argparse._SubParsersAction) -> None:
    """``preview``: contact sheets and movies to judge an export."""
    pv = add_verb(
        sub,
        VERB_PREVIEW,
        help="contact sheets and movies to judge an export: atlases, checkerboard, label propagation",
        description="Writes into MANIFEST's folder/preview (or --out, outside the run folder): atlases with "
        "coverage, a checkerboard mapped through each foreground atlas, and stripes painted on the first frame "
        "propagated; all files appear together once written, or none does. Run again (a retried task), it writes them "
        "again and succeeds.",
    )
    pv.add_argument("manifest", metavar="MANIFEST")
    pv.add_argument("--out", default=None, metavar="DIR")
    pv.add_argument("--no-movies", action="store_true", help="contact sheets only")


def _add_relink_parser(sub: argparse._SubParsersAction) -> None:
    """``relink``: an export told where its plate is now."""
    r = add_verb(
        sub,
        C.VERB_RELINK,
        help="point an export at its plate after the plate or the run folder moved",
        description="Rewrites MANIFEST's plate paths (relative to the manifest, and absolute) to the plate at "
        f"PATH, and the export's {NUKE_SCRIPT_NAME} with them while it is the one the export wrote (a script saved "
        "over it is left as it is). A sequence's folder must hold every frame file the export names. Prints one "
        "line per file, the manifest's path last.",
    )
    r.add_argument("manifest", metavar="MANIFEST", help=MANIFEST_HELP)
    r.add_argument(
        C.RELINK_PLATE_ARG,
        dest="plate",
        required=True,
        metavar="PATH",
        help="the plate: the folder of its frames (or one of them), or the movie",
    )


def _add_nuke_parser(sub: argparse._SubParsersAction) -> None:
    """``nuke``: a Nuke script of the edit."""
    from .export.nuke import DEFAULT_FILTER, OCIO_CONFIG_ARG, STMAP_FILTERS

    n = add_verb(
        sub,
        VERB_NUKE,
        help="write a Nuke script of the edit: per layer an STMap of its edit layer, over the plate",
        description="Reads MANIFEST's plate and passes, per layer Copy (its UV pass into rgba) -> STMap of the edit "
        "layer -> Merge (mask) by its coverage, sums the layers and puts them over the plate: the edit equation of "
        f"`render`. Paths are relative to the script's folder. `export` writes one beside the manifest "
        f"({NUKE_SCRIPT_NAME}); an existing file is never overwritten. The last line printed is the script's path.",
    )
    n.add_argument("manifest", metavar="MANIFEST", help=MANIFEST_HELP)
    n.add_argument("--out", required=True, metavar="FILE.nk", help="the script to write (a new file)")
    n.add_argument(
        "--filter",
        default=DEFAULT_FILTER,
        choices=STMAP_FILTERS,
        help=f"STMap's filter (default: {DEFAULT_FILTER}; Impulse matches `render --filter nearest` exactly)",
    )
    n.add_argument(
        OCIO_CONFIG_ARG,
        dest="ocio_config",
        default=None,
        metavar="CONFIG",
        help="the OCIO config (a file or an ocio:// URI) the script sets on its Root and names every Read's colour "
        "space in (default: the one the export was made in); it must know the plate's colour space",
    )


def _add_masks_parser(sub: argparse._SubParsersAction) -> None:
    """``masks``: coarse foreground masks from motion."""
    m = add_verb(
        sub,
        C.VERB_MASKS,
        help="coarse foreground masks from motion, for a clip that has none",
        description="Find what moves against the background (a homography per frame pair fitted to the optical "
        "flow) and write one 8-bit PNG per frame (0 = background, 255 = foreground), named like the frames, to "
        "check and fix before fitting. Existing files are never overwritten: a folder holding these very masks (the "
        "same command run before, e.g. a retried farm task) is left as it is and the command succeeds. The last line "
        "printed is the folder. "
        "See docs/auto-masks.md.",
    )
    m.add_argument("clip", help=CLIP_HELP)
    m.add_argument(
        "--out",
        required=True,
        metavar="FOLDER",
        help="folder for the mask PNGs (created); the whole set appears at once, or none of it (a full disk or a "
        "cancel leaves nothing: run again)",
    )
    add_plate_frames(m)
    m.add_argument("--truth", default=None, metavar="FOLDER", help="also print the IoU against these masks")
    m.add_argument("--colorspace", default=None, metavar="NAME", help="the clip's OCIO colour space (as fit's)")


def _add_parts_parser(sub: argparse._SubParsersAction) -> None:
    """``parts``: strokes that split one masked object into the parts that move apart."""
    p = add_verb(
        sub,
        C.VERB_PARTS,
        help="strokes splitting one masked object into the parts that move apart (for fit --scribbles)",
        description="Follow points inside the object's mask a few frames along the optical flow on six frames spread "
        "over the clip, and fit an affine motion to each part that moves apart from the rest (a limb swinging in front "
        "of the body). Where two or more parts hold on most of those frames, write their strokes as scribble images "
        "(Foreground1 red, Foreground2 green, ...) named like the frames, to check and pass to fit --scribbles with "
        "the same --mask; an object that moves as one piece gets none. Existing files are never overwritten: a folder "
        "holding these very strokes is left as it is and the command succeeds. The last line printed is the folder, "
        "or the line saying nothing was split. See docs/engine.md.",
    )
    p.add_argument("clip", help=CLIP_HELP)
    p.add_argument("--mask", required=True, metavar="FOLDER", help="the object's mask folder (one mask)")
    p.add_argument("--out", required=True, metavar="FOLDER", help="folder for the stroke images (created)")
    add_plate_frames(p)
    p.add_argument("--colorspace", default=None, metavar="NAME", help="the clip's OCIO colour space (as fit's)")


def _add_farm_parser(sub: argparse._SubParsersAction) -> None:
    """``farm plan|openjd|dask|flamenco SHOTS``: a sequence's shots on the schedulers studios already run. The
    back ends' own parsers come from their modules, imported here only for their parser (light; the scheduler
    libraries load when one runs)."""
    farm = add_verb(
        sub,
        C.VERB_FARM,
        help="fit, export and render the shots of a sequence on a farm (OpenJD/Deadline Cloud, Dask, Flamenco)",
        description="Plan every shot of a shots file (docs/farm.md) as engine commands with their dependencies: "
        "masks (auto_masks) -> fit -> export atlases -> export passes per frame chunk -> publish -> render per "
        "frame chunk -> preview; every back end runs exactly these command lines.",
    )
    commands = farm.add_subparsers(dest="farm_command", metavar="COMMAND", required=True)
    shots_help = "the shots file (.toml or .json; relative paths are relative to it)"
    plan = commands.add_parser(FARM_PLAN, help="print every task's engine arguments and dependencies")
    plan.add_argument("shots", metavar="SHOTS", help=shots_help)
    plan.add_argument("--json", action="store_true", help="one JSON object: the shots and their tasks")
    from .farm.openjd import add_openjd_parser

    add_openjd_parser(commands, shots_help)
    try:
        from .farm.dask_backend import add_dask_parser

        add_dask_parser(commands)
    except ImportError as exc:  # a back end whose module or library is missing: its command says so
        _add_missing_farm_parser(commands, FARM_DASK, exc)
    try:
        from .farm.flamenco import add_flamenco_parser

        add_flamenco_parser(commands)
    except ImportError as exc:
        _add_missing_farm_parser(commands, C.FARM_FLAMENCO, exc)


def _add_missing_farm_parser(commands: argparse._SubParsersAction, command: str, exc: ImportError) -> None:
    """A farm back end whose module or library is missing: its command takes anything and says so when run."""
    missing = commands.add_parser(command, help=f"(not available: {exc})")
    missing.add_argument("rest", nargs=argparse.REMAINDER)
    missing.set_defaults(farm_missing=f"{exc}")
