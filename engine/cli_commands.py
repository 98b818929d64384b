"""The command line's verbs: each handler takes its parsed arguments, calls the engine and prints what the verb
reports (``HANDLERS``). What a verb's arguments are is ``cli_parser``; exit codes and signals are ``cli``."""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from . import contract as C
from .errors import InputError
from .terms.cli import DEFAULT_PRESET, VERB_DEMO, VERB_NUKE, VERB_PREVIEW, VERB_RENDER
from .terms.farm import FARM_DASK, FARM_PLAN
from .terms.protocol import EVENT_WRITTEN, progress_line
from .terms.versions import SCHEMA_VERSION

if TYPE_CHECKING:
    from .fit.run_plan import FitPlan

#: How a cancelled or interrupted fit goes on (the run folder follows).
RESUME_COMMAND = f"python -m {C.CLI_MODULE} fit --resume --out"


def print_paths(paths: Iterable[Path | str]) -> int:
    """A verb's last lines: one ``written`` message listing what it wrote (a program reads that), then the same
    paths one per line (what the add-on and shell scripts read: the last line is the path when there is one)."""
    from .io.images import display_path  # a name that is not UTF-8 would stop a strict stdout

    written = [os.fspath(path) for path in paths]
    print(progress_line(EVENT_WRITTEN, paths=written))  # JSON escapes what is not UTF-8
    for path in written:
        print(display_path(path))
    return C.EXIT_OK


def _positions(clip: str | None, frames: tuple[int, int] | None, start_frame: int | None = None) -> Any:
    """The plate frame numbers of --frames as the positions the engine's readers take (None: every frame)."""
    if frames is None or clip is None:
        return frames
    from .io.clip import frame_positions

    return frame_positions(clip, frames, start_frame)


def _cmd_estimate(args: argparse.Namespace) -> int:
    from .config import parse_set_args
    from .fit.estimate import estimate, format_estimate
    from .fit.fit_inputs import FitInputs
    from .fit.progress import Reporter

    result = estimate(
        FitInputs(args.clip, args.mask, _positions(args.clip, args.frames)),
        presets=[p.strip() for p in args.presets.split(",")] if args.presets else None,
        work_dir=args.work,
        calib_seconds=args.calib_seconds,
        device_name=args.device,
        overrides=parse_set_args(args.set),
        threads=args.threads,
        # --json is for a program (the add-on): progress lines (``job``) before the result; the table stays plain
        reporter=Reporter() if args.json else None,
    )
    print(json.dumps(result) if args.json else format_estimate(result))
    return C.EXIT_OK


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
        follow_flow=args.follow_flow,
        precision=args.precision,
        stmap=args.stmap,
    )
    return print_paths([path])


def _cmd_render(args: argparse.Namespace) -> int:
    from .edit.render import RenderSettings, parse_edit_args, render_manifest

    settings = RenderSettings(args.format, args.filter, args.name, args.depth)
    out = render_manifest(
        args.manifest, args.out, parse_edit_args(args.edit), settings, args.movie, not args.no_bar, args.frames
    )
    return print_paths([Path(out).resolve()])


def _cmd_project_frame(args: argparse.Namespace) -> int:
    from .edit.project_frame import project_frame

    def stage(name: str, message: str, step: int, total: int) -> None:
        # the add-on's progress bar: what it does now, and how far (stages done of all)
        print(progress_line(C.EVENT_STAGE, stage=name, message=message), flush=True)
        print(progress_line(C.EVENT_PROGRESS, step=step, total=total), flush=True)

    return print_paths(project_frame(args.manifest, args.frame, args.edit, args.layer, on_stage=stage).values())


def _cmd_realign(args: argparse.Namespace) -> int:
    from .edit.realign import realign, realign_measured

    if args.measure:
        manifest, report = realign_measured(args.manifest, args.source, args.layer, args.frame_step)
        print(json.dumps(report))
    else:
        manifest, _ = realign(args.manifest, args.source, args.layer, args.frame_step)
    return print_paths([manifest.path])


def _cmd_preview(args: argparse.Namespace) -> int:
    from .edit.preview import write_previews

    return print_paths(write_previews(args.manifest, args.out, movies=not args.no_movies))


def _cmd_nuke(args: argparse.Namespace) -> int:
    from .export.nuke import write_nuke_script

    return print_paths([write_nuke_script(args.manifest, args.out, args.filter, args.ocio_config)])


def _cmd_relink(args: argparse.Namespace) -> int:
    from .export.manifest import Manifest
    from .export.relink import relink_plate

    for line in relink_plate(args.manifest, args.plate):
        print(line, file=sys.stderr)
    return print_paths([Manifest(args.manifest).path])


def _cmd_masks(args: argparse.Namespace) -> int:
    """Progress goes to stdout as a JSON stage line, so stderr holds nothing but a failure's one line; the folder
    is printed last (``print_paths``: as text any terminal takes, a name that is not UTF-8 showing its bytes as
    \\xNN)."""
    from .data.auto_masks import write_auto_masks

    def say(message: str) -> None:
        print(progress_line(C.EVENT_STAGE, stage=C.VERB_MASKS, message=message), flush=True)

    frames = _positions(args.clip, args.frames)
    report = write_auto_masks(
        args.clip, args.out, frame_range=frames, truth=args.truth, say=say, colorspace=args.colorspace
    )
    for line in report.summary():
        print(line)
    print(progress_line(C.EVENT_MASKS, found=bool(report.result.found), folder=str(report.folder),
                          message=report.result.message))  # fmt: skip
    return print_paths([report.folder])


def _cmd_parts(args: argparse.Namespace) -> int:
    """Progress goes to stdout as a JSON stage line; the summary, then the folder (or the no-split line) last."""
    from .data.motion_parts_files import write_motion_parts

    frames = _positions(args.clip, args.frames)
    report = write_motion_parts(args.clip, args.mask, args.out, frame_range=frames, colorspace=args.colorspace,
                                say=_say_parts)  # fmt: skip
    for line in report.summary():  # nothing split: its one line is the last
        print(line)
    return 0 if report.folder is None else print_paths([report.folder])


def _cmd_farm(args: argparse.Namespace) -> int:
    """Plan, then hand the plan to the back end; progress per shot as JSON lines, the result's path last."""
    missing = getattr(args, "farm_missing", None)
    if missing is not None:
        raise InputError(
            None, f"farm {args.farm_command} is not available ({missing})", "install the engine's farm extra"
        )
    if args.farm_command == FARM_DASK:
        from .farm.dask_backend import run_dask

        return run_dask(args)
    if args.farm_command == C.FARM_FLAMENCO:
        from .farm.flamenco import run_flamenco

        return run_flamenco(args)
    from .farm.plan import plan_with_shots, task_graph_text
    from .farm.shots import load_shots

    shots = load_shots(args.shots)
    plan, shot_plans = plan_with_shots(shots)
    if args.farm_command == FARM_PLAN:
        if args.json:
            print(json.dumps({"schema": SCHEMA_VERSION, **plan.to_json()}, indent=2))
        else:
            print(task_graph_text(plan))
        return C.EXIT_OK
    from .farm.openjd import run_openjd

    return print_paths(run_openjd(args, plan, shot_plans, shots.path)[:1])


def _cmd_fit(args: argparse.Namespace) -> int:
    """``fit``: the run folder's plan (``engine.fit.run_plan``: start, resume, refit, refine, or nothing left to
    do), then the fit; one summary line on stderr."""
    from .config import config_help

    if args.help_config:
        print(config_help())
        return C.EXIT_OK
    if args.out is None:
        raise InputError(None, "no run folder given", "pass --out RUN_DIR (a new folder, or a fit's to --resume)")
    from .fit.fit_inputs import FitInputs
    from .fit.run_plan import PLAN_DONE, PLAN_REFINE, FitMode, plan_fit
    from .fit.trainer import FitCancelled, fit

    run_dir = Path(args.out)
    inputs = FitInputs(
        clip=args.clip,
        masks=args.mask,
        frames=args.frames,
        scribbles=args.scribbles,
        auto_masks=args.auto_masks,
        colorspace=args.colorspace,
        fps=args.fps,
        start_frame=args.start_frame,
    )
    plan = plan_fit(
        run_dir,
        inputs,
        FitMode(args.resume, args.refit, args.resume_if_started, args.refine),
        preset=args.preset,
        default_preset=DEFAULT_PRESET,
        set_args=args.set,
        auto_parts=args.auto_parts,
    )
    if plan.action == PLAN_DONE:  # --resume-if-started: this fit is finished already
        metrics = plan.metrics or {}
        print(f"already fitted: {metrics.get('steps')} steps, PSNR {metrics.get('psnr')} dB -> {run_dir}",
              file=sys.stderr)  # fmt: skip
        return C.EXIT_OK
    if plan.action == PLAN_REFINE:
        return _cmd_refine(args, run_dir, plan)
    try:
        metrics = fit(run_dir, plan, device_name=args.device, progress_bar=not args.no_bar)
    except FitCancelled as exc:
        print(f"cancelled: {exc}; continue with: {RESUME_COMMAND} {run_dir}", file=sys.stderr)
        return C.EXIT_CANCELLED
    print(
        f"fit done: PSNR {metrics['psnr']:.2f} dB over every pixel, {metrics['steps']} steps in "
        f"{metrics['train_seconds']:.0f} s -> {run_dir}",
        file=sys.stderr,
    )
    return C.EXIT_OK


def _say_parts(message: str) -> None:
    """The progress of ``parts``: a JSON stage line on stdout."""
    print(progress_line(C.EVENT_STAGE, stage=C.VERB_PARTS, message=message), flush=True)


def _cmd_refine(args: argparse.Namespace, run_dir: Path, plan: FitPlan) -> int:
    """``fit --refine [STEPS] [--preset P]``: a finished fit continued (``engine.fit.refine``); the export its edit
    layers were painted on is recorded once training has run, for ``realign``."""
    from .edit.aligned import record_paint_export
    from .fit.trainer import FitCancelled, fit

    try:
        metrics = fit(run_dir, plan, device_name=args.device, progress_bar=not args.no_bar)
    except FitCancelled as exc:
        record_paint_export(run_dir)
        print(f"cancelled: {exc}; continue with: {RESUME_COMMAND} {run_dir}", file=sys.stderr)
        return C.EXIT_CANCELLED
    painted_on = record_paint_export(run_dir)
    carry = f"; carry the paint over: export, then {C.VERB_REALIGN} --from {painted_on}" if painted_on else ""
    print(
        f"fit refined from {plan.refined_from} steps: PSNR {metrics['psnr']:.2f} dB over every pixel, "
        f"{metrics['steps']} steps in {metrics['train_seconds']:.0f} s -> {run_dir}{carry}",
        file=sys.stderr,
    )
    return C.EXIT_OK


def _cmd_demo(args: argparse.Namespace) -> int:
    """``demo``: the embedded demo clip fitted, exported and edited (``engine.demo``)."""
    from .config import parse_set_args
    from .demo import run_demo
    from .fit.trainer import FitCancelled

    try:
        run_demo(Path(args.out), args.preset, parse_set_args(args.set))
    except FitCancelled as exc:
        print(f"cancelled: {exc}; run the demo again to continue", file=sys.stderr)
        return C.EXIT_CANCELLED
    return C.EXIT_OK


#: Each verb's handler: its parsed arguments in, its exit code out.
HANDLERS: dict[str, Callable[[argparse.Namespace], int]] = {
    C.VERB_FIT: _cmd_fit,
    C.VERB_EXPORT: _cmd_export,
    VERB_RENDER: _cmd_render,
    C.VERB_PROJECT_FRAME: _cmd_project_frame,
    C.VERB_REALIGN: _cmd_realign,
    VERB_PREVIEW: _cmd_preview,
    C.VERB_ESTIMATE: _cmd_estimate,
    C.VERB_MASKS: _cmd_masks,
    C.VERB_PARTS: _cmd_parts,
    VERB_NUKE: _cmd_nuke,
    C.VERB_RELINK: _cmd_relink,
    C.VERB_FARM: _cmd_farm,
    VERB_DEMO: _cmd_demo,
}
