"""``fit --refine STEPS [--preset P]``: continue a FINISHED fit for more steps, keeping what the artist made.

A refine is a resume of a fit that has finished: the same clip, masks, model and loss weights, the checkpoint's
weights, optimiser and sampling state, and a longer schedule (``steps`` = the steps done + STEPS). With ``--preset
P`` the schedule is P's (its learning rates, evaluation and checkpoint settings: ``config.RESUMABLE_FIELDS``) and
without STEPS the fit runs on to P's step budget. Everything else must be what the fit ran with, because the
checkpoint was trained with it:

- the loss phases (``config.PHASE_FIELDS``: ``bootstrap_steps``, ``global_rigidity_steps``) go on as the fit ran
  them: one the fit is past stays past (a preset's longer bootstrap is not replayed), and one the fit had on to its
  last step stays on to the refine's (``draft`` and ``balanced`` fit their masks for all of their steps: let go at
  the end of a refine's first phase, the alpha would hand a body that spins or bends to the background);
- the fields that decide only how a fit starts (``config.START_FIELDS``) are carried by the checkpoint;
- any other difference (the model, a loss weight, the sampling) is refused in one line: fit P into a new folder.

Before training continues, the export the edit layers were painted against is recorded in ``edits/aligned.json``
(unless a record is there; ``engine/edit/aligned.py``): the run's exports are never overwritten, so that export's
passes and manifest stay as they are, and ``realign`` carries the paint from them onto the refined fit's next export
(``engine/edit/realign.py``).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from .. import contract as C
from ..config import PHASE_FIELDS, START_FIELDS, FitConfig, preset_config, resume_changes, run_on
from ..errors import InputError
from .run_folder import RunFolder


@dataclasses.dataclass(frozen=True)
class RefinePlan:
    """What a refine continues with: the config (steps = ``done`` + the new steps) and the steps already done."""

    cfg: FitConfig
    done: int

    @property
    def more(self) -> int:
        return self.cfg.steps - self.done


def refine_config(run_dir: str | Path, more_steps: int | None, preset: str | None) -> RefinePlan:
    """The config a refine of the finished fit in ``run_dir`` continues with, checked before anything is written.

    ``more_steps``: steps to add (None: on to ``preset``'s step budget, which then must be given and above the steps
    done). Every refusal is one line naming the file and the fix."""
    run = RunFolder(run_dir)
    flag = C.FIT_REFINE_FLAG
    if not run.checkpoint.exists():
        raise InputError(run.path, f"holds no fit to refine ({C.RUN_CHECKPOINT} missing)", "fit the clip first")
    saved = run.read_config()
    metrics = run.read_metrics()
    if metrics is None:
        raise InputError(
            run.path,
            f"{flag}: this fit has not finished (no {C.RUN_METRICS})",
            "continue it with --resume first; refine it once it has finished",
        )
    done = int(metrics["steps"])
    cfg = saved
    if preset is not None and preset != saved.preset:
        cfg = _with_preset(run, saved, preset_config(preset))
    if more_steps is None:
        if preset is None:
            raise InputError(None, f"{flag} without STEPS or --preset", f"pass {flag} STEPS (e.g. {flag} 1000)")
        target = preset_config(preset).steps
        if target <= done:
            raise InputError(
                run.metrics,
                f"{flag} --preset {preset}: this fit already ran {done} steps, the preset's budget is {target}",
                f"pass {flag} STEPS to add steps",
            )
        more_steps = target - done
    if more_steps < 1:
        raise InputError(None, f"{flag} {more_steps}: no steps to add", f"pass a positive number, e.g. {flag} 1000")
    return RefinePlan(run_on(cfg, done, done + more_steps), done)


def _with_preset(run: RunFolder, saved: FitConfig, target: FitConfig) -> FitConfig:
    """``saved`` with ``target``'s schedule, or one line naming the first field the checkpoint was not fitted with.
    Only what the presets themselves differ in counts: the fit's own ``--set`` values (``long_edge``, ...) stay."""
    allowed, others = resume_changes(preset_config(saved.preset), target)
    for key in others:
        if key == "preset" or key in START_FIELDS:
            continue
        if key in PHASE_FIELDS:
            continue  # the fit's own phases go on as they ran (``run_on``)
        raise InputError(
            run.config,
            f"{C.FIT_REFINE_FLAG} --preset {target.preset}: the preset has {key} {getattr(target, key)!r}, this fit "
            f"was trained with {getattr(saved, key)!r} (preset {saved.preset})",
            f"refine with --preset {saved.preset} (or without --preset), or fit {target.preset} into a new --out",
        )
    schedule = {key: getattr(target, key) for key in allowed if key not in PHASE_FIELDS}  # phases: ``run_on``
    return dataclasses.replace(saved, **schedule)


__all__ = [
    "RefinePlan",
    "refine_config",
]
