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
    return p


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
