"""The engine command lines the add-on runs, one function per verb, and the environment they run in. No bpy here.

Every command is an argv list (``python -m engine <verb> ...``, never a shell string); the verbs and their
arguments are the contract's (``engine.contract``). The engine runs with its own interpreter and finds the
engine shipped inside the extension through PYTHONPATH.
"""

from __future__ import annotations

import os
import shlex
from dataclasses import dataclass

from ...engine import contract as C  # type: ignore[import-not-found]
from .errors import UserError

#: The fit's own progress bar is for terminals: the add-on reads the JSON progress lines instead.
NO_BAR_FLAG = "--no-bar"
#: The panel's field the artist types engine overrides into (named in its messages).
OVERRIDES_FIELD = "Engine Settings"


def extension_root() -> str:
    """The folder that holds ``engine/`` and ``addon/`` (the extension root, or the checkout)."""
    return os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def engine_env(base: dict[str, str] | None = None) -> dict[str, str]:
    """Environment for engine processes: the extension root first on PYTHONPATH, unbuffered output."""
    env = dict(os.environ if base is None else base)
    root = extension_root()
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env["PYTHONUNBUFFERED"] = "1"
    return env


def engine_argv(python: str, verb: str, *args: str) -> list[str]:
    return [python, "-m", C.CLI_MODULE, verb, *args]


def relink_argv(python: str, manifest: str, plate: str) -> list[str]:
    """``engine relink``: the export at ``manifest`` told its plate is at ``plate``."""
    return engine_argv(python, C.VERB_RELINK, manifest, C.RELINK_PLATE_ARG, plate)


def version_argv(python: str) -> list[str]:
    return [python, "-m", C.CLI_MODULE, "--version"]


@dataclass(frozen=True)
class ClipInputs:
    """What the engine reads of a clip: the plate (a sequence's folder or a movie file), one mask folder per
    foreground layer, the frames as the plate's frame numbers (first and last, inclusive) and, for a fit that
    splits one object with scribbles, the scribble folder. ``auto_parts`` False (Find Parts off): the engine is told
    not to split the object into the parts that move apart; True leaves it to the engine's default, which splits
    them wherever that applies (one mask, no scribbles)."""

    plate: str
    masks: tuple[str, ...]
    first: int
    last: int
    scribbles: str | None = None
    auto_parts: bool = True

    def args(self) -> list[str]:
        """``--mask M ... --frames A:B [--scribbles S] [--no-auto-parts]`` (the plate is the verb's first
        argument)."""
        out = [arg for folder in self.masks for arg in ("--mask", folder)]
        out += ["--frames", frames_arg(self.first, self.last)]
        if self.scribbles:
            out += [C.SCRIBBLE_ARG, self.scribbles]
        return out + ([] if self.auto_parts else [C.FIT_NO_AUTO_PARTS_FLAG])


def frames_arg(first: int, last: int) -> str:
    """The engine's ``--frames`` value: the plate's frame numbers (``core.frames.plate_numbers``), not scene frames."""
    return f"{first}:{last}"


def split_overrides(overrides: str) -> list[str]:
    """The artist's space-separated ``KEY=VALUE`` overrides, shell-quoted where a value holds spaces. An
    unbalanced quote is refused as a UserError (one line in the panel naming the field and the fix), not a
    traceback and not a guess: wherever the quote was meant to end, a guess could fit with other settings than
    the artist typed, and a fit takes hours."""
    try:
        return shlex.split(overrides)
    except ValueError as exc:  # shlex: "No closing quotation" / "No escaped character"
        raise UserError(
            f"{OVERRIDES_FIELD}: cannot read {overrides!r} ({str(exc).lower()}) — close the quote or remove it; the "
            "field takes space-separated KEY=VALUE pairs, e.g. steps=2000 lr=0.001"
        ) from None


def set_args(long_edge: int, overrides: str = "") -> list[str]:
    """``--set long_edge=N`` then each of the artist's space-separated ``KEY=VALUE`` overrides (``split_overrides``)."""
    return [arg for item in [f"long_edge={long_edge}", *split_overrides(overrides)] for arg in ("--set", item)]


def fit_argv(python: str, clip: ClipInputs, run_dir: str, preset: str, sets: list[str]) -> list[str]:
    args = [clip.plate, *clip.args(), "--out", run_dir, "--preset", preset, *sets, NO_BAR_FLAG]
    return engine_argv(python, C.VERB_FIT, *args)


def resume_argv(python: str, run_dir: str) -> list[str]:
    return engine_argv(python, C.VERB_FIT, "--resume", "--out", run_dir, NO_BAR_FLAG)


def refine_argv(python: str, run_dir: str, steps: int, preset: str | None = None) -> list[str]:
    """``fit --out RUN --refine [STEPS] [--preset P]``: the finished fit continued for ``steps`` more steps (0: on to
    ``preset``'s step budget), with ``preset``'s schedule (None: the fit's own)."""
    args = ["--out", run_dir, C.FIT_REFINE_FLAG, *([str(steps)] if steps > 0 else [])]
    return engine_argv(python, C.VERB_FIT, *args, *(["--preset", preset] if preset else []), NO_BAR_FLAG)


def realign_argv(python: str, run_dir: str) -> list[str]:
    """``realign RUN``: the edit layers carried from the export they were painted on onto the run's newest one."""
    return engine_argv(python, C.VERB_REALIGN, run_dir)


def carry_argv(python: str, manifest: str, source: str) -> list[str]:
    """``realign MANIFEST --from SOURCE --measure``: the paint of ``source`` (an export of another fit of the same
    plate) laid onto ``manifest``'s edit layers, and how much of it landed (one JSON line)."""
    return engine_argv(python, C.VERB_REALIGN, manifest, "--from", source, "--measure")


def export_argv(python: str, run_dir: str, follow_flow: bool = True) -> list[str]:
    """``export RUN``: with the engine's default (the UV follows the flow where the plate or the fit's flow is
    there), or the UV as fitted (``follow_flow`` False: ``--no-follow-flow``)."""
    return engine_argv(python, C.VERB_EXPORT, run_dir, *([] if follow_flow else [C.EXPORT_NO_FOLLOW_FLOW_FLAG]))


def masks_argv(python: str, plate: str, out_dir: str, first: int, last: int) -> list[str]:
    return engine_argv(python, C.VERB_MASKS, plate, "--out", out_dir, "--frames", frames_arg(first, last))


def estimate_argv(python: str, clip: ClipInputs, sets: list[str]) -> list[str]:
    """The estimate times the fit without scribbles (the verb takes none)."""
    plain = ClipInputs(clip.plate, clip.masks, clip.first, clip.last)
    return engine_argv(python, C.VERB_ESTIMATE, clip.plate, *plain.args(), *sets, "--json")
