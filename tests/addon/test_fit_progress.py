"""The Fit Atlas bar with the real engine (``core.jobs.FitJob`` as the modal operator drives it, no Blender
needed): it moves during the flow, training and export, never goes back (not when the export starts, and not
when a stopped fit is resumed), and its line says the ETA is the whole fit's."""

from __future__ import annotations

import subprocess
import time

import pytest
from helpers import engine_python
from neural_atlas.addon.core import engine_commands as EC
from neural_atlas.addon.core import engine_process as EP
from neural_atlas.addon.core.jobs import FitJob

FRAMES = 5
STEPS = 150
SETS = ["batch=256", "eval_every=10", "eval_pixels=4000", "bootstrap_steps=10", "global_rigidity_steps=5"]


def _clip(py: str, folder) -> EC.ClipInputs:
    code = (
        "import sys; from engine.data.synthetic import SceneSpec, make_scene, write_scene; "
        f"write_scene(make_scene(SceneSpec(width=48, height=32, frames={FRAMES}, fg_size=(16, 12), "
        "fg_start=(10.0, 8.0))), sys.argv[1])"
    )
    subprocess.run([py, "-c", code, str(folder)], check=True, timeout=300)
    return EC.ClipInputs(str(folder / "frames"), (str(folder / "masks"),), 0, FRAMES - 1)


def _drive(job: FitJob, stop_at: float | None = None) -> list[tuple[str, float, str]]:
    """Step the job as the modal timer does: (command, bar, line) after each step; Cancel once the bar passes
    ``stop_at``."""
    job.start()
    seen = []
    while True:
        more = job.step()
        seen.append((job.label, job.fraction, job.status_text()))
        if not more:
            return seen
        if stop_at is not None and job.fraction > stop_at and not job.cancelling:
            job.cancel()
        time.sleep(0.02)


@pytest.mark.slow
def test_fit_bar_moves_through_every_stage_and_resume_continues(tmp_path):
    py = engine_python("fit", "torch")
    clip = _clip(py, tmp_path / "clip")
    run = str(tmp_path / "run")
    sets = [a for s in [f"steps={STEPS}", *SETS] for a in ("--set", s)]
    job = FitJob(py, run, lambda: clip, "draft", sets)
    first = _drive(job, stop_at=0.08)
    assert job.result is not None and job.result.status == EP.STATUS_CANCELLED and job.can_resume()
    bars = [bar for _, bar, _ in first]
    assert bars == sorted(bars) and 0.0 < bars[-1] < 1.0
    lines = [line for _, _, line in first]
    assert any(line.startswith("step ") and "for the whole fit" in line for line in lines), lines

    resumed = FitJob(py, run, None, "draft", [])
    second = _drive(resumed)
    assert resumed.result is not None and resumed.result.status == EP.STATUS_OK, resumed.result
    bars2 = [bar for _, bar, _ in second]
    start = next(bar for _, bar, line in second if line.startswith("step "))
    print(f"bar: {bars[-1]:.3f} when cancelled, {bars2[0]:.3f} on resuming, {start:.3f} at its first step line")
    assert bars2[0] >= bars[-1] and start >= bars[-1]  # Resume does not drop the bar to 0
    assert bars2 == sorted(bars2) and bars2[-1] == 1.0, second  # nor does the export's start
    exporting = [line for label, _, line in second if label == "export"]
    assert any(line.startswith("exporting passes ") and "for the whole fit" in line for line in exporting), exporting
