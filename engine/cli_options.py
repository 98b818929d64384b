"""The command line's shared vocabulary: the argument types (``--frames``, ``--fps``), the options several verbs
take, each defined once here so their help cannot drift between verbs (``--frames`` of a plate, ``--set``,
``--device``, ``--no-bar``, a plate or manifest argument, ``--layer``), the verbs' common epilog and -q/-v.

The options are added by functions rather than argparse parent parsers: a parent's arguments come first in a
verb's help and usage, and each verb lists its own in the order a user reads them."""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from typing import Any

from . import contract as C
from .terms.cli import EXPORT_FOLLOW_FLOW_FLAG
from .terms.clip import MAX_START_FRAME

#: Every verb's exit codes, for the other verbs' help.
EXIT_EPILOG = """\
exit codes: 0 done, 1 engine error, 2 bad input, a full disk or a run folder in use (one line names the file
            and the fix), 3 cancelled by SIGINT/SIGTERM (nothing half-written is kept: run the command again).
"""


def frame_range(text: str) -> tuple[int, int]:
    """``--frames``: ``FIRST-LAST`` (``1010-1050``, as pipeline tools write a range), ``FIRST:LAST`` or one frame
    ``N``, in the plate's frame numbers (inclusive), read as a shot's ``frames`` is (``timing.parse_frames``)."""
    from .io.timing import ReversedFrames, parse_frames

    try:
        return parse_frames(text)
    except ReversedFrames as exc:
        raise argparse.ArgumentTypeError(f"frame range {text!r} is reversed: write {exc}") from None
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"frame range {text!r} must be FIRST-LAST in the plate's frame numbers, e.g. 1001-1100 (or 0:49)"
        ) from None


def start_frame(text: str) -> int:
    """``--start-frame``: a whole number from 0 to ``terms.clip.MAX_START_FRAME`` (Blender's highest frame)."""
    try:
        number = int(text)
    except ValueError:
        number = -1
    if not 0 <= number <= MAX_START_FRAME:
        raise argparse.ArgumentTypeError(
            f"start frame {text[:40]!r} must be a whole number from 0 to {MAX_START_FRAME}, e.g. 1001"
        )
    return number


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


#: -q and -v, on the engine and on every verb (``python -m engine -q fit ...`` or ``... fit ... -q``).
QUIET_HELP = "only what needs attention on stderr: errors, warnings, a cancellation (no bar, notes or summaries)"
VERBOSE_HELP = "also each stage as a line on stderr, with the whole job's percent where known"


def add_output_options(parser: argparse.ArgumentParser) -> None:
    """-q and -v on ``parser`` and on every verb below it; a verb's own copy leaves the engine's value alone unless
    given (its default is SUPPRESS), so either place works."""
    for at, default in ((parser, False), *((sub, argparse.SUPPRESS) for sub in verb_parsers(parser))):
        at.add_argument("-q", "--quiet", action="store_true", default=default, help=QUIET_HELP)
        at.add_argument("-v", "--verbose", action="store_true", default=default, help=VERBOSE_HELP)


def verb_parsers(parser: argparse.ArgumentParser) -> Iterator[argparse.ArgumentParser]:
    """Every verb and sub-verb parser below ``parser``, each once."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in dict.fromkeys(action.choices.values()):  # an alias names the same parser
                yield sub
                yield from verb_parsers(sub)


#: Every verb's help text in the layout its description and epilog were written in.
RAW_HELP = argparse.RawDescriptionHelpFormatter
#: A plate argument's help where a verb says no more about it.
CLIP_HELP = "image-sequence folder, sequence pattern or movie file"
#: A manifest argument's help where a verb says no more about it.
MANIFEST_HELP = "manifest.json of an export (or its folder)"


def add_verb(sub: argparse._SubParsersAction, name: str, **kwargs: Any) -> argparse.ArgumentParser:
    """A verb's parser with the verbs' common exit-code epilog, laid out as written (``kwargs``: its help and
    description, or another epilog)."""
    kwargs.setdefault("epilog", EXIT_EPILOG)
    return sub.add_parser(name, formatter_class=RAW_HELP, **kwargs)


def add_plate_frames(parser: argparse.ArgumentParser) -> None:
    """``--frames FIRST-LAST`` of a verb that reads a plate (``FRAMES_HELP``)."""
    parser.add_argument("--frames", type=frame_range, default=None, metavar="FIRST-LAST", help=FRAMES_HELP)


def add_set(parser: argparse.ArgumentParser, help: str) -> None:
    """``--set KEY=VALUE``, repeatable: a config field overridden."""
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help=help)


def add_device(parser: argparse.ArgumentParser, default: str) -> None:
    """``--device``: the torch device the verb computes on."""
    parser.add_argument("--device", default=default, help=f"auto | cpu | cuda | mps (default: {default})")


def add_threads(parser: argparse.ArgumentParser, help: str = "torch CPU threads (default: torch's choice)") -> None:
    """``--threads N``: torch's CPU threads for the work the command runs (None: torch's choice)."""
    parser.add_argument("--threads", type=int, default=None, help=help)


def add_preset(parser: argparse.ArgumentParser, default: str | None, help: str) -> None:
    """``--preset NAME``: the fit preset (``engine.config.PRESETS``; checked where the config is built)."""
    parser.add_argument("--preset", default=default, help=help)


def add_no_bar(parser: argparse.ArgumentParser, help: str = "no progress bar on stderr") -> None:
    """``--no-bar``: a verb whose progress shows as a bar on stderr."""
    parser.add_argument("--no-bar", action="store_true", help=help)


def add_follow_flow(parser: argparse.ArgumentParser, default: bool | None, follow_help: str, no_help: str) -> None:
    """``--follow-flow`` | ``--no-follow-flow`` into ``follow_flow`` (True | False; neither: ``default``): whether
    an export averages each layer's UV along optical flow (``engine.export.follow_flow``)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument(EXPORT_FOLLOW_FLOW_FLAG, dest="follow_flow", action="store_const", const=True,
                       default=default, help=follow_help)  # fmt: skip
    group.add_argument(C.EXPORT_NO_FOLLOW_FLOW_FLAG, dest="follow_flow", action="store_const", const=False,
                       help=no_help)  # fmt: skip


def add_layers(parser: argparse.ArgumentParser) -> None:
    """``--layer NAME``, repeatable: only these layers of an export."""
    parser.add_argument("--layer", action="append", default=None, metavar="NAME", help="only these layers")
