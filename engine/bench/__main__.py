"""The measurement tools for developing the engine, run as ``python -m engine.bench TOOL ...``. They are not
part of the product (its CLI is ``python -m engine``) and not in the extension zip.

    bench        accuracy against training time of several presets, in one process (docs/accuracy-vs-time.md)
    clips        one preset on every clip of a folder, fitted with degraded masks, scored against the precise ones
    speed        seconds per step of presets, side by side on one clip
    scene-speed  what the scene analysis saves: one clip fitted with components=auto and components=all
    expected-psnr  a finished fit's PSNR as its preset's expected PSNR (engine/fit/expected_psnr.json)
    farm         shots one after another against the same shots through `farm dask` with local workers
    motion-scenes  synthetic clip folders with ground-truth tracks (turning, deforming, small_fast, thin,
                   turning_depth, limbs_jump)
    masks        the mask snap alone on every clip of a folder: degraded masks' IoU before and after
    paint-tracks where paint on the exported atlases shows in each frame, scored against TAP-Vid tracks
    flow-tracks  the baseline: chained DIS optical flow on the native plate, scored the same way
    sharpness    the plate re-rendered from the exported atlas textures and passes: PSNR inside the mask
    paint-table  one preset fitted and exported on every clip of a folder, scored on the export: paint, flow,
                 IoU, sharpness, PSNR, training seconds; with a picture per clip
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import traceback
from pathlib import Path

from engine import contract as C
from engine.cli import frame_range
from engine.errors import InputError

BENCH = "bench"
CLIPS = "clips"
SPEED = "speed"
SCENE_SPEED = "scene-speed"
EXPECTED_PSNR = "expected-psnr"
FARM = "farm"
MOTION_SCENES = "motion-scenes"
MASKS = "masks"
PAINT_TRACKS = "paint-tracks"
FLOW_TRACKS = "flow-tracks"
SHARPNESS = "sharpness"
PAINT_TABLE = "paint-table"
PROG = "python -m engine.bench"

BENCH_EPILOG = """\
clips: a folder holding frames/ and masks/ (and tracks_tapvid.npz: then atlas tracking is scored), or a frame
  folder with --mask (one clip only).
--set KEY=VALUE applies to every preset, --set PRESET.KEY=VALUE to one (e.g. paper.batch=2000).
writes OUT/bench.json (curves, machine, versions, command) and OUT/bench.png; see docs/accuracy-vs-time.md.
"""


def parse_eval_at(text: str) -> tuple[float, ...]:
    """``--eval-at 180,600,1200`` -> (180.0, 600.0, 1200.0); a bad entry is a one-line input error."""
    try:
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        problem, fix = f"--eval-at {text!r} is not a list of seconds", "write e.g. --eval-at 180,600,1200"
        raise InputError(None, problem, fix) from None


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG, description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = p.add_subparsers(dest="tool", metavar="TOOL")
    b = sub.add_parser(
        BENCH,
        help="accuracy against training time of several presets, in one process",
        epilog=BENCH_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Fit presets side by side for a training-time budget each; record PSNR, mapping "
        "consistency and point-tracking accuracy against training seconds (evaluation excluded).",
    )
    b.add_argument("clips", nargs="+", metavar="CLIP", help="clip folder (frames/, masks/) or a frame folder")
    b.add_argument("--mask", action="append", default=[], metavar="FOLDER", help="mask folder (single clip only)")
    b.add_argument("--tracks", default=None, metavar="NPZ", help="tracks_tapvid.npz (single clip only)")
    b.add_argument(
        "--score-masks",
        action="append",
        default=[],
        metavar="FOLDER",
        help="precise masks to score the foreground alpha against (single clip only; default: a clip folder's masks/)",
    )
    b.add_argument("--presets", default="draft,balanced,paper", help="comma-separated (default: draft,balanced,paper)")
    b.add_argument("--budget-seconds", type=float, required=True, help="training seconds per run")
    b.add_argument("--out", default="bench_out", help="output folder (default: bench_out)")
    b.add_argument("--evals", type=int, default=6, help="evaluations per run, geometric in time (default: 6)")
    b.add_argument("--eval-frames", type=int, default=5, help="frames evaluated (default: 5; 0 = all)")
    b.add_argument("--slice-seconds", type=float, default=5.0, help="interleaving slice (default: 5)")
    b.add_argument("--sequential", action="store_true", help="run presets one after another, not interleaved")
    b.add_argument(
        "--eval-at", default="", metavar="S,S,...", help="also evaluate at these training seconds (e.g. 180,600,1200)"
    )
    b.add_argument("--eval-at-start", action="store_true", help="also evaluate each model before its first step")
    b.add_argument("--stride", type=int, default=4, help="pixel grid of the consistency and tracking search")
    b.add_argument("--set", action="append", default=[], metavar="[PRESET.]KEY=VALUE", help="config override")
    b.add_argument("--device", default="auto")
    b.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    sp = sub.add_parser(
        SPEED,
        help="seconds per step of presets, side by side on one clip",
        description="Interleaves short blocks of training steps of each preset in one process.",
    )
    sp.add_argument("clip")
    sp.add_argument("--mask", action="append", default=[], metavar="FOLDER")
    sp.add_argument("--presets", default="draft,balanced,paper", help="comma-separated (default: draft,balanced,paper)")
    sp.add_argument("--steps", type=int, default=10, help="steps per block (default: 10)")
    sp.add_argument("--rounds", type=int, default=3, help="interleaved rounds (default: 3)")
    sp.add_argument("--device", default="auto")
    sp.add_argument("--work", default=None, help="folder for the flow cache (default: a temp folder)")
    ss = sub.add_parser(
        SCENE_SPEED,
        help="one clip fitted with components=auto and =all: seconds per step, PSNR",
        description="Both fits use the same config, seed and steps; only `components` differs. Prints one line "
        "per fit and the ratio of seconds per step, then a JSON summary as the last line.",
    )
    ss.add_argument("clip")
    ss.add_argument("--mask", action="append", default=[])
    ss.add_argument("--frames", type=frame_range, default=None, metavar="A:B")
    ss.add_argument("--preset", default="draft")
    ss.add_argument("--steps", type=int, default=300)
    ss.add_argument("--long-edge", type=int, default=384)
    ss.add_argument("--out", default=None, help="folder for the two runs (default: a temporary folder)")
    ep = sub.add_parser(
        EXPECTED_PSNR,
        help="record a finished fit's PSNR as what `estimate` expects of its preset",
        description="Writes RUN_DIR's full-frame PSNR (metrics.json) into engine/fit/expected_psnr.json.",
    )
    ep.add_argument("preset")
    ep.add_argument("run", metavar="RUN_DIR", help="a finished fit of PRESET")
    ep.add_argument("--clip", required=True, help="the clip's name, e.g. blackswan")
    ep.add_argument("--note", required=True, help="one line: where the measurement is documented")
    _add_farm_parser(sub)
    _add_clips_parser(sub)
    _add_masks_parser(sub)
    _add_scoring_parsers(sub)
    _add_paint_table_parser(sub)
    ms = sub.add_parser(
        MOTION_SCENES,
        help="synthetic clip folders with ground-truth tracks (turning, deforming, small_fast, thin, turning_depth, "
        "limbs_jump)",
        description="Write OUT/KIND/ for each scene: frames/, masks/, tracks_tapvid.npz and gt_uv.npz (the surface "
        "coordinate of every pixel), ready for `clips OUT`; see docs/accuracy-vs-time.md.",
    )
    ms.add_argument("out", metavar="OUT", help="folder for the clip folders")
    ms.add_argument("--width", type=int, default=480, help="frame width (default: 480)")
    ms.add_argument("--height", type=int, default=272, help="frame height (default: 272)")
    ms.add_argument("--frames", type=int, default=36, help="frames per clip (default: 36)")
    ms.add_argument("--seed", type=int, default=0, help="texture seed (default: 0)")
    ms.add_argument("--kinds", default=None, metavar="K,K,...", help="scenes to write (default: all six)")
    return p


def _add_clips_parser(sub: argparse._SubParsersAction) -> None:
    from engine.bench.degrade import DEFAULT_SEED, RECIPES

    c = sub.add_parser(
        CLIPS,
        help="one preset on every clip of a folder, fitted with degraded masks, scored against the precise ones",
        description="Degrade each clip's masks/ by a named recipe into OUT/masks/RECIPE/CLIP, fit the preset on "
        "every clip with them (one after another, each to its steps) and score the last model against the "
        "clip's own masks/: PSNR, foreground alpha IoU, atlas and chained-flow TAP-Vid delta_avg, training "
        "seconds. Writes OUT/clips.md, OUT/clips.json and OUT/runs/CLIP/bench.json; see docs/accuracy-vs-time.md.",
    )
    c.add_argument("root", metavar="CLIPS_ROOT", help="folder of clip folders (frames/, masks/, tracks_tapvid.npz)")
    c.add_argument("--preset", default="draft", help="fit preset (default: draft)")
    c.add_argument(
        "--degrade", default="dilated10_dropped10", choices=list(RECIPES), help="mask recipe (default: %(default)s)"
    )
    c.add_argument("--seed", type=int, default=DEFAULT_SEED, help="seed of the dropped frames (default: 0)")
    c.add_argument("--out", default="clips_out", help="output folder (default: clips_out)")
    c.add_argument("--budget-seconds", type=float, default=None, help="training seconds per clip (default: its steps)")
    c.add_argument("--eval-frames", type=int, default=0, help="frames evaluated (default: 0 = all)")
    c.add_argument("--stride", type=int, default=4, help="pixel grid of the consistency and tracking search")
    c.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="config override")
    c.add_argument("--device", default="auto")
    c.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")


def _add_masks_parser(sub: argparse._SubParsersAction) -> None:
    from engine.bench.degrade import DEFAULT_SEED, RECIPES

    m = sub.add_parser(
        MASKS,
        help="the mask snap alone on every clip: degraded masks' IoU against the precise ones, before and after",
        description="Degrade each clip's masks/ by a named recipe into OUT/masks/RECIPE/CLIP, read them at the "
        "fit's working size, snap them as fit does (engine/data/mask_snap.py) and print their IoU against the "
        "precise masks before and after, the offset and the snap's seconds. Nothing is fitted.",
    )
    m.add_argument("root", metavar="CLIPS_ROOT", help="folder of clip folders (frames/, masks/)")
    m.add_argument(
        "--degrade", default="dilated10_dropped10", choices=list(RECIPES), help="mask recipe (default: %(default)s)"
    )
    m.add_argument("--seed", type=int, default=DEFAULT_SEED, help="seed of the dropped frames (default: 0)")
    m.add_argument("--reach", type=int, default=16, help="the snap's search in working pixels (default: 16)")
    m.add_argument("--out", default="masks_out", help="output folder (default: masks_out)")


def _add_scoring_parsers(sub: argparse._SubParsersAction) -> None:
    pt = sub.add_parser(
        PAINT_TRACKS,
        help="where paint on the exported atlases shows in each frame, scored against TAP-Vid tracks",
        description="Read an export's native UV + alpha passes; each query takes the UV of the layer most opaque at "
        "it, and in every other frame the pixel that layer covers (Z > 0.5) whose UV is nearest (sub-pixel). Prints "
        "TAP-Vid delta_avg (native pixels and at 256x256); a frame where the layer covers nothing is a miss.",
    )
    pt.add_argument("manifest", metavar="EXPORT_MANIFEST", help="an export's manifest.json (or its folder)")
    _tracks_and_json(pt)
    ft = sub.add_parser(
        FLOW_TRACKS,
        help="the baseline: chained DIS optical flow on the native plate, scored against TAP-Vid tracks",
        description="Chain OpenCV DIS flow (preset MEDIUM) on the native greyscale frames, forward and backward "
        "from each query; prints TAP-Vid delta_avg as paint-tracks does.",
    )
    ft.add_argument("frames", metavar="FRAMES_DIR", help="the plate (its frames in order are the tracks' frames)")
    _tracks_and_json(ft)
    sh = sub.add_parser(
        SHARPNESS,
        help="the plate re-rendered from the exported atlas textures and passes: PSNR inside the mask",
        description="Sample each exported atlas texture at the exported UVs (bilinear, as Map UV does), sum the "
        "layers by their coverage and compare with the plate inside the mask: PSNR per frame, mean and pooled.",
    )
    sh.add_argument("manifest", metavar="EXPORT_MANIFEST", help="an export's manifest.json (or its folder)")
    sh.add_argument("--plate", required=True, metavar="FRAMES", help="the plate the export was made from")
    sh.add_argument("--masks", action="append", required=True, metavar="FOLDER", help="the object's masks")
    _tracks_and_json(sh, tracks=False)


def _add_paint_table_parser(sub: argparse._SubParsersAction) -> None:
    from engine.bench.degrade import DEFAULT_SEED, RECIPES

    pt = sub.add_parser(
        PAINT_TABLE,
        help="one preset fitted and exported on every clip of a folder, scored on the export (paint, flow, IoU, "
        "sharpness, PSNR, train s)",
        description="For each clip folder (frames/, masks/, tracks_tapvid.npz; a motion scene's gt_uv.npz and "
        "texture.png too): degrade its masks by RECIPE, `fit` the preset into OUT/runs/CLIP (a finished fit is "
        "kept), `export` it, and score the export: paint-tracks, flow-tracks, their ratio, the exported foreground "
        "alpha's IoU against masks/, sharpness (and a scene's true-texture sharpness), PSNR and training seconds. "
        "Writes OUT/paint.md and OUT/paint.json; --pictures also OUT/pictures/CLIP.png (a checkerboard painted once, "
        "first / middle / last frame, above the same colours carried by chained flow).",
    )
    pt.add_argument("root", metavar="CLIPS_ROOT", help="folder of clip folders")
    pt.add_argument("--preset", default="draft", help="fit preset (default: draft)")
    pt.add_argument("--degrade", default="exact", choices=list(RECIPES), help="mask recipe (default: %(default)s)")
    pt.add_argument("--seed", type=int, default=DEFAULT_SEED, help="seed of the dropped frames (default: 0)")
    pt.add_argument("--out", default="paint_out", help="output folder (default: paint_out)")
    pt.add_argument("--only", default=None, metavar="CLIP,CLIP", help="these clips only (default: every clip)")
    pt.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="fit config override")
    pt.add_argument("--threads", type=int, default=None, help="CPU threads of each fit (default: torch's choice)")
    pt.add_argument("--pictures", action="store_true", help="also write OUT/pictures/CLIP.png")
    split = pt.add_mutually_exclusive_group()
    split.add_argument(
        "--parts", action="store_true", help="fit a clip with masks_parts/PART/ folders with one layer per part"
    )
    split.add_argument(
        "--scribbles",
        action="store_true",
        help="fit a clip with masks_parts/PART/ folders with its one mask split by strokes drawn from the parts "
        "on --scribble-frames frames: the product's Split with Scribbles",
    )
    pt.add_argument(
        "--scribble-frames",
        type=int,
        default=3,
        metavar="N",
        help="with --scribbles: frames with strokes, spread evenly from the first to the last (default: 3)",
    )


def _paint_table(args: argparse.Namespace) -> int:
    from engine.bench.paint_table import PAINT_JSON, format_table, run_paint_table

    table = run_paint_table(
        args.root,
        args.out,
        preset=args.preset,
        degrade=args.degrade,
        seed=args.seed,
        sets=args.set,
        threads=args.threads,
        only=[c for c in args.only.split(",") if c] if args.only else None,
        pictures=args.pictures,
        parts=args.parts,
        scribbles=args.scribbles,
        scribble_frames=args.scribble_frames,
        command=[PROG, *args.argv],
    )
    print(format_table(table))
    print(str((Path(args.out) / PAINT_JSON).resolve()))
    return C.EXIT_OK


def _tracks_and_json(parser: argparse.ArgumentParser, tracks: bool = True) -> None:
    """The scorers' shared options: the clip's tracks and the report file."""
    if tracks:
        parser.add_argument("--tracks", required=True, metavar="NPZ", help="tracks_tapvid.npz of the clip")
    parser.add_argument("--json", default=None, metavar="OUT", help="also write the full scores to this file")


def _tracking_line(tool: str, report: dict) -> str:
    def fmt(v: float | None) -> str:
        return "–" if v is None else f"{v:.3f}"

    return (
        f"{tool}: delta_avg {fmt(report['delta_avg'])} (native px), {fmt(report['delta_avg_256'])} (256x256), "
        f"{report['scored_points']} positions"
    )


def _paint_tracks(args: argparse.Namespace) -> int:
    from engine.bench.paint_tracking import score_export
    from engine.bench.report_file import read_tracks, write_report

    report = score_export(args.manifest, read_tracks(args.tracks))
    print(_tracking_line(PAINT_TRACKS, report) + f", {report['misses']} misses (layer covers nothing)")
    if args.json:
        print(str(write_report(args.json, PAINT_TRACKS, {**report, "tracks": str(args.tracks)}).resolve()))
    return C.EXIT_OK


def _flow_tracks(args: argparse.Namespace) -> int:
    from engine.bench.flow_tracks import score_clip
    from engine.bench.report_file import read_tracks, write_report

    report = score_clip(args.frames, read_tracks(args.tracks))
    print(_tracking_line(FLOW_TRACKS, report))
    if args.json:
        print(str(write_report(args.json, FLOW_TRACKS, {**report, "tracks": str(args.tracks)}).resolve()))
    return C.EXIT_OK


def _sharpness(args: argparse.Namespace) -> int:
    from engine.bench.report_file import write_report
    from engine.bench.sharpness import atlas_sharpness

    report = atlas_sharpness(args.manifest, args.plate, args.masks)

    def fmt(v: float | None) -> str:
        return "–" if v is None else f"{v:.2f} dB"

    print(
        f"{SHARPNESS}: masked PSNR mean {fmt(report['psnr_mean'])}, pooled {fmt(report['psnr_pooled'])}, "
        f"{report['frames_scored']} frames"
    )
    if args.json:
        print(str(write_report(args.json, SHARPNESS, report).resolve()))
    return C.EXIT_OK


def _masks(args: argparse.Namespace) -> int:
    from engine.bench.mask_check import check_all, format_rows

    print(format_rows(check_all(args.root, args.out, args.degrade, args.seed, args.reach), args.degrade))
    return C.EXIT_OK


def _clips(args: argparse.Namespace) -> int:
    from engine.bench.all_clips import CLIPS_JSON, format_table, run_all_clips
    from engine.config import parse_set_args

    table = run_all_clips(
        args.root,
        args.out,
        preset=args.preset,
        degrade=args.degrade,
        seed=args.seed,
        overrides=parse_set_args(args.set),
        budget_seconds=args.budget_seconds,
        eval_frames=args.eval_frames,
        device_name=args.device,
        stride=args.stride,
        threads=args.threads,
        command=[PROG, *args.argv],
    )
    print(format_table(table))
    print(str((Path(args.out) / CLIPS_JSON).resolve()))
    return C.EXIT_OK


def _add_farm_parser(sub: argparse._SubParsersAction) -> None:
    fb = sub.add_parser(
        FARM,
        help="shots one after another vs through `farm dask` with local workers: wall times and their ratio",
        description="Plan the clips as a shots file and run the plan twice: every task one after another (all "
        "cores to each engine), then on a Dask scheduler and workers started on 127.0.0.1 (the cores split "
        "between them). Prints a markdown table (date, machine, this command) and writes OUT/farm_bench.json.",
    )
    fb.add_argument("clips", nargs="+", metavar="CLIP", help="clip folder holding frames/ and masks/")
    fb.add_argument("--out", default="farm_bench_out", help="output folder, replaced (default: farm_bench_out)")
    fb.add_argument("--preset", default="draft", help="fit preset of every shot (default: draft)")
    fb.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="fit config override")
    fb.add_argument("--workers", type=int, default=2, help="Dask workers, one engine each (default: 2)")
    fb.add_argument("--cores", type=int, default=None, help="torch threads in all (default: the machine's cores)")
    fb.add_argument("--export-chunk", type=int, default=None, metavar="N", help="frames per export-passes task")


def _bench(args: argparse.Namespace) -> int:
    from engine.bench.bench import BENCH_JSON, resolve_clip, run_bench, summary_table
    from engine.config import parse_set_args

    if (args.mask or args.tracks or args.score_masks) and len(args.clips) != 1:
        raise InputError(
            None, "--mask, --tracks and --score-masks need exactly one clip", "bench one clip, or use clip folders"
        )
    clips = [resolve_clip(c, args.mask or None, args.tracks, args.score_masks or None) for c in args.clips]
    record = run_bench(
        clips,
        [p.strip() for p in args.presets.split(",") if p.strip()],
        args.budget_seconds,
        args.out,
        overrides=parse_set_args(args.set),
        evals=args.evals,
        eval_frames=args.eval_frames,
        slice_seconds=args.slice_seconds,
        sequential=args.sequential,
        device_name=args.device,
        stride=args.stride,
        command=["python", "-m", "engine.bench", *args.argv],
        threads=args.threads,
        eval_at_start=args.eval_at_start,
        eval_at=parse_eval_at(args.eval_at),
    )
    print(summary_table(record))
    print(str((Path(args.out) / BENCH_JSON).resolve()))
    return C.EXIT_OK


def _speed(args: argparse.Namespace) -> int:
    from engine.bench.speed import format_table, measure_step_times

    with tempfile.TemporaryDirectory() as tmp:
        rows = measure_step_times(
            args.clip,
            args.mask,
            args.presets.split(","),
            Path(args.work or tmp),
            steps=args.steps,
            rounds=args.rounds,
            device_name=args.device,
        )
    print(format_table(rows))
    return C.EXIT_OK


def _scene_speed(args: argparse.Namespace) -> int:
    from engine.bench.scene_speed import compare_components, print_comparison

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out) if args.out else Path(tmp)
        res = compare_components(args.clip, args.mask, out, args.preset, args.steps, args.long_edge, args.frames)
    print_comparison(res)
    return C.EXIT_OK


def _expected_psnr(args: argparse.Namespace) -> int:
    from engine.bench.bench import record_expected_psnr

    print(record_expected_psnr(args.preset, args.run, args.clip, args.note))
    return C.EXIT_OK


def _farm(args: argparse.Namespace) -> int:
    from engine.bench.bench import resolve_clip
    from engine.bench.farm import FARM_BENCH_JSON, format_table, run_farm_bench

    record = run_farm_bench(
        [resolve_clip(c) for c in args.clips],
        Path(args.out),
        command=[PROG, *args.argv],
        preset=args.preset,
        overrides=args.set,
        workers=args.workers,
        cores=args.cores,
        export_chunk=args.export_chunk,
    )
    print(format_table(record))
    print(str((Path(args.out) / FARM_BENCH_JSON).resolve()))
    return C.EXIT_OK


def _motion_scenes(args: argparse.Namespace) -> int:
    from engine.bench.motion_scenes import KINDS, write_motion_clips

    kinds = tuple(k.strip() for k in args.kinds.split(",") if k.strip()) if args.kinds else KINDS
    unknown = [k for k in kinds if k not in KINDS]
    if unknown or args.width < 16 or args.height < 16 or args.frames < 2:
        problem = f"unknown scene {unknown[0]!r}" if unknown else "a motion scene needs 16x16 pixels and 2 frames"
        raise InputError(None, problem, f"choose from {', '.join(KINDS)}; --width/--height >= 16, --frames >= 2")
    for folder in write_motion_clips(args.out, args.width, args.height, args.frames, args.seed, kinds):
        print(str(folder.resolve()))
    return C.EXIT_OK


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(argv)
    args.argv = argv  # recorded by bench
    tools = {
        BENCH: _bench,
        CLIPS: _clips,
        SPEED: _speed,
        SCENE_SPEED: _scene_speed,
        EXPECTED_PSNR: _expected_psnr,
        FARM: _farm,
        MOTION_SCENES: _motion_scenes,
        MASKS: _masks,
        PAINT_TRACKS: _paint_tracks,
        FLOW_TRACKS: _flow_tracks,
        SHARPNESS: _sharpness,
        PAINT_TABLE: _paint_table,
    }
    if args.tool not in tools:
        parser.print_help()
        return C.EXIT_OK
    try:
        return tools[args.tool](args)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return C.EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return C.EXIT_CANCELLED
    except Exception:
        traceback.print_exc()
        return C.EXIT_FAILED


if __name__ == "__main__":
    sys.exit(main())
