"""The embedded demo: a generated plate with a moving object, fitted end to end.

README command 1 runs this. It needs nothing outside the repository (no ``../shared``, no downloads),
and is idempotent: a second run reuses the clip and a finished fit, and resumes an interrupted one.
"""

from __future__ import annotations

import io
import json
import sys
from pathlib import Path

import torch

from engine import contract as C
from engine.config import apply_overrides, preset_config
from engine.fit_preview import write_contact_sheet
from engine.synthetic import demo_spec, make_scene, write_scene
from engine.trainer import FitCancelled, fit, load_run


def run_demo(out: Path, preset: str = "draft", overrides: dict[str, str] | None = None) -> dict:
    out = Path(out)
    print(f"== demo clip -> {out / 'clip'}", file=sys.stderr)
    frames_dir, masks_dir = write_scene(make_scene(demo_spec()), out / "clip")
    run = out / "run"
    cfg = apply_overrides(preset_config(preset), overrides or {})
    if (run / C.RUN_METRICS).exists():
        print(f"== fit already done in {run} (delete it to refit)", file=sys.stderr)
    else:
        resume = (run / C.RUN_CHECKPOINT).exists()
        print(f"== {'resuming' if resume else 'fitting'} ({preset}) -> {run}", file=sys.stderr)
        try:
            # the bar on stderr is for people; the JSON progress lines go to the run's fit.log only
            fit(frames_dir, [masks_dir], run, cfg, resume=resume, stream=io.StringIO())
        except FitCancelled:
            print(f"== cancelled; run the same command again to resume {run}", file=sys.stderr)
            raise
    metrics = json.loads((run / C.RUN_METRICS).read_text())
    model, prepared, _ = load_run(run)
    sheet = write_contact_sheet(model, prepared.frames, prepared.size, torch.device("cpu"), out / "contact_sheet.png")
    print(
        f"== done: PSNR {metrics['psnr']:.2f} dB, foreground alpha IoU {metrics['alpha_iou'][0]:.3f}, "
        f"{metrics['steps']} steps in {metrics['train_seconds']:.0f} s\n"
        f"   clip: {out / 'clip'}\n   fit:  {run} (config.json, metrics.json, checkpoint.pt, fit.log)\n"
        f"   look: {sheet}",
        file=sys.stderr,
    )
    return metrics
