"""Every command line that README.md and docs/*.md document is a real command, and the quick ones run as written.

**Which lines.** In a fenced code block: every command that starts with ``python -m engine``,
``.venv/bin/python -m engine``, ``python -m bench`` or ``bash run.sh`` (after environment assignments such
as ``OMP_NUM_THREADS=1``, a ``/usr/bin/time -v`` prefix, ``&&``, ``;``, a pipe or a loop's ``do``). In running
text: every inline code span that is such a command. A span that names only the program or a verb
(`python -m engine render`, `python -m bench bench|speed`) refers to it; its verbs must exist.

**Synopses.** ``[...]`` is optional, ``a|b`` and ``[x | y]`` are alternatives, ``...`` is repetition. The
command as written (every optional left out) and every variant that adds one optional part (each alternative,
each alternative word) are checked.

**Placeholders** (``SUBSTITUTIONS``; only these words change): the plate (``PLATE``, ``CLIP``, ``clip/frames``,
``CLIPS/<name>/frames``, ``<plate>``) is a tiny synthetic clip; mask folders (``MASKS``, ``MASKS2``, ``GT_MASKS``,
``clip/masks``, ``CLIPS/<name>/masks``) its masks; a clip folder of the bench (``CLIPS/<name>``) the folder holding
both; a run folder (``RUN_DIR``, ``RUN``, ``run``, ``runs/<name>``) a fitted run, and one already exported for
``MANIFEST`` or ``.../exports/v001/manifest.json``; ``FIRST:LAST`` and ``A:B`` are ``0:3``; ``N`` is ``12``; ``P``,
``PRESET`` every preset; ``LAYER=IMAGE`` ``Foreground=<a paint image>`` (the one foreground layer's name); ``PAINT.png``
and ``paint_on_frame_12.png`` a paint image the size of the plate; ``key=value`` ``steps=2``; ``FOLDER`` after
``--scribbles`` a scribble folder; a shots file (``SHOTS``, ``shots.toml``) one shot of the synthetic clip. A path
after ``--out`` or ``--work`` (``MASKS``, ``RUN_DIR``, ``DIR``, ``edited/``,
``/tmp/auto/$c``...) is a new folder of its own.

**Checks** (``test_every_documented_command_parses``): each variant parses with the real parser
(``engine.cli.build_parser``, or ``bench``'s); every ``--set KEY=VALUE`` names a real config key with a
valid value, for the preset the command names (the bench: ``PRESET.KEY`` as the bench reads it); every preset
name is real; ``bash run.sh X``: ``X`` is one of run.sh's commands.

**Runs** (``test_documented_commands_run``, slow): the variants that take seconds are run in a scratch folder
(the commands' own relative paths land there) on the synthetic clip, with budget caps appended (``CAPS``: fits
``--set steps=2`` and a small batch, estimates a short calibration), and must exit 0 and write what they
document (``_assert_outputs``). Parse-only, with the reason (``parse_only_reason``): ``bash run.sh`` (the demo and the
whole suite take minutes: tests/engine/test_demo.py and CI run them), the bench (``python -m bench``: minutes
of training by design; tests/bench runs it on budgets of seconds), blocks that tests/docs/test_examples.py
already runs (``<!-- test -->``: they fail on purpose or build on earlier blocks), ``--device cuda|mps`` (needs that
hardware), ``--scribbles`` (needs strokes drawn on the clip; tests/engine/data/test_scribbles.py and the fit
tests run it) and ``fit --refine`` (needs a finished fit in ``--out``, which is a new folder here;
tests/engine/test_realign.py runs it).

``test_estimate_without_masks_gives_every_preset_a_row``: ``estimate PLATE`` as a user types it first, with no
mask, gives every preset a row and says why the paper's does not apply instead of a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import itertools
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from engine import contract as C
from engine.config import PRESETS, apply_overrides, parse_set_args, preset_config
from engine.errors import InputError
from engine.terms.cli import VERB_NUKE, VERB_PREVIEW, VERB_RENDER
from engine.terms.farm import FARM_DASK
from engine.terms.lock import RUN_LOCK
from tests.paths import ROOT

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
RUN_SH = ROOT / "run.sh"
#: The interpreters a documented command may start with.
PYTHONS = {"python", "python3", ".venv/bin/python", ".venv/bin/python3"}
#: Words before the program that do not change the command: a timer and its flag.
PREFIXES = {"/usr/bin/time", "time", "-v"}
#: Shell words that end one command and may start the next.
SEPARATORS = {"&&", "||", ";", "|", "do", "then", "(", ")", "{", "}"}
ENV_ASSIGNMENT = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*=")
#: A synopsis's optional parts and its alternatives ignore this many variants beyond the command as written.
MAX_VARIANTS = 40
#: Appended to the runs so each takes seconds (later --set values win); the synthetic clip is 64x48.
CAPS = {
    C.VERB_FIT: ["--set", "steps=2", "--set", "batch=64", "--set", "eval_pixels=256", "--no-bar"],
    C.VERB_ESTIMATE: ["--calib-seconds", "0.01", "--set", "batch=64", "--set", "eval_pixels=256"],
}
#: Seconds one documented command may take when it runs here.
RUN_TIMEOUT_S = 300
#: The synthetic plate: 13 frames, so frame 12 (``project-frame --frame 12``) exists.
CLIP_FRAMES = 13
CLIP_SIZE = (64, 48)
#: What stands for a frame range and a frame number in the documented lines.
FRAME_RANGE, FRAME_NUMBER = "0:3", "12"


# --- extraction ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Documented:
    """One documented command: where it is, what was written, and its words after the program."""

    page: str
    line: int
    text: str
    program: str  # "engine", "bench" or "run.sh"
    words: tuple[str, ...]
    inline: bool
    tested_block: bool  # in a <!-- test --> block that tests/docs/test_examples.py runs
    fails_on_purpose: bool = False  # in a <!-- test: fails "..." --> block: its values are the documented error

    @property
    def where(self) -> str:
        return f"{self.page}:{self.line}"

    @property
    def is_reference(self) -> bool:
        """An inline span naming only the program or a verb (`python -m engine render`): not a command."""
        rest = [w for w in self.words if w != "..."]
        return self.inline and len(rest) <= 1 and not any(w.startswith("-") for w in rest)


def _shell_words(text: str) -> list[str]:
    """Shell words of a line, with ``&&``, ``;``, ``>`` and parentheses apart; ``|`` stays inside words (``a|b``)."""
    # a <placeholder> (even <Run Folder>) is one word, not two redirections
    text = re.sub(r"<([^<>]+)>", lambda m: "\x01" + m.group(1).replace(" ", "_") + "\x02", text)
    lexer = shlex.shlex(text, posix=True, punctuation_chars="();>&")
    lexer.whitespace_split = True
    try:
        words = list(lexer)
    except ValueError:  # an unbalanced quote in prose: take the plain words
        words = text.split()
    return [w.replace("\x01", "<").replace("\x02", ">") for w in words]


def _commands_in(words: list[str]) -> Iterator[tuple[str, list[str]]]:
    """(program, words after it) of every command among the shell words of one line."""
    segments: list[list[str]] = [[]]
    skip = False
    for word in words:
        if skip:
            skip = False
        elif word in (">", ">>"):
            skip = True  # a redirection's target is no argument
        elif word in SEPARATORS and not _inside_brackets(segments[-1]):
            segments.append([])
        else:
            segments[-1].append(word)
    for segment in segments:
        while segment and (ENV_ASSIGNMENT.match(segment[0]) or segment[0] in PREFIXES):
            segment = segment[1:]
        if len(segment) >= 3 and segment[0] in PYTHONS and segment[1] == "-m" and segment[2] in ("engine", "bench"):
            yield segment[2], segment[3:]
        elif len(segment) >= 2 and segment[0] == "bash" and segment[1] == "run.sh":
            yield "run.sh", segment[2:]


def _inside_brackets(words: list[str]) -> bool:
    text = " ".join(words)
    return text.count("[") > text.count("]")


def _fences(lines: list[str]) -> Iterator[tuple[int, str, str | None]]:
    """(line number, the line with its continuations joined, its block's tag: "test", "fails" or None) of every
    line inside a fenced code block."""
    fence_open = False
    tested: str | None = None
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("```"):
            if not fence_open:
                prev = next((lines[k] for k in range(i - 1, -1, -1) if lines[k].strip()), "")
                tag = re.search(r"<!--\s*test(:\s*fails)?\b", prev)
                tested = None if tag is None else "fails" if tag.group(1) else "test"
            fence_open = not fence_open
            i += 1
            continue
        if fence_open:
            start = i
            while line.endswith("\\") and i + 1 < len(lines):
                i += 1
                line = line[:-1] + " " + lines[i].strip()
            yield start + 1, line, tested
        i += 1


def documented_commands() -> list[Documented]:
    out = []
    for page in PAGES:
        lines = page.read_text(encoding="utf-8").splitlines()
        for number, line, tested in _fences(lines):
            for program, words in _commands_in(_shell_words(line.split(" #")[0])):
                block = (tested is not None, tested == "fails")
                out.append(Documented(page.name, number, line.strip(), program, tuple(words), False, *block))
        in_fence = False
        for number, line in enumerate(lines, 1):
            if line.startswith("```"):
                in_fence = not in_fence
                continue
            if in_fence:
                continue
            for span in re.findall(r"`([^`]+)`", line):
                for program, words in _commands_in(_shell_words(span)):
                    if words or span.split()[0] in PYTHONS | {"bash"} | PREFIXES:
                        out.append(Documented(page.name, number, span, program, tuple(words), True, False))
    return out


# --- synopses: optional parts and alternatives ---------------------------------------------------------------


@dataclass
class _Group:
    """``[...]``: optional; its alternatives are separated by a lone ``|``."""

    alternatives: list[list[_Item]] = field(default_factory=list)


_Item = str | _Group


def _bracket_tokens(words: tuple[str, ...]) -> list[str]:
    """Brackets as tokens of their own: ``[--mask``, ``MASKS2``, ``...]`` -> ``[``, ``--mask``, ... ``]``."""
    out = []
    for word in words:
        opening = len(word) - len(word.lstrip("["))
        core = word[opening:]
        closing = len(core) - len(core.rstrip("]"))
        core = core[: len(core) - closing] if closing else core
        out += ["["] * opening + ([core] if core else []) + ["]"] * closing
    return out


def _parse_synopsis(tokens: list[str]) -> list[_Item]:
    def sequence(pos: int, in_group: bool) -> tuple[list[list[_Item]], int]:
        alternatives: list[list[_Item]] = [[]]
        while pos < len(tokens):
            token = tokens[pos]
            if token == "[":
                inner, pos = sequence(pos + 1, True)
                alternatives[-1].append(_Group(inner))
                continue
            if token == "]" and in_group:
                return alternatives, pos + 1
            if token == "|" and in_group:
                alternatives.append([])
            elif token not in ("...", "]"):
                alternatives[-1].append(token)
            pos += 1
        return alternatives, pos

    (items, *_), _ = sequence(0, False)
    return items


def _word_options(word: str) -> list[str]:
    """``draft|balanced`` -> both; a word without ``|`` (or a pipe alone) -> itself."""
    return word.split("|") if "|" in word and word != "|" else [word]


def _base(items: list[_Item]) -> list[str]:
    return [_word_options(i)[0] for i in items if isinstance(i, str)]


def _variants(items: list[_Item]) -> list[list[str]]:
    """The command with every optional part left out, then each optional part (each of its alternatives, with
    their own optional parts one at a time) and each alternative word added to it, one at a time."""
    out = [_base(items)]
    for index, item in enumerate(items):
        if isinstance(item, str):
            for option in _word_options(item)[1:]:
                out.append([*_base(items[:index]), option, *_base(items[index + 1 :])])
            continue
        for alternative in item.alternatives:
            for inner in _variants(alternative):
                out.append(_base(items[:index]) + inner + _base(items[index + 1 :]))
    unique = list(dict.fromkeys(tuple(v) for v in out))
    return [list(v) for v in unique[: 1 + MAX_VARIANTS]]


def variants(cmd: Documented) -> list[list[str]]:
    return _variants(_parse_synopsis(_bracket_tokens(cmd.words)))


# --- placeholders ----------------------------------------------------------------------------------------------


@dataclass
class Places:
    """What the placeholders stand for. Parse checks use the names as they are; runs get real files."""

    frames: str = "clip/frames"
    masks: str = "clip/masks"
    masks2: str = "clip/masks2"
    clip_folder: str = "clip"
    run: Callable[[], str] = lambda: "run"
    manifest: Callable[[], str] = lambda: "run/exports/v001/manifest.json"
    paint: str = "paint.png"
    scribbles: str = "scribbles"
    fresh: Callable[[str], str] = lambda name: name
    shots: str = "shots.toml"


#: (pattern of a whole word, what it becomes). A pattern that is an output after --out/--work gets a new folder.
SUBSTITUTIONS: list[tuple[str, Callable[[Places, str], str]]] = [
    (r"PLATE|CLIP|clip/frames|CLIPS/[^/]+/frames|<plate>", lambda p, w: p.frames),
    (r"MASKS2", lambda p, w: p.masks2),  # a second object's masks: a folder of its own (one folder twice is refused)
    (r"MASKS|GT_MASKS|clip/masks|CLIPS/[^/]+/masks", lambda p, w: p.masks),
    (r"CLIPS/[^/]+", lambda p, w: p.clip_folder),
    (r"(RUN_DIR|RUN|run|runs/[^/]+)/exports/v001/manifest\.json|MANIFEST", lambda p, w: p.manifest()),
    (r"RUN_DIR|RUN|run|runs/[^/]+", lambda p, w: p.run()),
    (r"FIRST:LAST|A:B", lambda p, w: FRAME_RANGE),
    (r"N", lambda p, w: FRAME_NUMBER),
    (r"LAYER=IMAGE", lambda p, w: f"Foreground={p.paint}"),
    (r"PAINT\.png|paint_on_frame_12\.png", lambda p, w: p.paint),
    (r"key=value", lambda p, w: "steps=2"),
    (r"FOLDER", lambda p, w: p.scribbles),
    (r"SHOTS|shots\.(toml|json)", lambda p, w: p.shots),
]
#: Placeholders of a preset: every preset is checked.
PRESET_PLACEHOLDERS = {"P", "PRESET"}
#: Flags whose value is a new output.
OUTPUT_FLAGS = {"--out", "--work"}


def substitute(words: list[str], places: Places) -> list[list[str]]:
    """The argv of ``words`` with the placeholders replaced; one argv per preset when a preset is a placeholder."""
    argv = []
    for i, word in enumerate(words):
        if i and words[i - 1] in OUTPUT_FLAGS:
            argv.append(places.fresh(word))
            continue
        for pattern, make in SUBSTITUTIONS:
            if re.fullmatch(pattern, word):
                word = make(places, word)
                break
        argv.append(word)
    if not PRESET_PLACEHOLDERS & set(argv):
        return [argv]
    return [[name if w in PRESET_PLACEHOLDERS else w for w in argv] for name in PRESETS]


# --- checks -------------------------------------------------------------------------------------------------------


def _parser(program: str) -> argparse.ArgumentParser:
    if program == "bench":
        from bench.tool_parsers import build_parser as bench_parser

        return bench_parser()
    from engine.cli import build_parser

    return build_parser()


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def run_sh_commands() -> set[str]:
    """The commands of run.sh: the labels of its top-level ``case``."""
    return set(re.findall(r"^  ([a-z][a-z-]*)\)$", RUN_SH.read_text(encoding="utf-8"), re.MULTILINE))


def problem(program: str, argv: list[str], values: bool = True) -> str | None:
    """Why ``argv`` is not a real command of ``program`` (None when it is); ``values``: check presets and --set too
    (not for an example that shows their error on purpose)."""
    if program == "run.sh":
        known = run_sh_commands()
        return None if argv[:1] and argv[0] in known else f"run.sh has no command {argv[:1]} ({sorted(known)})"
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            args = _parser(program).parse_args(argv)
    except SystemExit as exc:
        return None if exc.code == 0 else " ".join(err.getvalue().split()[-40:])
    return _values_problem(program, args) if values else None


def _values_problem(program: str, args: argparse.Namespace) -> str | None:
    """Presets and --set keys and values: real, for the presets the command names."""
    presets = [getattr(args, "preset", None) or "balanced"]
    variants: list[str] = []
    if getattr(args, "presets", None):
        presets = [p.strip() for p in args.presets.split(",")]
        if program == "bench":  # `speed` takes PRESET:KEY=VALUE entries (bench.speed.variant_config)
            from bench.speed import VARIANT_SEP

            variants = [p for p in presets if VARIANT_SEP in p]
            presets = list(dict.fromkeys(p.split(VARIANT_SEP, 1)[0] for p in presets))
    unknown = [p for p in presets if p not in PRESETS]
    if unknown:
        return f"unknown preset {unknown} ({sorted(PRESETS)})"
    sets = getattr(args, "set", None) or []
    try:
        if variants:
            from bench.speed import variant_config

            for entry in variants:
                variant_config(entry)
        if program == "bench":
            from bench.bench import bench_configs

            bench_configs(presets, parse_set_args(sets))
        else:
            for name in presets:
                apply_overrides(preset_config(name), parse_set_args(sets))
    except InputError as exc:
        return str(exc)
    return None


def _verbs_exist(cmd: Documented) -> str | None:
    """A reference names real verbs (each of ``a|b``)."""
    names = [w for w in cmd.words if w != "..."]
    if cmd.program == "run.sh":
        return problem("run.sh", names[:1]) if names else None
    known = set(_subcommands(_parser(cmd.program)))
    missing = [v for w in names for v in _word_options(w) if v not in known]
    return f"no such verb {missing} ({sorted(known)})" if missing else None


#: Documented commands that are wrong in pages this test's owners do not edit, with the exact fix; each must
#: still be wrong (so the entry goes once the page is fixed).
KNOWN_WRONG: dict[str, str] = {}


ALL = documented_commands()


def test_the_documented_commands_are_found():
    """The extraction finds the commands the pages show (a regression here would silently check nothing)."""
    where = {(c.page, c.program) for c in ALL}
    assert {("README.md", "engine"), ("README.md", "run.sh"), ("accuracy-vs-time.md", "bench")} <= where
    assert sum(not c.is_reference for c in ALL) >= 40
    assert not any(c.page == "architecture.md" and not c.inline for c in ALL)  # its layout tree holds no command


def test_every_documented_command_parses():
    problems = {}
    for cmd in ALL:
        if cmd.is_reference:
            found = _verbs_exist(cmd)
        else:
            found = next(
                (
                    f"`{' '.join(argv)}`: {why}"
                    for variant in variants(cmd)
                    for argv in substitute(variant, Places())
                    if (why := problem(cmd.program, argv, values=not cmd.fails_on_purpose)) is not None
                ),
                None,
            )
        if found is not None:
            problems[cmd.where] = f"{cmd.text} -> {found}"
    still_wrong = {k: v for k, v in problems.items() if k in KNOWN_WRONG}
    assert set(still_wrong) == set(KNOWN_WRONG), f"fixed, drop from KNOWN_WRONG: {set(KNOWN_WRONG) - set(still_wrong)}"
    wrong = {k: v for k, v in problems.items() if k not in KNOWN_WRONG}
    assert not wrong, "documented commands that are not real:\n" + "\n".join(f"{k}: {v}" for k, v in wrong.items())


# --- runs ---------------------------------------------------------------------------------------------------------


def parse_only_reason(cmd: Documented, argv: list[str]) -> str | None:
    """Why a documented command is parse-checked here and not run (None: it runs)."""
    if cmd.program == "run.sh":
        return "bash run.sh: the demo and the whole suite take minutes (tests/engine/test_demo.py, CI)"
    if cmd.program == "bench":
        return "the bench trains for minutes by design (tests/bench runs it on budgets of seconds)"
    if cmd.tested_block:
        return "a <!-- test --> block: tests/docs/test_examples.py runs it, in order with its page"
    if cmd.where in KNOWN_WRONG and any(problem(cmd.program, a) for a in substitute(argv, Places())):
        return "known wrong (KNOWN_WRONG)"
    if "--device" in argv and argv[argv.index("--device") + 1] in ("cuda", "mps"):
        return "--device cuda|mps needs that hardware"
    if C.SCRIBBLE_ARG in argv:
        return "--scribbles needs strokes drawn on the clip (tests/engine/data/test_scribbles.py, the fit tests)"
    if "--resume" in argv:
        return "--resume needs a fit stopped part way (tests/stability/test_faults.py)"
    if C.FIT_REFINE_FLAG in argv:
        return "--refine needs a finished fit in --out, a new folder here (tests/engine/test_realign.py runs it)"
    if argv[:2] == [C.VERB_FARM, FARM_DASK]:
        return "farm dask needs a Dask scheduler and workers (tests/farm/test_dask.py starts them on 127.0.0.1)"
    if argv[:2] == [C.VERB_FARM, C.FARM_FLAMENCO] and "--manager" in argv:
        return "farm flamenco needs a Flamenco Manager (tests/farm/test_flamenco_submit.py runs a stub one)"
    if any(word.startswith("SEQ/") for word in argv):
        return "a command farm plan prints: SEQ stands for the shots file's folder (tests/farm/test_plan.py)"
    return None


class Scratch:
    """The folder documented commands run in: the synthetic clip, a fitted run and its export, a paint image."""

    def __init__(self, folder: Path) -> None:
        from engine.data.synthetic import SceneSpec, make_scene, write_scene

        self.folder = folder
        scene = make_scene(SceneSpec(width=CLIP_SIZE[0], height=CLIP_SIZE[1], frames=CLIP_FRAMES))
        frames, masks = write_scene(scene, folder / "clip")
        paint = np.zeros((CLIP_SIZE[1], CLIP_SIZE[0], 4), np.float32)
        paint[10:20, 10:30] = (1.0, 0.2, 0.1, 1.0)
        from engine.io.images import write_png

        self.paint = write_png(folder / "paint.png", paint)
        self.fitted = folder / "fitted_run"
        self._engine([C.VERB_FIT, str(frames), "--mask", str(masks), "--out", str(self.fitted), *CAPS[C.VERB_FIT]])
        self._engine([C.VERB_EXPORT, str(self.fitted)])
        self.places = Places(
            frames=str(frames),
            masks=str(masks),
            masks2=str(shutil.copytree(masks, folder / "masks2")),
            clip_folder=str(folder / "clip"),
            run=self._run_copy,
            manifest=lambda: str(Path(self._run_copy()) / "exports" / "v001" / C.MANIFEST_NAME),
            paint=str(self.paint),
            scribbles=str(folder / "no_scribbles"),
            fresh=self._fresh,
            shots=str(self._shots_file(frames, masks)),
        )
        self._count = itertools.count()

    def _shots_file(self, frames: Path, masks: Path) -> Path:
        """A shots file of one shot, the synthetic clip with its masks, on the fit's budget caps."""
        path = self.folder / "shots.json"
        caps = [v for k, v in zip(CAPS[C.VERB_FIT], CAPS[C.VERB_FIT][1:], strict=False) if k == "--set"]
        shot = {"name": "sh010", "plate": str(frames), "masks": [str(masks)], "run": "farm_runs/sh010"}
        shots = {C.SHOTS_TAG: C.SHOTS_VERSION, C.SHOTS_DEFAULTS_KEY: {"preset": "draft", "set": caps},
                 C.SHOTS_LIST_KEY: [shot]}  # fmt: skip
        path.write_text(json.dumps(shots), encoding="utf-8")
        return path

    def _engine(self, argv: list[str]) -> subprocess.CompletedProcess:
        proc = run_engine("engine", argv, self.folder)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return proc

    def _run_copy(self) -> str:
        """A fitted, exported run of its own (each command changes what it is given)."""
        copy = self.folder / f"run_copy_{next(self._count)}"
        shutil.copytree(self.fitted, copy, ignore=shutil.ignore_patterns(RUN_LOCK))
        return str(copy)

    def _fresh(self, name: str) -> str:
        suffix = ".nk" if name.endswith(".nk") else ""  # a Nuke script's name ends in .nk
        stem = re.sub(r"[^A-Za-z0-9_]+", "_", name.removesuffix(suffix)).strip("_") or "out"
        return str(self.folder / "fresh" / f"{stem}_{next(self._count)}{suffix}")


def run_engine(program: str, argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", program, *argv], cwd=cwd, env=env, capture_output=True, text=True,
        timeout=RUN_TIMEOUT_S,
    )  # fmt: skip


def _flag(argv: list[str], name: str) -> str | None:
    return argv[argv.index(name) + 1] if name in argv else None


def _assert_outputs(argv: list[str], proc: subprocess.CompletedProcess, cwd: Path) -> None:
    """What each verb documents it writes exists."""
    verb = argv[0] if argv else ""
    last = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else ""
    if verb == C.VERB_FIT and "--help-config" not in argv:
        run = cwd / _flag(argv, "--out")
        assert (run / C.RUN_CHECKPOINT).exists() and (run / C.RUN_METRICS).exists(), sorted(run.iterdir())
    elif verb == C.VERB_EXPORT:
        assert last.endswith(C.MANIFEST_NAME) and (cwd / last).exists(), proc.stdout
    elif verb in (VERB_PREVIEW, C.VERB_PROJECT_FRAME):
        # the written paths; progress messages (one JSON object a line) are the contract's, not paths
        printed = [ln for ln in proc.stdout.splitlines() if ln.strip() and C.parse_progress_line(ln) is None]
        assert printed and all((cwd / ln).exists() for ln in printed), proc.stdout
    elif verb == VERB_RENDER:
        out = cwd / _flag(argv, "--out")
        assert len([p for p in out.iterdir() if p.suffix in (".exr", ".png")]) == CLIP_FRAMES, sorted(out.iterdir())
        movie = _flag(argv, "--movie")
        assert movie is None or (cwd / movie).stat().st_size > 0
    elif verb == C.VERB_MASKS:
        first, last_frame = (int(v) for v in (_flag(argv, "--frames") or f"0:{CLIP_FRAMES - 1}").split(":"))
        assert len(list((cwd / _flag(argv, "--out")).glob("*.png"))) == last_frame - first + 1
    elif verb == VERB_NUKE:
        assert last.endswith(".nk") and "STMap {" in (cwd / last).read_text(encoding="utf-8"), proc.stdout
    elif verb == C.VERB_ESTIMATE:
        if "--json" in argv:
            rows = json.loads(last)["presets"]
        else:
            rows = [ln for ln in proc.stdout.splitlines() if ln.startswith("| ") and "| preset |" not in ln]
        assert len(rows) == len(PRESETS), proc.stdout
    else:
        assert proc.stdout.strip(), "printed nothing"


def expected_refusal(argv: list[str]) -> str | None:
    """What a synopsis allows but the engine refuses, in one line and exit 2, with what the line names (None: the
    command must succeed). The paper's architecture has exactly one foreground layer (README: ``paper``: exactly
    one ``--mask``)."""
    if argv[:1] == [C.VERB_FIT] and _flag(argv, "--preset") == "paper" and argv.count("--mask") != 1:
        return "paper"
    return None


def _runnable() -> list[Any]:
    out = []
    for cmd in ALL:
        if cmd.is_reference:
            continue
        for n, variant in enumerate(variants(cmd)):
            if parse_only_reason(cmd, variant) is not None:
                continue
            out.append(pytest.param(f"{cmd.where}#{n}", cmd, variant, id=f"{cmd.where}#{n}"))
    return out


RUNNABLE = _runnable()


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Scratch:
    return Scratch(tmp_path_factory.mktemp("documented"))


@pytest.mark.slow
@pytest.mark.parametrize(("where", "cmd", "variant"), RUNNABLE)
def test_documented_commands_run(where: str, cmd: Documented, variant: list[str], scratch: Scratch):
    argv = substitute(variant, scratch.places)[0]
    argv += CAPS.get(argv[0] if argv else "", [])
    proc = run_engine(cmd.program, argv, scratch.folder)
    what = f"{where} `{cmd.text}` as `{' '.join(argv)}`"
    refusal = expected_refusal(argv)
    if refusal is not None:
        lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
        assert proc.returncode == C.EXIT_BAD_INPUT and len(lines) == 1, f"{what}: {proc.stderr[-3000:]}"
        assert lines[0].startswith("error: ") and refusal in lines[0], lines
        return
    assert proc.returncode == 0, f"{what} exited {proc.returncode}:\n{proc.stderr[-3000:]}"
    _assert_outputs(argv, proc, scratch.folder)


def test_what_is_parse_only_says_why():
    """Every documented command is either run above or has a reason here; the reasons are few and named."""
    reasons = {parse_only_reason(c, v) for c in ALL if not c.is_reference for v in variants(c)} - {None}
    assert reasons and all(r for r in reasons)
    assert len(RUNNABLE) >= 20


# --- estimate as a user first types it ----------------------------------------------------------------------------


@pytest.mark.slow
def test_estimate_without_masks_gives_every_preset_a_row(scratch: Scratch):
    """``estimate PLATE`` with no mask: the paper model cannot fit it (the model raises ``ValueError: the paper model
    has exactly one background and one foreground layer``). Now every preset has its row; the paper's says why it does
    not apply, in the table and in ``--json`` (``unavailable``), and the exit code is 0."""
    frames = scratch.places.frames
    table = run_engine("engine", [C.VERB_ESTIMATE, frames, *CAPS[C.VERB_ESTIMATE]], scratch.folder)
    assert table.returncode == 0 and "Traceback" not in table.stderr, table.stderr
    rows = {ln.split("|")[1].strip(): ln for ln in table.stdout.splitlines() if ln.startswith("| ")}
    assert set(PRESETS) <= set(rows)
    assert "not available: the paper model fits exactly 1 foreground layer" in rows["paper"]
    assert "no --mask" in rows["paper"] and "not available" not in rows["draft"]
    as_json = run_engine("engine", [C.VERB_ESTIMATE, frames, "--json", *CAPS[C.VERB_ESTIMATE]], scratch.folder)
    assert as_json.returncode == 0, as_json.stderr
    presets = {r["preset"]: r for r in json.loads(as_json.stdout.strip().splitlines()[-1])["presets"]}
    assert list(presets) == list(PRESETS)
    assert presets["paper"]["unavailable"] and presets["paper"]["total_seconds"] is None
    assert all(presets[p]["unavailable"] is None and presets[p]["total_seconds"] > 0 for p in PRESETS if p != "paper")
    two = run_engine(
        "engine",
        [C.VERB_ESTIMATE, frames, "--mask", scratch.places.masks, "--mask", scratch.places.masks, "--json",
         "--presets", "paper,draft", *CAPS[C.VERB_ESTIMATE]],
        scratch.folder,
    )  # fmt: skip
    assert two.returncode == 0, two.stderr
    paper = json.loads(two.stdout.strip().splitlines()[-1])["presets"][0]
    assert "2 --mask folders" in paper["unavailable"]


@pytest.mark.slow
def test_estimate_of_a_clip_whose_folder_name_is_not_utf8(scratch: Scratch, tmp_path: Path):
    """A plate in a folder named in Latin-1, on a strict UTF-8 stdout: the table's first line and the JSON's
    ``clip`` show the odd byte as ``\\xe9``; nothing raises."""
    odd = Path(os.fsdecode(os.path.join(os.fsencode(tmp_path), b"plate_\xe9")))
    try:
        shutil.copytree(scratch.places.frames, odd)
    except (OSError, UnicodeError) as exc:
        pytest.skip(f"this file system takes only UTF-8 names ({exc})")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONIOENCODING": "utf-8"}
    for extra in ([], ["--json"]):
        argv = [C.VERB_ESTIMATE, str(odd), "--presets", "draft", *extra, *CAPS[C.VERB_ESTIMATE]]
        proc = subprocess.run(
            [sys.executable, "-m", "engine", *argv], cwd=scratch.folder, env=env, capture_output=True,
            timeout=RUN_TIMEOUT_S,
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr.decode("utf-8", "replace")[-2000:]
        out = proc.stdout.decode("utf-8")
        clip = json.loads(out.splitlines()[-1])["clip"] if extra else out.splitlines()[0].split(":")[0]
        assert clip.endswith("plate_\\xe9"), out
