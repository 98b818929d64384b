"""The run policy: what ``fit`` does with its run folder. A new fit starts, a stopped one resumes (``--resume``,
``--resume-if-started``), a finished one is refitted (``--refit``) or refined (``--refine``): ``plan_fit``
reads the folder once for the command line's flags and returns the plan; ``read_resume`` reads and checks what
a resume continues from. The same clip, masks, frames, colour space and config (but for the schedule) are
required of every resume, in one line naming the first difference."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import torch

from .. import contract as C
from ..config import (
    RESUMABLE_FIELDS,
    FitConfig,
    apply_overrides,
    parse_set_args,
    preset_config,
    resume_changes,
    run_on,
)
from ..data.scene_analysis import SceneAnalysis
from ..errors import InputError
from ..io.clip import frame_positions
from ..io.colour import recorded_space, resolve
from ..terms.cli import FIT_RESUME_IF_STARTED_FLAG
from ..terms.run_folder import FIT_AUTO_MASKS_FLAG, RUN_CONFIG
from .auto_parts import PartsRequest, parts_wanted, strokes_in_run
from .fit_inputs import FitInputs
from .run_folder import ClipRecord, RunFolder

#: What ``plan_fit`` found to do: start a new fit, continue a stopped one, fit again over a finished one, continue
#: a finished one for more steps, or nothing (``--resume-if-started`` with this fit finished).
PLAN_START, PLAN_RESUME, PLAN_REFIT, PLAN_REFINE, PLAN_DONE = "start", "resume", "refit", "refine", "done"


@dataclass(frozen=True)
class FitMode:
    """What the command line asks of RUN_DIR: ``--resume``, ``--refit``, ``--resume-if-started`` (``if_started``),
    ``--refine [STEPS]`` (``refine``: None when not given, 0 for the preset's steps)."""

    resume: bool = False
    refit: bool = False
    if_started: bool = False
    refine: int | None = None

    def check(self, inputs: FitInputs) -> None:
        """The flags that cannot go together, refused in one line before RUN_DIR is read."""
        if self.resume and self.refit:
            raise InputError(
                None, "--resume and --refit both given", "pass --resume to continue the fit, or --refit to fit again"
            )
        if self.if_started and (self.resume or self.refit):
            raise InputError(
                None,
                f"{FIT_RESUME_IF_STARTED_FLAG} with --{'resume' if self.resume else 'refit'}",
                f"pass {FIT_RESUME_IF_STARTED_FLAG} alone: it starts, continues or leaves the fit as RUN_DIR holds it",
            )
        if self.refine is not None:
            clashing = [flag for flag, given in (("--resume", self.resume), ("--refit", self.refit),
                        (FIT_RESUME_IF_STARTED_FLAG, self.if_started), (FIT_AUTO_MASKS_FLAG, inputs.auto_masks),
                        ("--frames", inputs.frames is not None)) if given]  # fmt: skip
            if clashing:
                raise InputError(
                    None,
                    f"{C.FIT_REFINE_FLAG} with {clashing[0]}",
                    f"pass {C.FIT_REFINE_FLAG} alone with --out: it continues the finished fit as it was fitted",
                )


@dataclass(frozen=True)
class FitPlan:
    """What ``fit`` does with RUN_DIR (``action``, one of the ``PLAN_*``), with the config it trains with and what it
    fits (``inputs``, their frames as the plate's positions; None: every frame, or a resume's recorded ones). The
    command line builds it with ``plan_fit``; the demo, the bench and the tests build it directly."""

    action: str
    cfg: FitConfig
    inputs: FitInputs = field(default_factory=FitInputs)
    #: ``PLAN_REFINE``: the steps the finished fit had done
    refined_from: int = 0
    #: ``PLAN_DONE``: the finished fit's metrics
    metrics: dict[str, Any] | None = None

    @property
    def resume(self) -> bool:
        """Whether the fit continues from RUN_DIR's checkpoint (a resume or a refinement)."""
        return self.action in (PLAN_RESUME, PLAN_REFINE)

    @property
    def refit(self) -> bool:
        """Whether the fit starts again over a finished one (its edits and exports kept)."""
        return self.action == PLAN_REFIT


def plan_fit(
    run_dir: Path,
    inputs: FitInputs,
    mode: FitMode,
    *,
    preset: str | None,
    default_preset: str,
    set_args: list[str],
    auto_parts: bool | None = None,
) -> FitPlan:
    """The plan of ``fit``'s command line (``inputs.frames`` in the plate's numbers, ``set_args`` the ``--set``
    texts, ``auto_parts`` the ``--auto-parts``/``--no-auto-parts`` flag or None): the flags that cannot go together
    refused in one line, RUN_DIR read once for what it holds, the config built (a resume's from config.json, with
    its preset kept), the frames turned into positions in the plate a resume continues with, and the parts policy
    of a fit that starts (``_plan_parts``)."""
    mode.check(inputs)
    if mode.refine is not None:
        return _plan_refine(run_dir, mode.refine, preset, set_args, inputs)
    given_scribbles = inputs.scribbles
    if auto_parts and inputs.scribbles is None:  # strokes an earlier --auto-parts wrote, or the artist fixed
        inputs = replace(inputs, scribbles=strokes_in_run(run_dir))
    run = RunFolder(run_dir)
    saved = record = None
    resume = mode.resume
    if mode.if_started and run.checkpoint.exists():
        cfg = apply_overrides(preset_config(preset or default_preset), parse_set_args(set_args))
        record = run.read_clip()
        given = None if inputs.frames is None else frame_positions(record.source, inputs.frames, record.movie_start)
        if _same_fit(run, saved := run.read_config(), record, replace(inputs, frames=given), cfg):
            return FitPlan(PLAN_DONE, cfg, metrics=run.read_metrics())
        resume = True
    if resume:
        cfg = saved or run.read_config()
        if preset is not None and preset != cfg.preset:
            raise InputError(
                run_dir / RUN_CONFIG,
                f"--preset {preset} with --resume: this fit started with preset {cfg.preset}",
                "drop --preset to continue it, or fit with that preset into a new --out (or --refit)",
            )
    else:
        cfg = preset_config(preset or default_preset)
    if mode.if_started and resume:  # the config the fit started with, as the same argv builds it
        cfg = preset_config(preset or default_preset)
    overrides = parse_set_args(set_args)
    last, cfg = cfg.steps, apply_overrides(cfg, overrides)
    if resume and not mode.if_started:  # a phase that lasted the whole fit lasts the new schedule too
        cfg = run_on(cfg, last, cfg.steps, keep=overrides)
    frames = inputs.frames
    if resume and frames is not None:  # the recorded plate, numbered as it was fitted
        record = record or run.read_clip()
        missing = record.missing_input(run_dir)
        if missing is not None:
            raise missing
        positions = frame_positions(record.source, frames, record.movie_start)
    else:
        positions = frames if frames is None or inputs.clip is None else frame_positions(
            inputs.clip, frames, inputs.start_frame
        )  # fmt: skip
    plan = FitPlan(
        PLAN_RESUME if resume else PLAN_REFIT if mode.refit else PLAN_START, cfg, replace(inputs, frames=positions)
    )
    return plan if plan.resume else _plan_parts(run_dir, plan, auto_parts, given_scribbles)


def _plan_parts(run_dir: Path, plan: FitPlan, flag: bool | None, given_scribbles: str | Path | None) -> FitPlan:
    """A fit that starts: its one mask split into the parts that move apart (``auto_parts.parts_wanted``: the
    flag, or where it applies by default). Strokes found in RUN_DIR/parts are the scribbles (an earlier search's,
    or the artist's fix of them); else the search runs in the fit, on its own frames, mask and flow."""
    inputs = plan.inputs
    if not parts_wanted(flag, plan.cfg, inputs.masks, given_scribbles, inputs.auto_masks):
        return plan
    asked = flag is True
    scribbles = inputs.scribbles
    if scribbles is None and not asked:
        scribbles = strokes_in_run(run_dir)
    parts = PartsRequest(asked) if scribbles is None else None
    return replace(plan, inputs=replace(inputs, scribbles=scribbles, parts=parts))


def _plan_refine(
    run_dir: Path, steps: int | None, preset: str | None, set_args: list[str], inputs: FitInputs
) -> FitPlan:
    """``fit --refine [STEPS] [--preset P]``: a finished fit continued (``engine.fit.refine``), given alone."""
    from .refine import refine_config

    plan = refine_config(run_dir, steps or None, preset)
    cfg = apply_overrides(plan.cfg, parse_set_args(set_args))
    return FitPlan(PLAN_REFINE, cfg, inputs, refined_from=plan.done)


def _same_fit(run: RunFolder, saved: FitConfig, record: ClipRecord, inputs: FitInputs, cfg: FitConfig) -> bool:
    """For a retried fit (``fit --resume-if-started``, whose arguments are the same on every try) of a run folder
    that holds a checkpoint: True when it holds this fit finished (nothing to do), False when a checkpoint of
    this same fit (continue it as ``--resume`` does). This same fit: the clip, masks, scribbles, frames and colour
    space given are the recorded ones and ``cfg`` differs from config.json in nothing but the schedule
    (``RESUMABLE_FIELDS``), checked as ``--resume`` checks them; else one line. Reads only: the fit that follows
    takes the lock."""
    _check_resume_inputs(run, record, inputs)
    _check_resume_colour(run, record, inputs.colorspace)
    _check_resume_config(run, saved, cfg)
    return run.read_metrics() is not None and cfg == saved


@dataclass
class ResumedFit:
    """What a resume continues from, read from its run folder and checked against what ``fit`` was given."""

    saved: FitConfig
    record: ClipRecord
    scene: SceneAnalysis
    state: dict[str, Any]

    @property
    def inputs(self) -> FitInputs:
        """What the resume fits: the recorded plate, masks, frames, scribbles and colour space, read as fitted."""
        return FitInputs.of_record(self.record)


def read_resume(run: RunFolder, cfg: FitConfig, device: torch.device, inputs: FitInputs) -> ResumedFit:
    """``fit --resume``'s run folder: its config, clip record, scene and checkpoint, read under the lock; the
    clip, masks, frames (positions), scribbles and colour space given must be the recorded ones, the recorded input
    must be there, ``cfg`` may change only the schedule and the checkpoint must be this run's (each one line)."""
    saved, record = run.read_config(), run.read_clip()
    scene = run.read_scene(record)
    _check_resume_inputs(run, record, inputs)
    missing = record.missing_input(run.path)
    if missing is not None:
        raise missing
    _check_resume_colour(run, record, inputs.colorspace)
    _check_resume_config(run, saved, cfg)
    state = run.load_checkpoint(device)
    run.check_checkpoint_belongs(state, saved, record)
    return ResumedFit(saved, record, scene, state)


def check_fit_inputs(cfg: FitConfig, inputs: FitInputs, resume: bool) -> None:
    """``fit``'s input as given, checked before anything is read: a new fit needs a clip, masks come from folders
    or from motion (not both), and the paper model takes exactly one mask (a resume fits the recorded ones)."""
    mask_dirs = inputs.masks
    if not resume and inputs.clip is None:
        raise InputError(None, "no clip given", "pass a frame folder or movie file")
    find_masks = inputs.auto_masks and not resume
    if find_masks and mask_dirs:
        raise InputError(None, f"{FIT_AUTO_MASKS_FLAG} and --mask both given", "pass one of them")
    seen: dict[str, str | Path] = {}
    for mask in mask_dirs:  # one folder twice would fit two identical layers, each owning half of the object
        real = os.path.normcase(os.path.realpath(mask))
        if real in seen:
            raise InputError(mask, f"given twice as --mask (also as {seen[real]})", "pass each object's masks once")
        seen[real] = mask
    if cfg.model == "paper" and not resume:
        check_paper_layers(mask_dirs, find_masks, inputs.scribbles)


def check_paper_layers(mask_dirs: Sequence[str | Path], auto_masks: bool, scribble_dir: str | Path | None) -> None:
    """The paper's architecture has one background and one foreground layer: exactly one --mask (masks found by
    motion may be none, and scribbles split the object into several), checked before anything is read."""
    given = None
    if auto_masks:
        given = f"{FIT_AUTO_MASKS_FLAG} was given"
    elif scribble_dir is not None:
        given = f"{C.SCRIBBLE_ARG} split the object into layers"
    elif len(mask_dirs) != 1:
        given = f"{len(mask_dirs)} --mask folders were given"
    if given is not None:
        raise InputError(
            None,
            f"the paper model fits one background and one foreground layer, but {given}",
            "pass exactly one --mask, or use a fast preset (draft, balanced or final)",
        )


def _same_path(given: str | Path, recorded: str) -> bool:
    """Whether a path given on the command line names what the run recorded (symlinks and ``~`` resolved)."""
    return os.path.realpath(os.path.expanduser(os.fspath(given))) == os.path.realpath(recorded)


def _check_resume_inputs(run: RunFolder, record: ClipRecord, inputs: FitInputs) -> None:
    """``--resume`` continues the fit of the clip, masks, scribbles and frames clip.json records: any of them given
    again must be the recorded one (a different mask folder would otherwise be fitted while clip.json keeps the
    old one). One line naming the first difference."""
    clip, mask_dirs, frame_range, scribble_dir = inputs.clip, inputs.masks, inputs.frames, inputs.scribbles
    changed: tuple[str, str, str] | None = None
    if clip is not None and not _same_path(clip, record.source):
        changed = ("the clip", str(clip), record.source)
    elif mask_dirs and not (len(mask_dirs) == len(record.masks) and all(map(_same_path, mask_dirs, record.masks))):
        changed = ("--mask", ", ".join(map(str, mask_dirs)), ", ".join(record.masks) or "no masks")
    elif scribble_dir is not None and (record.scribbles is None or not _same_path(scribble_dir, record.scribbles)):
        changed = ("--scribbles", str(scribble_dir), record.scribbles or "no scribbles")
    elif frame_range is not None and tuple(frame_range) != tuple(record.frame_range):
        first, last = record.frame_range
        changed = ("--frames", f"{frame_range[0]}:{frame_range[1]}", f"{first}:{last}")
    if changed is not None:
        what, given, recorded = changed
        raise InputError(
            run.clip,
            f"--resume with {what} {given}, but this run fitted {recorded}",
            "drop it to continue the fit as it started, or fit with it into a new --out (or --refit)",
        )


def _check_resume_colour(run: RunFolder, record: ClipRecord, given: str | None) -> tuple[str, str | None]:
    """The recorded plate colour space and config a resume continues with, as recorded (a run made before colour
    management: "sRGB"/"linear" and no config, which ``prepare_clip`` reads as it did); a ``--colorspace`` that
    names another space is refused in one line."""
    space, config = recorded_space(record.colorspace, record.colour_config)
    if given is not None and resolve(given, config) != space:
        raise InputError(
            run.clip,
            f"--resume with --colorspace {given}, but this run fitted the plate as {space!r}",
            "drop --colorspace to continue the fit as it started, or fit with it into a new --out (or --refit)",
        )
    return record.colorspace, record.colour_config


def _check_resume_config(run: RunFolder, saved: FitConfig, cfg: FitConfig) -> None:
    """A resume may change the schedule (``config.RESUMABLE_FIELDS``) and nothing else: one line naming the
    first other field that differs from config.json."""
    _, refused = resume_changes(saved, cfg)
    if refused:
        key = refused[0]
        raise InputError(
            run.config,
            f"--resume cannot change {key} ({getattr(saved, key)!r} -> {getattr(cfg, key)!r}); "
            f"a resume changes only {', '.join(RESUMABLE_FIELDS)}",
            "drop that --set to continue the fit, or fit with it into a new --out (or --refit)",
        )
