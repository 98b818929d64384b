"""Command line: parse, call, map errors to exit codes. No logic lives here."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
import traceback
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from . import contract as C
from .errors import FitDiverged, InputError

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

#: The preset of a new fit when --preset is not given.
DEFAULT_PRESET = "balanced"

#: Every verb's exit codes, for the other verbs' help.
EXIT_EPILOG = """\
exit codes: 0 done, 1 engine error, 2 bad input, a full disk or a run folder in use (one line names the file
            and the fix), 3 cancelled by SIGINT/SIGTERM (nothing half-written is kept: run the command again).
"""


class Cancelled(KeyboardInterrupt):
    """SIGTERM outside the training loop: unwinds like Ctrl-C, so every writer's cleanup runs."""


@contextlib.contextmanager
def _cancellable() -> Iterator[None]:
    """SIGTERM raises ``Cancelled`` for the verb's whole run (the training loop installs its own handler, which
    checkpoints first, and restores this one); the previous handler is back afterwards."""

    def handle(signum: int, _frame: Any) -> None:
        raise Cancelled(signal.Signals(signum).name)

    try:
        old = signal.signal(signal.SIGTERM, handle)
    except ValueError:  # not the main thread: the caller handles signals
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def _print_paths(paths: Iterable[Path | str]) -> int:
    """A verb's last lines: one ``written`` message listing what it wrote (a program reads that), then the same
    paths one per line (what the add-on and shell scripts read: the last line is the path when there is one)."""
    from .io.images import display_path  # a name that is not UTF-8 would stop a strict stdout

    written = [os.fspath(path) for path in paths]
    print(C.progress_line(C.EVENT_WRITTEN, paths=written))  # JSON escapes what is not UTF-8
    for path in written:
        print(display_path(path))
    return C.EXIT_OK


def frame_range(text: str) -> tuple[int, int]:
    """``--frames``: ``FIRST-LAST`` (``1010-1050``, as pipeline tools write a range), ``FIRST:LAST`` or one frame
    ``N``, in the plate's frame numbers (inclusive)."""
    a, sep, b = text.strip().replace(":", "-").partition("-")
    try:
        first = int(a)
        last = int(b) if sep else first
        if first < 0 or last < 0:
            raise ValueError
        return first, last
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"frame range {text!r} must be FIRST-LAST in the plate's frame numbers, e.g. 1001-1100 (or 0:49)"
        ) from None


def frame_rate(text: str) -> Any:
    """``--fps``: ``24``, ``25``, ``23.976`` (taken as 24000/1001) or an exact ``24000/1001``."""
    from .io.timing import parse_rate

    try:
        return parse_rate(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


#: --frames' help, for every verb that reads a plate.
FRAMES_HELP = (
    "inclusive range of the plate's frame numbers, FIRST-LAST (plate.1010.exr .. plate.1050.exr: 1010-1050; a "
    "movie's frames count from 0 or --start-frame); default: all"
)


def _positions(clip: str | None, frames: tuple[int, int] | None, start_frame: int | None = None) -> Any:
    """The plate frame numbers of --frames as the positions the engine's readers take (None: every frame)."""
    if frames is None or clip is None:
        return frames
    from .io.clip import frame_positions

    return frame_positions(clip, frames, start_frame)


#: The command `pip install` makes (pyproject.toml's [project.scripts]): the same verbs as `python -m engine`.
CONSOLE_SCRIPT = "neural-atlas"


#: How a cancelled or interrupted fit goes on (the run folder follows).
_RESUME = f"python -m {C.CLI_MODULE} fit --resume --out"


def build_parser(prog: str = f"python -m {C.CLI_MODULE}") -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=prog, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--version", action="version", version=f"neural-atlas engine {C.ENGINE_VERSION}")
    sub = p.add_subparsers(dest="verb", metavar="VERB")
    f = sub.add_parser(
        C.VERB_FIT,
        help="fit atlases to a clip",
        epilog=FIT_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
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
        C.FIT_AUTO_MASKS_FLAG,
        dest="auto_masks",
        action="store_true",
        help=f"no masks: find moving objects (masks written to RUN_DIR/{C.AUTO_MASKS_DIR} for checking) and fit "
        f"them; nothing moving gives a background-only fit. A full set of masks already in RUN_DIR/{C.AUTO_MASKS_DIR} "
        "(written by `masks`, or fixed by hand) is used as it is. Without --mask or this, the fit is background-only",
    )
    f.add_argument(
        "--out",
        default=None,
        metavar="RUN_DIR",
        help="run folder (created; a folder that holds a fit takes --resume or --refit; one in use by another "
        "process is refused)",
    )
    f.add_argument(
        "--preset",
        default=None,
        help=f"draft | balanced | final | paper (default: {DEFAULT_PRESET}; not with --resume)",
    )
    f.add_argument("--device", default="auto", help="auto | cpu | cuda | mps (default: auto)")
    f.add_argument("--frames", type=frame_range, default=None, metavar="FIRST-LAST", help=FRAMES_HELP)
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
        type=int,
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
    f.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override any config field (see --help-config)",
    )
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
        C.FIT_RESUME_IF_STARTED_FLAG,
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
    f.add_argument("--no-bar", action="store_true", help="no progress bar on stderr (JSON lines only)")
    f.add_argument("--help-config", action="store_true", help="list every config field and exit")
    d = sub.add_parser(
        C.VERB_DEMO,
        help="fit the embedded demo clip (README command 1)",
        description="Generate the demo plate, fit it, and write a contact sheet. Idempotent.",
        epilog=EXIT_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    d.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    d.add_argument("--preset", default="draft", help="preset (default: draft)")
    d.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config field")
    _add_estimate_parser(sub)
    _add_export_parsers(sub)
    _add_masks_parser(sub)
    _add_nuke_parser(sub)
    _add_farm_parser(sub)
    _add_output_options(p)
    return p


def _add_estimate_parser(sub: argparse._SubParsersAction) -> None:
    e = sub.add_parser(
        C.VERB_ESTIMATE,
        help="estimated fit time of each preset on this machine and clip",
        description="Time a few training steps of each preset on the clip and multiply by its step budget. Every "
        "preset asked for gets a row; one that cannot fit this clip (paper: exactly one --mask) says why instead.",
        epilog=EXIT_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    e.add_argument("clip", help="image-sequence folder, sequence pattern or movie file")
    e.add_argument("--mask", action="append", default=[], metavar="FOLDER", help="mask folder per foreground layer")
    e.add_argument("--presets", default=None, help="comma-separated (default: every preset)")
    e.add_argument("--frames", type=frame_range, default=None, metavar="FIRST-LAST", help=FRAMES_HELP)
    e.add_argument("--calib-seconds", type=float, default=2.0, help="timed seconds per preset and regime")
    e.add_argument("--work", default=None, metavar="RUN_DIR", help="keep the flow cache here (a fit reuses it)")
    e.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    e.add_argument("--device", default="auto")
    e.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    e.add_argument("--json", action="store_true", help="print one JSON object (contract.ESTIMATE_TAG) instead")


def _cmd_estimate(args: argparse.Namespace) -> int:
    import json

    from .config import parse_set_args
    from .fit.estimate import estimate, format_estimate
    from .fit.progress import Reporter

    result = estimate(
        args.clip,
        args.mask,
        presets=[p.strip() for p in args.presets.split(",")] if args.presets else None,
        work_dir=args.work,
        calib_seconds=args.calib_seconds,
        device_name=args.device,
        frame_range=_positions(args.clip, args.frames),
        overrides=parse_set_args(args.set),
        threads=args.threads,
        # --json is for a program (the add-on): progress lines (``job``) before the result; the table stays plain
        reporter=Reporter() if args.json else None,
    )
    print(json.dumps(result) if args.json else format_estimate(result))
    return C.EXIT_OK


def _add_export_parsers(sub: argparse._SubParsersAction) -> None:
    x = sub.add_parser(
        C.VERB_EXPORT,
        help="write UV + alpha EXR passes, atlas textures, edit layers and a manifest",
        description="Export a fitted run for compositing into RUN_DIR/exports/vNNN (never overwritten), holding "
        "the run folder's lock. Passes are float32 EXR at the plate's native resolution; edit layers (RUN_DIR/edits) "
        "are created once and never overwritten. The manifest's paths are relative to it, so the run folder can move "
        "with its plate. The last line printed is the manifest's path (--stage atlases and passes: the staging "
        "folder).",
        epilog=EXIT_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    x.add_argument("run", metavar="RUN_DIR", help="the --out folder of a fit")
    x.add_argument(
        "--atlas-size",
        type=int,
        default=None,
        help=f"atlas texture long side in texels (default: {C.ATLAS_SIZE_DEFAULT}; publish: the staged one)",
    )
    x.add_argument(
        "--frames",
        type=frame_range,
        default=None,
        metavar="FIRST-LAST",
        help="inclusive range of the plate's frame numbers, as for fit (default: every fitted frame; passes: the "
        "chunk to write, default the staged range)",
    )
    x.add_argument("--device", default="cpu", help="auto | cpu | cuda | mps (default: cpu)")
    x.add_argument(
        C.EXPORT_INTO_ARG,
        dest="into",
        default=None,
        metavar="vNNN",
        help=f"export into RUN_DIR/{C.EXPORTS_DIR}/vNNN (its manifest path is known before it runs) rather than the "
        "next free version; already exported there with the same frames and atlas size: nothing to do, the "
        "manifest's path is printed (a retried task succeeds); with others: refused",
    )
    x.add_argument(
        C.EXPORT_STAGE_ARG,
        dest="stage",
        default=None,
        choices=C.EXPORT_STAGES,
        help=f"one part of the export {C.EXPORT_INTO_ARG} vNNN, for a farm: atlases (once, holding the lock: the "
        f"layer frames and atlas textures into {C.EXPORTS_DIR}/.vNNN.chunks), passes --frames A-B (chunks, at once "
        "on several hosts, no lock: frames already written are skipped, a cancel keeps the finished ones), publish "
        "(once every chunk is done: edit layers, manifest and Nuke script, then the folder becomes vNNN). The files "
        "are those of a whole export, byte for byte; each part run again is idempotent",
    )
    x.add_argument("--no-bar", action="store_true", help="no progress bar on stderr")
    r = sub.add_parser(
        C.VERB_RENDER,
        help="render the edited clip from an export (the paper's edit equations)",
        description="Blend each layer's edit layer (sampled at its UV) over the ORIGINAL plate, layers weighted "
        "by the learned alpha. With every edit layer empty the output is the plate. The frames (and the movie) "
        "appear together once all are written, or none does; --out and --movie may not be the plate's folder, a "
        "mask folder or inside the run folder.",
        epilog=EXIT_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    r.add_argument("manifest", metavar="MANIFEST", help="manifest.json of an export (or its folder)")
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
    r.add_argument("--no-bar", action="store_true", help="no progress bar on stderr")
    pf = sub.add_parser(
        C.VERB_PROJECT_FRAME,
        help="land paint made on one frame on the atlases' edit layers",
        description="IMAGE is RGBA paint over plate frame N (transparent where unpainted). The paint goes to the "
        "layers that own each pixel and is composited over their edit layers (the old ones are kept in "
        "edits/history), all together, holding the run folder's lock.",
        epilog=EXIT_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    pf.add_argument("manifest", metavar="MANIFEST")
    pf.add_argument("--frame", type=int, required=True, metavar="N", help="plate frame number the paint was made on")
    pf.add_argument("--edit", required=True, metavar="IMAGE", help="RGBA paint, the plate's size")
    pf.add_argument("--layer", action="append", default=None, metavar="NAME", help="only these layers")
    ra = sub.add_parser(
        C.VERB_REALIGN,
        help="carry the edit layers painted on an earlier export onto a later one's mapping (after fit --refine)",
        description="A refined fit maps the clip onto its atlases a little differently: paint painted against the "
        "earlier export would drift. Pixels each layer owns in both exports pair every new atlas texel with where "
        "it was in the old atlas; the old paint is re-sampled there into the edit layers (the old ones are kept in "
        "edits/history; texels no frame shows in both keep their paint), all together, holding the run folder's lock. "
        "edits/aligned.json then records the export the paint matches: run again, it does nothing. The last line "
        "printed is MANIFEST's path.",
        epilog=EXIT_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
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
        "fit --refine writes; else the export before MANIFEST's)",
    )
    ra.add_argument("--layer", action="append", default=None, metavar="NAME", help="only these layers")
    ra.add_argument(
        "--frame-step", type=int, default=1, metavar="N", help="pair pixels on every N-th shared frame (default: 1)"
    )
    ra.add_argument(
        "--measure",
        action="store_true",
        help="also print (one JSON line on stdout) the paint's placement error against the old export, with and "
        "without re-alignment: mean/max colour difference over painted pixels and the painted areas' IoU",
    )
    pv = sub.add_parser(
        C.VERB_PREVIEW,
        help="contact sheets and movies to judge an export: atlases, checkerboard, label propagation",
        description="Writes into MANIFEST's folder/preview (or --out, outside the run folder): atlases with "
        "coverage, a checkerboard mapped through each foreground atlas, and stripes painted on the first frame "
        "propagated; all files appear together once written, or none does. Run again (a retried task), it writes them "
        "again and succeeds.",
        epilog=EXIT_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    pv.add_argument("manifest", metavar="MANIFEST")
    pv.add_argument("--out", default=None, metavar="DIR")
    pv.add_argument("--no-movies", action="store_true", help="contact sheets only")


def _cmd_export(args: argparse.Namespace) -> int:
    from .export.exporter import export_run

    path = export_run(
        args.run,
        atlas_size=args.atlas_size,
        frames=args.frames,
        device_name=args.device,
        progress_bar=not args.no_bar,
        into=args.into,
        stage=args.stage,
    )
    return _print_paths([path])


def _cmd_render(args: argparse.Namespace) -> int:
    from .edit.render import parse_edit_args, render_manifest

    out = render_manifest(
        args.manifest,
        args.out,
        parse_edit_args(args.edit),
        fmt=args.format,
        filter=args.filter,
        movie=args.movie,
        progress_bar=not args.no_bar,
        frames=args.frames,
        name=args.name,
        depth=args.depth,
    )
    return _print_paths([Path(out).resolve()])


def _cmd_project_frame(args: argparse.Namespace) -> int:
    from .edit.project_frame import project_frame

    def stage(name: str, message: str, step: int, total: int) -> None:
        # the add-on's progress bar: what it does now, and how far (stages done of all)
        print(C.progress_line(C.EVENT_STAGE, stage=name, message=message), flush=True)
        print(C.progress_line(C.EVENT_PROGRESS, step=step, total=total), flush=True)

    return _print_paths(project_frame(args.manifest, args.frame, args.edit, args.layer, on_stage=stage).values())


def _cmd_realign(args: argparse.Namespace) -> int:
    from .edit.realign import realign, realign_measured

    if args.measure:
        manifest, report = realign_measured(args.manifest, args.source, args.layer, args.frame_step)
        print(json.dumps(report))
    else:
        manifest, _ = realign(args.manifest, args.source, args.layer, args.frame_step)
    return _print_paths([manifest.path])


def _cmd_preview(args: argparse.Namespace) -> int:
    from .edit.preview import write_previews

    return _print_paths(write_previews(args.manifest, args.out, movies=not args.no_movies))


def _add_nuke_parser(sub: argparse._SubParsersAction) -> None:
    from .export.nuke import DEFAULT_FILTER, OCIO_CONFIG_ARG, STMAP_FILTERS

    n = sub.add_parser(
        C.VERB_NUKE,
        help="write a Nuke script of the edit: per layer an STMap of its edit layer, over the plate",
        description="Reads MANIFEST's plate and passes, per layer Shuffle (STMap<Layer>) -> STMap of the edit layer "
        "-> Merge (mask) by its coverage, sums the layers and puts them over the plate: the edit equation of "
        f"`render`. Paths are relative to the script's folder. `export` writes one beside the manifest "
        f"({C.NUKE_SCRIPT_NAME}); an existing file is never overwritten. The last line printed is the script's path.",
        epilog=EXIT_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    n.add_argument("manifest", metavar="MANIFEST", help="manifest.json of an export (or its folder)")
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


def _cmd_nuke(args: argparse.Namespace) -> int:
    from .export.nuke import write_nuke_script

    return _print_paths([write_nuke_script(args.manifest, args.out, args.filter, args.ocio_config)])


def _add_masks_parser(sub: argparse._SubParsersAction) -> None:
    m = sub.add_parser(
        C.VERB_MASKS,
        help="coarse foreground masks from motion, for a clip that has none",
        description="Find what moves against the background (a homography per frame pair fitted to the optical "
        "flow) and write one 8-bit PNG per frame (0 = background, 255 = foreground), named like the frames, to "
        "check and fix before fitting. Existing files are never overwritten: a folder holding these very masks (the "
        "same command run before, e.g. a retried farm task) is left as it is and the command succeeds. The last line "
        "printed is the folder. "
        "See docs/auto-masks.md.",
        epilog=EXIT_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    m.add_argument("clip", help="image-sequence folder, sequence pattern or movie file")
    m.add_argument(
        "--out",
        required=True,
        metavar="FOLDER",
        help="folder for the mask PNGs (created); the whole set appears at once, or none of it (a full disk or a "
        "cancel leaves nothing: run again)",
    )
    m.add_argument("--frames", type=frame_range, default=None, metavar="FIRST-LAST", help=FRAMES_HELP)
    m.add_argument("--truth", default=None, metavar="FOLDER", help="also print the IoU against these masks")
    m.add_argument("--colorspace", default=None, metavar="NAME", help="the clip's OCIO colour space (as fit's)")


def _cmd_masks(args: argparse.Namespace) -> int:
    """Progress goes to stdout as a JSON stage line, so stderr holds nothing but a failure's one line; the folder
    is printed last (``_print_paths``: as text any terminal takes, a name that is not UTF-8 showing its bytes as
    \\xNN)."""
    from .data.auto_masks import write_auto_masks

    def say(message: str) -> None:
        print(C.progress_line(C.EVENT_STAGE, stage=C.VERB_MASKS, message=message), flush=True)

    frames = _positions(args.clip, args.frames)
    report = write_auto_masks(
        args.clip, args.out, frame_range=frames, truth=args.truth, say=say, colorspace=args.colorspace
    )
    for line in report.summary():
        print(line)
    print(C.progress_line(C.EVENT_MASKS, found=bool(report.result.found), folder=str(report.folder),
                          message=report.result.message))  # fmt: skip
    return _print_paths([report.folder])


def _add_farm_parser(sub: argparse._SubParsersAction) -> None:
    """``farm plan|openjd|dask|flamenco SHOTS``: a sequence's shots on the schedulers studios already run. The
    back ends' own parsers come from their modules, imported here only for their parser (light; the scheduler
    libraries load when one runs)."""
    farm = sub.add_parser(
        C.VERB_FARM,
        help="fit, export and render the shots of a sequence on a farm (OpenJD/Deadline Cloud, Dask, Flamenco)",
        description="Plan every shot of a shots file (docs/farm.md) as engine commands with their dependencies: "
        "masks (auto_masks) -> fit -> export atlases -> export passes per frame chunk -> publish -> render per "
        "frame chunk -> preview; every back end runs exactly these command lines.",
        epilog=EXIT_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    commands = farm.add_subparsers(dest="farm_command", metavar="COMMAND", required=True)
    shots_help = "the shots file (.toml or .json; relative paths are relative to it)"
    plan = commands.add_parser(C.FARM_PLAN, help="print every task's engine arguments and dependencies")
    plan.add_argument("shots", metavar="SHOTS", help=shots_help)
    plan.add_argument("--json", action="store_true", help="one JSON object: the shots and their tasks")
    oj = commands.add_parser(
        C.FARM_OPENJD,
        help="write an Open Job Description bundle (AWS Deadline Cloud; `openjd run`)",
        description="Write BUNDLE_DIR/template.json, parameter_values.json and asset_references.json (Deadline "
        "Cloud's job bundle) and job_parameters.json (`openjd run BUNDLE_DIR/template.json -p "
        "file://BUNDLE_DIR/job_parameters.json`). The last line printed is the template's path.",
    )
    oj.add_argument("shots", metavar="SHOTS", help=shots_help)
    oj.add_argument("--out", required=True, metavar="BUNDLE_DIR", help="the bundle's folder (created)")
    oj.add_argument(
        "--engine-python",
        default=sys.executable,
        metavar="PYTHON",
        help="the engine's Python on the workers (default: this one; the EnginePython job parameter)",
    )
    oj.add_argument(
        "--engine-path",
        default=str(Path(__file__).resolve().parent.parent),
        metavar="DIR",
        help="the folder holding engine/ on the workers, put on PYTHONPATH (default: this engine's; '' when the "
        "engine is installed in the workers' Python)",
    )
    oj.add_argument("--no-gpu", action="store_true", help="no GPU host requirement on the fit and export steps")
    oj.add_argument("--name", default=None, help="the job's name (default: the shots file's name)")
    try:
        from .farm.dask_backend import add_dask_parser

        add_dask_parser(commands)
    except ImportError as exc:  # a back end whose module or library is missing: its command says so
        _add_missing_farm_parser(commands, C.FARM_DASK, exc)
    try:
        from .farm.flamenco import add_flamenco_parser

        add_flamenco_parser(commands)
    except ImportError as exc:
        _add_missing_farm_parser(commands, C.FARM_FLAMENCO, exc)


def _add_missing_farm_parser(commands: argparse._SubParsersAction, command: str, exc: ImportError) -> None:
    missing = commands.add_parser(command, help=f"(not available: {exc})")
    missing.add_argument("rest", nargs=argparse.REMAINDER)
    missing.set_defaults(farm_missing=f"{exc}")


def _cmd_farm(args: argparse.Namespace) -> int:
    """Plan, then hand the plan to the back end; progress per shot as JSON lines, the result's path last."""
    import json

    missing = getattr(args, "farm_missing", None)
    if missing is not None:
        raise InputError(
            None, f"farm {args.farm_command} is not available ({missing})", "install the engine's farm extra"
        )
    if args.farm_command == C.FARM_DASK:
        from .farm.dask_backend import run_dask

        return run_dask(args)
    if args.farm_command == C.FARM_FLAMENCO:
        from .farm.flamenco import run_flamenco

        return run_flamenco(args)
    from .farm.plan import plan_with_shots, task_graph_text
    from .farm.shots import load_shots

    shots = load_shots(args.shots)
    plan, shot_plans = plan_with_shots(shots)
    if args.farm_command == C.FARM_PLAN:
        if args.json:
            print(json.dumps({"schema": C.SCHEMA_VERSION, **plan.to_json()}, indent=2))
        else:
            print(task_graph_text(plan))
        return C.EXIT_OK
    from .farm.openjd import write_bundle

    files = write_bundle(
        plan,
        shot_plans,
        args.out,
        name=args.name or f"Neural Atlas {shots.path.stem}",
        gpu=not args.no_gpu,
        python=args.engine_python,
        engine_path=args.engine_path,
    )
    for sp in shot_plans:
        name, count = sp.shot.name, len(plan.shot_tasks(sp.shot.name))
        message = f"{name}: {count} tasks, export {sp.version}"
        print(C.progress_line(C.EVENT_STAGE, stage=C.VERB_FARM, shot=name, tasks=count, message=message))
    return _print_paths(files[:1])


def _cmd_fit(args: argparse.Namespace) -> int:
    from .config import apply_overrides, config_help, parse_set_args, preset_config

    if args.help_config:
        print(config_help())
        return C.EXIT_OK
    if args.out is None:
        raise InputError(None, "no run folder given", "pass --out RUN_DIR (a new folder, or a fit's to --resume)")
    if args.resume and args.refit:
        raise InputError(
            None, "--resume and --refit both given", "pass --resume to continue the fit, or --refit to fit again"
        )
    if args.resume_if_started and (args.resume or args.refit):
        raise InputError(
            None,
            f"{C.FIT_RESUME_IF_STARTED_FLAG} with --{'resume' if args.resume else 'refit'}",
            f"pass {C.FIT_RESUME_IF_STARTED_FLAG} alone: it starts, continues or leaves the fit as RUN_DIR holds it",
        )
    from .fit.run_folder import RunFolder
    from .fit.trainer import FitCancelled, fit

    run_dir = Path(args.out)
    if args.refine is not None:
        return _cmd_refine(args, run_dir)
    if args.resume_if_started and not _start_or_resume(args, run_dir):
        return C.EXIT_OK  # this fit is finished already
    if args.resume:
        cfg = RunFolder(run_dir).read_config()
        if args.preset is not None and args.preset != cfg.preset:
            raise InputError(
                run_dir / C.RUN_CONFIG,
                f"--preset {args.preset} with --resume: this fit started with preset {cfg.preset}",
                "drop --preset to continue it, or fit with that preset into a new --out (or --refit)",
            )
    else:
        cfg = preset_config(args.preset or DEFAULT_PRESET)
    if args.resume_if_started and args.resume:  # the config the fit started with, as the same argv builds it
        cfg = preset_config(args.preset or DEFAULT_PRESET)
    cfg = apply_overrides(cfg, parse_set_args(args.set))
    if args.resume and args.frames is not None:  # the recorded plate, numbered as it was fitted
        record = RunFolder(run_dir).read_clip()
        missing = record.missing_input(run_dir)
        if missing is not None:
            raise missing
        frames = _positions(record.source, args.frames, record.movie_start)
    else:
        frames = _positions(args.clip, args.frames, args.start_frame)
    try:
        metrics = fit(
            args.clip,
            args.mask,
            run_dir,
            cfg,
            device_name=args.device,
            resume=args.resume,
            frame_range=frames,
            progress_bar=not args.no_bar,
            scribble_dir=args.scribbles,
            auto_masks=args.auto_masks,
            refit=args.refit,
            colorspace=args.colorspace,
            fps=args.fps,
            start_frame=args.start_frame,
        )
    except FitCancelled as exc:
        print(f"cancelled: {exc}; continue with: {_RESUME} {run_dir}", file=sys.stderr)
        return C.EXIT_CANCELLED
    print(
        f"fit done: PSNR {metrics['psnr']:.2f} dB over every pixel, {metrics['steps']} steps in "
        f"{metrics['train_seconds']:.0f} s -> {run_dir}",
        file=sys.stderr,
    )
    return C.EXIT_OK


def _cmd_refine(args: argparse.Namespace, run_dir: Path) -> int:
    """``fit --refine [STEPS] [--preset P]``: a finished fit continued (``engine.fit.refine``); the export its edit
    layers were painted on is recorded once training has run, for ``realign``."""
    from .config import apply_overrides, parse_set_args
    from .edit.aligned import record_paint_export
    from .fit.refine import refine_config
    from .fit.trainer import FitCancelled, fit

    clashing = [flag for flag, given in (("--resume", args.resume), ("--refit", args.refit),
                (C.FIT_RESUME_IF_STARTED_FLAG, args.resume_if_started), (C.FIT_AUTO_MASKS_FLAG, args.auto_masks),
                ("--frames", args.frames is not None)) if given]  # fmt: skip
    if clashing:
        raise InputError(
            None,
            f"{C.FIT_REFINE_FLAG} with {clashing[0]}",
            f"pass {C.FIT_REFINE_FLAG} alone with --out: it continues the finished fit as it was fitted",
        )
    plan = refine_config(run_dir, args.refine or None, args.preset)
    cfg = apply_overrides(plan.cfg, parse_set_args(args.set))
    try:
        metrics = fit(
            args.clip,
            args.mask,
            run_dir,
            cfg,
            device_name=args.device,
            resume=True,
            progress_bar=not args.no_bar,
            scribble_dir=args.scribbles,
            colorspace=args.colorspace,
        )
    except FitCancelled as exc:
        record_paint_export(run_dir)
        print(f"cancelled: {exc}; continue with: {_RESUME} {run_dir}", file=sys.stderr)
        return C.EXIT_CANCELLED
    painted_on = record_paint_export(run_dir)
    carry = f"; carry the paint over: export, then {C.VERB_REALIGN} --from {painted_on}" if painted_on else ""
    print(
        f"fit refined from {plan.done} steps: PSNR {metrics['psnr']:.2f} dB over every pixel, {metrics['steps']} "
        f"steps in {metrics['train_seconds']:.0f} s -> {run_dir}{carry}",
        file=sys.stderr,
    )
    return C.EXIT_OK


def _start_or_resume(args: argparse.Namespace, run_dir: Path) -> bool:
    """``fit --resume-if-started``: sets ``args.resume`` when RUN_DIR holds a checkpoint of this same fit; False when
    it holds this fit finished (said on stderr: nothing to do); a different fit there is one line."""
    from .config import apply_overrides, parse_set_args, preset_config
    from .fit.run_folder import RunFolder
    from .fit.trainer import FIT_FINISHED, FIT_NEW, fit_state

    run = RunFolder(run_dir)
    if not run.checkpoint.exists():
        return True
    cfg = apply_overrides(preset_config(args.preset or DEFAULT_PRESET), parse_set_args(args.set))
    record = run.read_clip()
    frames = _positions(record.source, args.frames, record.movie_start) if args.frames is not None else None
    state = fit_state(run_dir, args.clip, args.mask, cfg, frames, args.scribbles, args.colorspace)
    if state == FIT_FINISHED:
        metrics = run.read_metrics() or {}
        print(f"already fitted: {metrics.get('steps')} steps, PSNR {metrics.get('psnr')} dB -> {run_dir}",
              file=sys.stderr)  # fmt: skip
        return False
    args.resume = state != FIT_NEW
    return True


def _cancelled_line(args: argparse.Namespace, exc: KeyboardInterrupt) -> str:
    """The one line printed when a verb is stopped by SIGINT/SIGTERM outside the training loop."""
    how = str(exc) or "SIGINT"
    line = f"cancelled: {args.verb} stopped by {how} before it finished; nothing half-written was kept"
    if args.verb == C.VERB_FIT and args.out is not None:
        from .fit.run_folder import RunFolder

        run = RunFolder(args.out)
        if run.checkpoint.exists():
            return f"{line}; continue with: {_RESUME} {run.path}"
    return f"{line}; run the same command again"


def main(argv: list[str] | None = None, prog: str = f"python -m {C.CLI_MODULE}") -> int:
    parser = build_parser(prog)
    args = parser.parse_args(argv)
    if args.verb is None:  # nothing was asked: the help, on stderr (stdout is for what a verb reports), and 2
        parser.print_help(sys.stderr)
        return C.EXIT_BAD_INPUT
    if args.quiet and args.verbose:
        parser.error("-q and -v ask for less and more output: pass one of them")
    with _cancellable(), _output(args) as finished:
        code = _run(parser, args)
        finished(code)
        return code


#: -q and -v, on the engine and on every verb (``python -m engine -q fit ...`` or ``... fit ... -q``).
QUIET_HELP = "only what needs attention on stderr: errors, warnings, a cancellation (no bar, notes or summaries)"
VERBOSE_HELP = "also each stage as a line on stderr, with the whole job's percent where known"


def _add_output_options(parser: argparse.ArgumentParser) -> None:
    """-q and -v on ``parser`` and on every verb below it; a verb's own copy leaves the engine's value alone unless
    given (its default is SUPPRESS), so either place works."""
    for at, default in ((parser, False), *((sub, argparse.SUPPRESS) for sub in _verb_parsers(parser))):
        at.add_argument("-q", "--quiet", action="store_true", default=default, help=QUIET_HELP)
        at.add_argument("-v", "--verbose", action="store_true", default=default, help=VERBOSE_HELP)


def _verb_parsers(parser: argparse.ArgumentParser) -> Iterator[argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in dict.fromkeys(action.choices.values()):  # an alias names the same parser
                yield sub
                yield from _verb_parsers(sub)


@contextlib.contextmanager
def _output(args: argparse.Namespace) -> Iterator[Callable[[int], None]]:
    """stdout and stderr as -q, -v and an OpenJD task (``contract.OPENJD_PROGRESS_ENV``) ask, for the verb's run;
    yields what to call with its exit code (an OpenJD task's 100 % once it succeeded). Without them: untouched."""
    from .fit.progress import LineTap, OpenJDProgress, quiet_lines, verbose_lines

    openjd = OpenJDProgress() if os.environ.get(C.OPENJD_PROGRESS_ENV, "") else None
    echo = verbose_lines(sys.stderr) if args.verbose else None
    if args.quiet and hasattr(args, "no_bar"):
        args.no_bar = True
    stdout, stderr = sys.stdout, sys.stderr

    def on_stdout(line: str) -> str:
        if echo is not None:
            echo(line)
        return line if openjd is None else openjd(line)

    taps = []
    if openjd is not None or echo is not None:
        sys.stdout = tap = LineTap(stdout, on_stdout)  # type: ignore[assignment]
        taps.append(tap)
    if args.quiet:
        sys.stderr = tap = LineTap(stderr, quiet_lines())  # type: ignore[assignment]
        taps.append(tap)

    def finished(code: int) -> None:
        for each in taps:
            each.close()
        if openjd is not None and code == C.EXIT_OK:
            stdout.write(openjd.finished())
            stdout.flush()

    try:
        yield finished
    finally:
        for each in taps:
            each.close()
        sys.stdout, sys.stderr = stdout, stderr


def console_main() -> int:
    """The ``neural-atlas`` command of an installed engine: ``main`` under that name (its help and usage say it)."""
    return main(prog=CONSOLE_SCRIPT)


def _run(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    from .io.atomic import disk_full_error

    try:
        handlers = {
            C.VERB_FIT: _cmd_fit,
            C.VERB_EXPORT: _cmd_export,
            C.VERB_RENDER: _cmd_render,
            C.VERB_PROJECT_FRAME: _cmd_project_frame,
            C.VERB_REALIGN: _cmd_realign,
            C.VERB_PREVIEW: _cmd_preview,
            C.VERB_ESTIMATE: _cmd_estimate,
            C.VERB_MASKS: _cmd_masks,
            C.VERB_NUKE: _cmd_nuke,
            C.VERB_FARM: _cmd_farm,
        }
        if args.verb in handlers:
            return handlers[args.verb](args)
        if args.verb == C.VERB_DEMO:
            from .config import parse_set_args
            from .demo import run_demo
            from .fit.trainer import FitCancelled

            try:
                run_demo(Path(args.out), args.preset, parse_set_args(args.set))
            except FitCancelled as exc:
                print(f"cancelled: {exc}; run the demo again to continue", file=sys.stderr)
                return C.EXIT_CANCELLED
            return C.EXIT_OK
    except (InputError, C.RunLocked) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return C.EXIT_BAD_INPUT
    except FitDiverged as exc:
        print(f"error: {exc}", file=sys.stderr)
        return C.EXIT_DIVERGED
    except KeyboardInterrupt as exc:
        print(_cancelled_line(args, exc), file=sys.stderr)
        return C.EXIT_CANCELLED
    except (OSError, RuntimeError) as exc:
        # a full disk or a quota is the machine's state, not an engine bug: one line, and what survives
        filename = getattr(exc, "filename", None)
        full = disk_full_error(exc, Path(filename).parent if filename else Path.cwd())
        if full is None:
            traceback.print_exc()
            return C.EXIT_FAILED
        print(f"error: {full}", file=sys.stderr)
        return C.EXIT_BAD_INPUT
    except Exception:
        traceback.print_exc()
        return C.EXIT_FAILED
    parser.error(f"unknown verb {args.verb}")
    return C.EXIT_BAD_INPUT
