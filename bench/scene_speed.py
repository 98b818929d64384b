"""What the scene analysis saves: the same clip fitted with ``components=auto`` and ``components=all``.

    python -m bench scene-speed CLIP [--mask FOLDER] [--frames A:B] [--preset draft] [--steps N]
                                        [--long-edge PX] [--out DIR]

Both fits use the same config, seed and steps; only ``components`` differs. Prints one line per fit
(seconds per step, full-frame PSNR, background mapping class, terms evaluated) and the ratio of seconds
per step, then a JSON summary as the last line. Training time only (the flow is computed once per run and
cached; it is not part of ``train_seconds``). docs/engine.md (Scene analysis) quotes its ratios; the full table is in
docs/bench/experiments.md (Engine measurements).
"""

from __future__ import annotations

import io
import json
import sys
from pathlib import Path
from typing import Any

from engine.config import apply_overrides, preset_config
from engine.fit.fit_inputs import FitInputs
from engine.fit.run_folder import RunFolder
from engine.fit.run_plan import PLAN_START, FitPlan
from engine.fit.trainer import fit

#: A checkpoint interval longer than any of these fits: the comparison times training, not checkpoints.
NO_CHECKPOINTS_S = "1e9"
#: Guard against a zero-step fit's 0 s/step in the ratio.
MIN_SECONDS_PER_STEP = 1e-9


def compare_components(
    clip: str | Path,
    masks: list[str | Path],
    out: Path,
    preset: str = "draft",
    steps: int = 300,
    long_edge: int = 384,
    frame_range: tuple[int, int] | None = None,
    overrides: dict[str, str] | None = None,
) -> dict[str, Any]:
    """Fit ``clip`` twice (components auto, then all) into ``out/auto`` and ``out/all``; returns both
    fits' seconds per step, PSNR and scene decisions, and the seconds-per-step ratio all/auto."""
    rows: dict[str, Any] = {}
    for comp in ("auto", "all"):
        cfg = apply_overrides(
            preset_config(preset),
            {
                "steps": str(steps),
                "long_edge": str(long_edge),
                "eval_every": str(max(steps, 1)),
                "checkpoint_seconds": NO_CHECKPOINTS_S,
                "components": comp,
                **(overrides or {}),
            },
        )
        run = Path(out) / comp
        plan = FitPlan(PLAN_START, cfg, FitInputs(clip, masks, frame_range))
        metrics = fit(run, plan, device_name="cpu", progress_bar=False, stream=io.StringIO())
        scene = RunFolder(run).read_scene()
        rows[comp] = {
            "seconds_per_step": metrics["seconds_per_step"],
            "psnr": metrics["psnr"],
            "alpha_iou": metrics["alpha_iou"],
            "background_motion": scene.background_motion,
            "active_terms": scene.active_terms,
            "working_size": metrics["working_size"],
            "frames": metrics["frames"],
        }
    auto_sps = max(rows["auto"]["seconds_per_step"], MIN_SECONDS_PER_STEP)
    return {
        "clip": str(clip),
        "steps": steps,
        "preset": preset,
        **rows,
        "speedup": rows["all"]["seconds_per_step"] / auto_sps,
    }


def print_comparison(res: dict[str, Any]) -> None:
    """One line per fit and the speed-up on stderr, the JSON summary as the last line of stdout."""
    for comp in ("auto", "all"):
        r = res[comp]
        print(
            f"components={comp}: {r['seconds_per_step'] * 1000:.1f} ms/step, PSNR {r['psnr']:.2f} dB, "
            f"background {r['background_motion']}, {len(r['active_terms'] or [])} terms",
            file=sys.stderr,
        )
    print(f"speed-up (all / auto seconds per step): {res['speedup']:.2f}x", file=sys.stderr)
    print(json.dumps(res))
