"""Command line: parse, call, map errors to exit codes. No logic lives here."""

from __future__ import annotations

import argparse
import sys
import traceback
from pathlib import Path

from engine import contract as C
from engine.errors import InputError

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
exit codes: 0 done, 1 engine error, 2 bad input (one line names the file and the fix),
            3 cancelled by SIGINT/SIGTERM (a checkpoint was written: --resume continues).
"""


def _frame_range(text: str) -> tuple[int, int]:
    a, sep, b = text.partition(":")
    try:
        if not sep:
            raise ValueError
        return int(a), int(b)
    except ValueError:
        raise argparse.ArgumentTypeError(f"frame range {text!r} must be FIRST:LAST, e.g. 0:49") from None


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m engine", description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
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
    f.add_argument("clip", nargs="?", help="image-sequence folder (png/jpg/exr/dpx/tif) or movie file")
    f.add_argument(
        "--mask",
        action="append",
        default=[],
        metavar="FOLDER",
        help="foreground mask sequence, one folder per foreground layer (>0.5 = foreground)",
    )
    f.add_argument("--out", required=True, metavar="RUN_DIR", help="run folder (created; never overwritten)")
    f.add_argument("--preset", default="balanced", help="draft | balanced | final | paper (default: balanced)")
    f.add_argument("--device", default="auto", help="auto | cpu | cuda | mps (default: auto)")
    f.add_argument(
        "--frames",
        type=_frame_range,
        default=None,
        metavar="FIRST:LAST",
        help="inclusive range of positions in the sequence (default: all)",
    )
    f.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override any config field (see --help-config)",
    )
    f.add_argument("--resume", action="store_true", help="continue the fit in RUN_DIR from its checkpoint")
    f.add_argument("--no-bar", action="store_true", help="no progress bar on stderr (JSON lines only)")
    f.add_argument("--help-config", action="store_true", help="list every config field and exit")
    d = sub.add_parser(
        C.VERB_DEMO,
        help="fit the embedded demo clip (README command 1)",
        description="Generate the demo plate, fit it, and write a contact sheet. Idempotent.",
    )
    d.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    d.add_argument("--preset", default="draft", help="preset (default: draft)")
    d.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config field")
    sp = sub.add_parser(
        C.VERB_SPEED,
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
    return p


def _cmd_speed(args: argparse.Namespace) -> int:
    import tempfile

    from engine.speed import format_table, measure_step_times

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


def _cmd_fit(args: argparse.Namespace) -> int:
    from engine.config import FitConfig, apply_overrides, config_help, parse_set_args, preset_config

    if args.help_config:
        print(config_help())
        return C.EXIT_OK
    from engine.trainer import FitCancelled, fit

    run_dir = Path(args.out)
    overrides = parse_set_args(args.set)
    if args.resume:
        cfg_path = run_dir / C.RUN_CONFIG
        if not cfg_path.exists():
            raise InputError(cfg_path, "no fit to resume here", "run `fit` without --resume first")
        cfg = FitConfig.from_json(cfg_path.read_text(encoding="utf-8"), cfg_path)
    else:
        cfg = preset_config(args.preset)
    cfg = apply_overrides(cfg, overrides)
    try:
        metrics = fit(
            args.clip,
            args.mask,
            run_dir,
            cfg,
            device_name=args.device,
            resume=args.resume,
            frame_range=args.frames,
            progress_bar=not args.no_bar,
        )
    except FitCancelled as exc:
        print(f"cancelled: {exc}; continue with: python -m engine fit --resume --out {run_dir}", file=sys.stderr)
        return C.EXIT_CANCELLED
    print(
        f"fit done: PSNR {metrics['psnr']:.2f} dB over every pixel, {metrics['steps']} steps in "
        f"{metrics['train_seconds']:.0f} s -> {run_dir}",
        file=sys.stderr,
    )
    return C.EXIT_OK


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.verb is None:
        parser.print_help()
        return C.EXIT_OK
    try:
        if args.verb == C.VERB_FIT:
            return _cmd_fit(args)
        if args.verb == C.VERB_SPEED:
            return _cmd_speed(args)
        if args.verb == C.VERB_DEMO:
            from engine.config import parse_set_args
            from engine.demo import run_demo
            from engine.trainer import FitCancelled

            try:
                run_demo(Path(args.out), args.preset, parse_set_args(args.set))
            except FitCancelled:
                return C.EXIT_CANCELLED
            return C.EXIT_OK
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return C.EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return C.EXIT_CANCELLED
    except Exception:
        traceback.print_exc()
        return C.EXIT_FAILED
    parser.error(f"unknown verb {args.verb}")
    return C.EXIT_BAD_INPUT
