"""The farm's one plan: every task of every shot, with its exact engine command line and its dependencies.

Each back end (OpenJD, Dask, Flamenco) is generated from this plan and runs ``python -m engine *task.args`` for
each task, so every scheduler runs the very same command lines. Per shot::

    masks (auto_masks only) -> fit -> atlases -> passes A-B, C-D, ... -> publish -> render A-B, ... (render only)
                                                                              \\-> preview (preview only)

Every task is safe to run again (a farm retries preempted and failed tasks): ``fit --resume-if-started`` continues
its own checkpoint, the export's stages and the render's chunks skip or rewrite what they already wrote, and the
export version (``--into vNNN``) is chosen here, once, so a retried task writes into the same one.

The masks task writes ``RUN/auto_masks`` (``contract.AUTO_MASKS_DIR``, where ``fit --auto-masks`` puts them) with
the ``masks`` verb, and the fit, ``--auto-masks``, uses the masks it finds there: finding masks needs no GPU and is a
task of its own, so it runs on any host, its result stays in the run folder for the artist to check, a retried fit
never finds masks again, and masks that found nothing give a background-only fit, as ``fit --auto-masks`` alone
does.

Torch-free: the submitting machine needs the plate (its frame numbers chunk the export) but no GPU stack.
"""

from __future__ import annotations

import os
import re
import shlex
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from .. import contract as C
from ..errors import InputError
from ..export.stage_record import continues_fit
from ..terms.cli import EXPORT_INTO_ARG, EXPORT_STAGE_ARG, FIT_RESUME_IF_STARTED_FLAG, VERB_PREVIEW, VERB_RENDER
from ..terms.export_names import EXPORT_CHUNKS_SUFFIX, EXPORT_VERSION_FORMAT
from ..terms.run_folder import FIT_AUTO_MASKS_FLAG, FIT_AUTO_PARTS_FLAG
from .shots import Shot, ShotsFile, load_shots

MASKS, FIT, ATLASES, PASSES, PUBLISH = "masks", "fit", "atlases", "passes", "publish"
RENDER, PREVIEW = "render", "preview"
TASK_KINDS: tuple[str, ...] = (MASKS, FIT, ATLASES, PASSES, PUBLISH, RENDER, PREVIEW)
#: The kinds that want a GPU host.
ACCELERATOR_KINDS: frozenset[str] = frozenset({FIT, ATLASES, PASSES})
#: The kinds run as several tasks, one per frame range.
CHUNKED_KINDS: frozenset[str] = frozenset({PASSES, RENDER})

#: An export version's folder, a chunked export's staging folder or a dead export's leftovers: numbers taken.
_VERSION_ENTRY = re.compile(r"^\.?v(\d+)(?:\..*)?$")


@dataclass(frozen=True)
class Task:
    """One command of the plan: what a scheduler runs as one job task."""

    id: str
    """Unique in the plan: ``sh010.fit``, ``sh010.passes.1001-1050``."""
    shot: str
    kind: str
    """One of TASK_KINDS."""
    args: tuple[str, ...]
    """The engine's argv after ``python -m engine``, with absolute paths."""
    depends: tuple[str, ...]
    """Ids of the tasks that must finish first."""
    accelerator: bool
    """Wants a GPU host (fit, atlases, passes)."""
    frames: tuple[int, int] | None
    """The chunk's plate frame range, when chunked."""

    def argv(self, python: str) -> list[str]:
        """The full command line on a worker whose engine Python is ``python``."""
        return [python, "-m", C.CLI_MODULE, *self.args]


@dataclass(frozen=True)
class Plan:
    """Every task of every shot, dependencies first."""

    tasks: tuple[Task, ...]
    shots: tuple[str, ...]

    def shot_tasks(self, shot: str) -> tuple[Task, ...]:
        return tuple(t for t in self.tasks if t.shot == shot)

    def task(self, task_id: str) -> Task:
        for t in self.tasks:
            if t.id == task_id:
                return t
        raise KeyError(task_id)

    def to_json(self) -> dict[str, object]:
        """The plan as ``farm plan --json`` prints it."""
        return {
            "shots": list(self.shots),
            "tasks": [
                {
                    "id": t.id,
                    "shot": t.shot,
                    "kind": t.kind,
                    "args": list(t.args),
                    "depends": list(t.depends),
                    "accelerator": t.accelerator,
                    "frames": None if t.frames is None else list(t.frames),
                }
                for t in self.tasks
            ],
        }


@dataclass(frozen=True)
class ShotPlan:
    """What the plan decided for a shot beside its tasks: what the back ends name as inputs and outputs."""

    shot: Shot
    frames: tuple[int, int]
    """The shot's plate frame range (all of the plate when the shot gives none)."""
    version: str
    """The export version its tasks write (``v003``)."""
    numbers: tuple[int, ...] = ()
    """The plate frame numbers of ``frames`` (the chunks split these)."""

    @property
    def manifest(self) -> str:
        return os.path.join(self.shot.run, C.EXPORTS_DIR, self.version, C.MANIFEST_NAME)

    @property
    def masks_out(self) -> str:
        return os.path.join(self.shot.run, C.AUTO_MASKS_DIR)


def load_plan(shots_file: str | Path) -> Plan:
    """Read and validate the shots file and plan every shot (reads each plate's frame numbers)."""
    return plan_shots(load_shots(shots_file))


def plan_shots(shots: ShotsFile) -> Plan:
    return plan_with_shots(shots)[0]


def plan_with_shots(shots: ShotsFile) -> tuple[Plan, list[ShotPlan]]:
    """The plan, and what it decided per shot (frame range, export version): what a back end names as job inputs
    and outputs beside the tasks. Reads every plate once."""
    plans = shot_plans(shots)
    tasks = [task for sp in plans for task in shot_tasks(sp)]
    return Plan(tuple(tasks), tuple(s.name for s in shots.shots)), plans


def shot_plans(shots: ShotsFile) -> list[ShotPlan]:
    """Each shot's frame range and export version (what needs the disk: the plate and the run folder)."""
    plans = []
    for shot in shots.shots:
        numbers = _in_range(shots.path, shot, plate_frame_numbers(shots.path, shot))
        plans.append(ShotPlan(shot, (numbers[0], numbers[-1]), next_version(shot.run), tuple(numbers)))
    return plans


def shot_tasks(sp: ShotPlan) -> list[Task]:
    """The tasks of one shot, dependencies first."""
    shot = sp.shot
    name = shot.name
    first, last = sp.frames
    frames = f"{first}-{last}"
    tasks: list[Task] = []

    def add(kind: str, args: list[str], depends: Iterable[str], chunk: tuple[int, int] | None = None) -> Task:
        suffix = f".{chunk[0]}-{chunk[1]}" if chunk is not None else ""
        task = Task(f"{name}.{kind}{suffix}", name, kind, tuple(args), tuple(depends), kind in ACCELERATOR_KINDS, chunk)
        tasks.append(task)
        return task

    fit_after: list[str] = []
    if shot.auto_masks:
        m = verb_flags(C.VERB_MASKS)
        found = add(MASKS, [C.VERB_MASKS, shot.plate, m["out"], sp.masks_out, *_masks_options(shot, sp)], [])
        fit_after = [found.id]
    f = verb_flags(C.VERB_FIT)
    fit_args = [C.VERB_FIT, shot.plate, f["out"], shot.run, FIT_RESUME_IF_STARTED_FLAG, f["preset"], shot.preset]
    for override in shot.set:
        fit_args += [f["set"], override]
    for mask in shot.masks:
        fit_args += [f["mask"], mask]
    if shot.auto_masks:
        fit_args.append(FIT_AUTO_MASKS_FLAG)
    if shot.auto_parts is not None:  # not given: the fit's default (the parts wherever that applies)
        fit_args.append(FIT_AUTO_PARTS_FLAG if shot.auto_parts else C.FIT_NO_AUTO_PARTS_FLAG)
    fit_args += [f["frames"], frames]
    fit_args += _option(f["colorspace"], shot.colorspace) + _option(f["fps"], shot.fps)
    fit_args += _option(f["start_frame"], shot.start_frame) + _option(f["device"], shot.device) + [f["no_bar"]]
    fit = add(FIT, fit_args, fit_after)

    e = verb_flags(C.VERB_EXPORT)
    export = [C.VERB_EXPORT, shot.run, EXPORT_INTO_ARG, sp.version, EXPORT_STAGE_ARG]
    device = _option(e["device"], shot.device)
    atlases = add(
        ATLASES, [*export, ATLASES, e["frames"], frames, *_option(e["atlas_size"], shot.atlas_size), *device,
                  *([] if shot.follow_flow else [C.EXPORT_NO_FOLLOW_FLOW_FLAG]),
                  *_option(e["precision"], shot.pass_precision), *([e["stmap"]] if shot.stmap else []),
                  e["no_bar"]],
        [fit.id],
    )  # fmt: skip
    numbers = list(sp.numbers) or list(range(first, last + 1))
    passes = [
        add(PASSES, [*export, PASSES, e["frames"], f"{a}-{b}", *device, e["no_bar"]], [atlases.id], (a, b))
        for a, b in chunk_ranges(numbers, shot.export_chunk)
    ]
    publish = add(PUBLISH, [*export, PUBLISH, e["no_bar"]], [p.id for p in passes])
    if shot.render is not None:
        r = verb_flags(VERB_RENDER)
        fmt = _option(r["format"], shot.render_format)
        for a, b in chunk_ranges(numbers, shot.render_chunk):
            add(
                RENDER,
                [VERB_RENDER, sp.manifest, r["out"], shot.render, r["frames"], f"{a}-{b}", *fmt, r["no_bar"]],
                [publish.id],
                (a, b),
            )
    if shot.preview:
        add(PREVIEW, [VERB_PREVIEW, sp.manifest], [publish.id])
    return tasks


def chunk_ranges(numbers: list[int], size: int) -> list[tuple[int, int]]:
    """Consecutive frame numbers in runs of ``size`` (the last shorter), as inclusive (first, last) ranges."""
    if size < 1:
        raise ValueError(f"chunk size {size} < 1")
    return [(numbers[i], numbers[min(i + size, len(numbers)) - 1]) for i in range(0, len(numbers), size)]


def next_version(run: str | Path) -> str:
    """The export version this plan's export tasks write: the next number after every one ``RUN/exports`` holds,
    published (``v002``) or left by a dead export (``.v003.partial``); except that an unfinished chunked export that
    is the newest (``.v004.chunks`` and no ``v004``: a farm run stopped part way) is continued, not left behind, so a
    sequence submitted again picks up its finished chunks (each export stage is idempotent)."""
    folder = Path(run) / C.EXPORTS_DIR
    taken = [0]
    chunked: set[int] = set()
    try:
        for entry in folder.iterdir():
            match = _VERSION_ENTRY.match(entry.name)
            if match:
                taken.append(int(match.group(1)))
                if entry.name.endswith(EXPORT_CHUNKS_SUFFIX):
                    chunked.add(int(match.group(1)))
    except (FileNotFoundError, NotADirectoryError):
        pass
    newest = max(taken)
    published = (folder / EXPORT_VERSION_FORMAT.format(newest)).exists()
    # one staged from another fit (a refine since) is left: its stages refuse to mix two fits into one version
    chunks = folder / f".{EXPORT_VERSION_FORMAT.format(newest)}{EXPORT_CHUNKS_SUFFIX}"
    if newest in chunked and not published and continues_fit(Path(run), chunks):
        return EXPORT_VERSION_FORMAT.format(newest)
    return EXPORT_VERSION_FORMAT.format(newest + 1)


def plate_frame_numbers(shots_file: Path, shot: Shot) -> list[int]:
    """The plate's frame numbers, listed (a sequence) or counted (a movie: PyAV) without decoding the frames."""
    from ..io.clip import open_clip

    try:
        info = open_clip(shot.plate, start_frame=shot.start_frame)
    except InputError as exc:
        where = f"{exc.path}: " if exc.path and exc.path != shot.plate else ""
        raise InputError(shots_file, f"shot {shot.name!r}: plate {shot.plate}: {where}{exc.problem}", exc.fix) from None
    return list(info.frame_numbers)


def _in_range(shots_file: Path, shot: Shot, numbers: list[int]) -> list[int]:
    if shot.frames is None:
        return numbers
    first, last = shot.frames
    for n in (first, last):
        if n not in numbers:
            from ..io.clip import frame_ranges

            raise InputError(
                shots_file,
                f"shot {shot.name!r}: frame {n} of 'frames' is not in the plate "
                f"(its frames are {frame_ranges(numbers)})",
                f"give frames within {numbers[0]}-{numbers[-1]}",
            )
    return [n for n in numbers if first <= n <= last]


def _masks_options(shot: Shot, sp: ShotPlan) -> list[str]:
    """``masks --frames`` speaks the plate's frame numbers, and a movie's from 0 (the verb has no --start-frame)."""
    offset, m = shot.start_frame or 0, verb_flags(C.VERB_MASKS)
    options = [m["frames"], f"{sp.frames[0] - offset}-{sp.frames[1] - offset}"]
    return options + _option(m["colorspace"], shot.colorspace)


def _option(flag: str, value: object) -> list[str]:
    return [] if value is None else [flag, str(value)]


def verb_flags(verb: str) -> dict[str, str]:
    """``cli_parser.verb_flags``: the flags of ``verb`` as the engine's parser declares them (imported when a plan
    is made: the parser's farm verb imports the back ends, which import this module)."""
    from ..cli_parser import verb_flags as declared

    return declared(verb)


def task_graph_text(plan: Plan) -> str:
    """The plan as indented text, one task per line with what it waits for (``farm plan`` without --json); each
    command as a POSIX shell would run it (quoted where a name has spaces, quotes, ``$`` or newlines), so a line
    pasted into a shell runs exactly that task."""
    lines = []
    for shot in plan.shots:
        lines.append(f"{shot}:")
        for t in plan.shot_tasks(shot):
            gpu = " [gpu]" if t.accelerator else ""
            after = f"  <- {', '.join(t.depends)}" if t.depends else ""
            lines.append(f"  {t.id}{gpu}{after}")
            lines.append(f"      {shlex.join(t.argv('python'))}")
    return "\n".join(lines)


__all__ = [
    "TASK_KINDS",
    "Plan",
    "ShotPlan",
    "Task",
    "chunk_ranges",
    "load_plan",
    "next_version",
    "plan_shots",
    "plan_with_shots",
]
