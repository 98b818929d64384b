"""``python -m bench TOOL ...``: parse the command line (``bench.tool_parsers``, which lists the
tools), run the tool (each imports its module only when it runs) and print its result, and map its errors to
the exit codes of ``engine.contract``. The tools are not part of the product and not in the extension zip.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import traceback
from pathlib import Path

from bench.tool_parsers import (
    BENCH,
    CLIPS,
    EXPECTED_PSNR,
    EXPORT_COST,
    EXPORT_SIZE,
    FARM,
    FLOW_TRACKS,
    LONG_PLATE,
    MASKS,
    MOTION_SCENES,
    PAINT_GAPS,
    PAINT_SLIP,
    PAINT_TABLE,
    PAINT_TRACKS,
    PROG,
    SCENE_SPEED,
    SHARPNESS,
    SPEED,
    build_parser,
)
from engine import contract as C
from engine.errors import InputError
from engine.terms.cli import EXIT_FAILED


def parse_eval_at(text: str) -> tuple[float, ...]:
    """``--eval-at 180,600,1200`` -> (180.0, 600.0, 1200.0); a bad entry is a one-line input error."""
    try:
        return tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        problem, fix = f"--eval-at {text!r} is not a list of seconds", "write e.g. --eval-at 180,600,1200"
        raise InputError(None, problem, fix) from None


def _paint_table(args: argparse.Namespace) -> int:
    from bench.paint_table import PAINT_JSON, TableFit, format_table, run_paint_table

    how = TableFit.of_flags(
        parts=args.parts,
        scribbles=args.scribbles,
        auto_parts=args.auto_parts,
        one_layer=args.one_layer,
        preset=args.preset,
        degrade=args.degrade,
        seed=args.seed,
        sets=tuple(args.set),
        threads=args.threads,
        scribble_frames=args.scribble_frames,
        follow_flow=args.follow_flow,
    )
    table = run_paint_table(
        args.root, args.out, how, only=args.only, pictures=args.pictures, command=[PROG, *args.argv]
    )
    print(format_table(table))
    print(str((Path(args.out) / PAINT_JSON).resolve()))
    return C.EXIT_OK


def _tracking_line(tool: str, report: dict) -> str:
    def fmt(v: float | None) -> str:
        return "–" if v is None else f"{v:.3f}"

    return (
        f"{tool}: delta_avg {fmt(report['delta_avg'])} (native px), {fmt(report['delta_avg_256'])} (256x256), "
        f"{report['scored_points']} positions"
    )


def _paint_tracks(args: argparse.Namespace) -> int:
    from bench.paint_tracking import score_export
    from bench.report_file import read_tracks, write_report

    report = score_export(args.manifest, read_tracks(args.tracks))
    print(_tracking_line(PAINT_TRACKS, report) + f", {report['misses']} misses (layer covers nothing)")
    if args.json:
        print(str(write_report(args.json, PAINT_TRACKS, {**report, "tracks": str(args.tracks)}).resolve()))
    return C.EXIT_OK


def _flow_tracks(args: argparse.Namespace) -> int:
    from bench.flow_tracks import score_clip
    from bench.report_file import read_tracks, write_report

    report = score_clip(args.frames, read_tracks(args.tracks))
    print(_tracking_line(FLOW_TRACKS, report))
    if args.json:
        print(str(write_report(args.json, FLOW_TRACKS, {**report, "tracks": str(args.tracks)}).resolve()))
    return C.EXIT_OK


def _measure(value: float | None, unit: str) -> str:
    """A scorer's number as printed: two decimals and its unit, or "–" where nothing was scored."""
    return "–" if value is None else f"{value:.2f} {unit}"


def _sharpness(args: argparse.Namespace) -> int:
    from bench.report_file import write_report
    from bench.sharpness import atlas_sharpness

    report = atlas_sharpness(args.manifest, args.plate, args.masks)
    print(
        f"{SHARPNESS}: masked PSNR mean {_measure(report['psnr_mean'], 'dB')}, "
        f"pooled {_measure(report['psnr_pooled'], 'dB')}, {report['frames_scored']} frames"
    )
    if args.run is not None:
        from bench.network_sharpness import network_sharpness

        report["network"] = network_sharpness(args.run, args.plate, args.masks)
        print(f"{SHARPNESS}: the fit's networks, pooled {_measure(report['network']['psnr_pooled'], 'dB')}")
    if args.json:
        print(str(write_report(args.json, SHARPNESS, report).resolve()))
    return C.EXIT_OK


def _paint_slip(args: argparse.Namespace) -> int:
    from bench.paint_slip import export_slip
    from bench.report_file import write_report

    report = export_slip(args.manifest, args.plate)
    for name, layer in report["layers"].items():
        print(
            f"{PAINT_SLIP}: {name}: median {_measure(layer['median_px'], 'px')}, "
            f"mean {_measure(layer['mean_px'], 'px')}, 90% {_measure(layer['p90_px'], 'px')} "
            f"over {layer['pixels']} pixels of {report['frame_pairs']} frame pairs"
        )
    if args.json:
        print(str(write_report(args.json, PAINT_SLIP, report).resolve()))
    return C.EXIT_OK


def _masks(args: argparse.Namespace) -> int:
    from bench.mask_check import check_all, format_rows

    print(format_rows(check_all(args.root, args.out, args.degrade, args.seed, args.reach), args.degrade))
    return C.EXIT_OK


def _clips(args: argparse.Namespace) -> int:
    from bench.all_clips import CLIPS_JSON, clips_plan, format_table, run_all_clips
    from engine.config import parse_set_args

    plan = clips_plan(
        args.preset,
        args.budget_seconds,
        overrides=parse_set_args(args.set),
        eval_frames=args.eval_frames,
        device_name=args.device,
        stride=args.stride,
        threads=args.threads,
    )
    table = run_all_clips(args.root, args.out, plan, args.degrade, args.seed, command=[PROG, *args.argv])
    print(format_table(table))
    print(str((Path(args.out) / CLIPS_JSON).resolve()))
    return C.EXIT_OK


def _bench(args: argparse.Namespace) -> int:
    from bench.bench import BENCH_JSON, BenchPlan, run_bench
    from bench.bench_clip import resolve_clip
    from bench.bench_summary import summary_table
    from engine.config import parse_set_args

    if (args.mask or args.tracks or args.score_masks) and len(args.clips) != 1:
        raise InputError(
            None, "--mask, --tracks and --score-masks need exactly one clip", "bench one clip, or use clip folders"
        )
    clips = [resolve_clip(c, args.mask or None, args.tracks, args.score_masks or None) for c in args.clips]
    plan = BenchPlan(
        tuple(p.strip() for p in args.presets.split(",") if p.strip()),
        args.budget_seconds,
        overrides=parse_set_args(args.set),
        evals=args.evals,
        eval_frames=args.eval_frames,
        eval_at_start=args.eval_at_start,
        eval_at=parse_eval_at(args.eval_at),
        stride=args.stride,
        slice_seconds=args.slice_seconds,
        sequential=args.sequential,
        device_name=args.device,
        threads=args.threads,
    )
    record = run_bench(clips, plan, args.out, command=["python", "-m", "bench", *args.argv])
    print(summary_table(record))
    print(str((Path(args.out) / BENCH_JSON).resolve()))
    return C.EXIT_OK


def _speed(args: argparse.Namespace) -> int:
    from bench.speed import format_table, measure_step_times

    with tempfile.TemporaryDirectory() as tmp:
        rows = measure_step_times(
            args.clip,
            args.mask,
            args.presets.split(","),
            Path(args.work or tmp),
            steps=args.steps,
            rounds=args.rounds,
            device_name=args.device,
            at_step=args.at_step,
        )
    print(format_table(rows))
    return C.EXIT_OK


def _scene_speed(args: argparse.Namespace) -> int:
    from bench.scene_speed import compare_components, print_comparison

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out) if args.out else Path(tmp)
        res = compare_components(args.clip, args.mask, out, args.preset, args.steps, args.long_edge, args.frames)
    print_comparison(res)
    return C.EXIT_OK


def _expected_psnr(args: argparse.Namespace) -> int:
    from bench.finished_fit import record_expected_psnr

    print(record_expected_psnr(args.preset, args.run, args.clip, args.note))
    return C.EXIT_OK


def _farm(args: argparse.Namespace) -> int:
    from bench.bench_clip import resolve_clip
    from bench.farm import FARM_BENCH_JSON, format_table, run_farm_bench

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
    from bench.motion_scenes import write_motion_clips
    from bench.motion_spec import KINDS

    kinds = tuple(k.strip() for k in args.kinds.split(",") if k.strip()) if args.kinds else KINDS
    unknown = [k for k in kinds if k not in KINDS]
    if unknown or args.width < 16 or args.height < 16 or args.frames < 2:
        problem = f"unknown scene {unknown[0]!r}" if unknown else "a motion scene needs 16x16 pixels and 2 frames"
        raise InputError(None, problem, f"choose from {', '.join(KINDS)}; --width/--height >= 16, --frames >= 2")
    for folder in write_motion_clips(args.out, args.width, args.height, args.frames, args.seed, kinds):
        print(str(folder.resolve()))
    return C.EXIT_OK


def _long_plate(args: argparse.Namespace) -> int:
    from bench.long_plate import write_long_plate

    if args.width < 16 or args.height < 16 or args.frames < 1:
        problem, fix = "a long plate needs 16x16 pixels and a frame", "give --width/--height >= 16, --frames >= 1"
        raise InputError(None, problem, fix)
    print(str(write_long_plate(args.clip, args.out, args.width, args.height, args.frames).resolve()))
    return C.EXIT_OK


def _paint_gaps(args: argparse.Namespace) -> int:
    from bench.paint_gaps import plot_paint_gaps, read_table

    if args.label and len(args.label) != len(args.tables):
        problem = f"{len(args.label)} --label for {len(args.tables)} tables"
        raise InputError(None, problem, "give one --label per table, or none")
    tables = [read_table(t) for t in args.tables]
    plot_paint_gaps(tables, args.out, args.only, args.label)
    print(str(Path(args.out).resolve()))
    return C.EXIT_OK


def _export_cost(args: argparse.Namespace) -> int:
    from bench.export_cost import format_cost, measure_export_cost
    from bench.report_file import write_report

    work = Path(args.work) if args.work else None
    report = measure_export_cost(Path(args.run), args.repeats, args.threads, work, args.compare)
    print(format_cost(report))
    if args.json:
        print(str(write_report(args.json, EXPORT_COST, report).resolve()))
    return C.EXIT_OK


def _export_size(args: argparse.Namespace) -> int:
    from bench.export_size import format_sizes, measure_export_size
    from bench.report_file import write_report
    from engine.export.manifest import Manifest

    export = Path(args.export)
    rows = measure_export_size(export, args.frames)
    folder = export.parent if export.name == C.MANIFEST_NAME else export
    resolution = tuple(Manifest(folder).resolution) if (folder / C.MANIFEST_NAME).is_file() else None
    print(format_sizes(folder, rows, resolution))  # type: ignore[arg-type]
    if args.json:
        report = {"export": str(folder), "resolution": resolution, "rows": [vars(r) for r in rows]}
        print(str(write_report(args.json, EXPORT_SIZE, report).resolve()))
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
        LONG_PLATE: _long_plate,
        MASKS: _masks,
        PAINT_TRACKS: _paint_tracks,
        FLOW_TRACKS: _flow_tracks,
        SHARPNESS: _sharpness,
        PAINT_TABLE: _paint_table,
        PAINT_GAPS: _paint_gaps,
        PAINT_SLIP: _paint_slip,
        EXPORT_COST: _export_cost,
        EXPORT_SIZE: _export_size,
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
        return EXIT_FAILED


if __name__ == "__main__":
    sys.exit(main())
