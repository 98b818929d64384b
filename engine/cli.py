"""Command line: parse, call, map errors to exit codes. No logic lives here: the parser is ``cli_parser``, each
verb's handler ``cli_commands``."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import traceback
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from . import contract as C
from .cli_commands import HANDLERS, RESUME_COMMAND
from .cli_parser import build_parser
from .errors import FitDiverged, InputError
from .terms.cli import EXIT_DIVERGED, EXIT_FAILED
from .terms.protocol import OPENJD_PROGRESS_ENV


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


#: The command `pip install` makes (pyproject.toml's [project.scripts]): the same verbs as `python -m engine`.
CONSOLE_SCRIPT = "neural-atlas"


def _cancelled_line(args: argparse.Namespace, exc: KeyboardInterrupt) -> str:
    """The one line printed when a verb is stopped by SIGINT/SIGTERM outside the training loop."""
    how = str(exc) or "SIGINT"
    line = f"cancelled: {args.verb} stopped by {how} before it finished; nothing half-written was kept"
    if args.verb == C.VERB_FIT and args.out is not None:
        from .fit.run_folder import RunFolder

        run = RunFolder(args.out)
        if run.checkpoint.exists():
            return f"{line}; continue with: {RESUME_COMMAND} {run.path}"
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


@contextlib.contextmanager
def _output(args: argparse.Namespace) -> Iterator[Callable[[int], None]]:
    """stdout and stderr as -q, -v and an OpenJD task (``terms.protocol.OPENJD_PROGRESS_ENV``) ask, for the verb's run;
    yields what to call with its exit code (an OpenJD task's 100 % once it succeeded). Without them: untouched."""
    from .fit.progress import LineTap, OpenJDProgress, quiet_lines, verbose_lines

    openjd = OpenJDProgress() if os.environ.get(OPENJD_PROGRESS_ENV, "") else None
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
    """The verb's handler, its errors mapped to the exit codes (one line for what the user can fix)."""
    from .io.atomic import disk_full_error

    try:
        if args.verb in HANDLERS:
            return HANDLERS[args.verb](args)
    except (InputError, C.RunLocked) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return C.EXIT_BAD_INPUT
    except FitDiverged as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_DIVERGED
    except KeyboardInterrupt as exc:
        print(_cancelled_line(args, exc), file=sys.stderr)
        return C.EXIT_CANCELLED
    except (OSError, RuntimeError) as exc:
        # a full disk or a quota is the machine's state, not an engine bug: one line, and what survives
        filename = getattr(exc, "filename", None)
        full = disk_full_error(exc, Path(filename).parent if filename else Path.cwd())
        if full is None:
            traceback.print_exc()
            return EXIT_FAILED
        print(f"error: {full}", file=sys.stderr)
        return C.EXIT_BAD_INPUT
    except Exception:
        traceback.print_exc()
        return EXIT_FAILED
    parser.error(f"unknown verb {args.verb}")
    return C.EXIT_BAD_INPUT
