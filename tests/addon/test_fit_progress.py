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


def test_the_status_line_says_what_find_parts_found_while_and_after_the_fit(tmp_path, monkeypatch):
    """The parts search (after the flow, before training) is the status line while it runs and once it has found
    the parts, not "optical flow 4/4"; training's line then says the object was split; the fit's log keeps the
    finding for the line once it is imported (``progress.parts_finding``), a resumed fit's too."""
    from helpers import fake_python
    from neural_atlas.addon.core import progress

    monkeypatch.setenv("FAKE_ENGINE_MODE", "parts")
    run = str(tmp_path / "run")
    clip = EC.ClipInputs(str(tmp_path / "frames"), (str(tmp_path / "masks"),), 0, 4)
    job = FitJob(fake_python(tmp_path), run, lambda: clip, "draft", [])
    lines = [line for _, _, line in _drive(job)]
    assert job.result is not None and job.result.status == EP.STATUS_OK, job.result
    looking, found = f"looking for parts that move apart ({run}/parts)", progress.parts_finding(job.log_path)
    assert found == (2, f"2 parts that move apart, strokes on 5 frame(s) (0, 1, 2, 3, 4) ({run}/parts)")
    assert looking in lines and found[1] in lines
    assert not any(line.startswith("optical flow") for line in lines[lines.index(looking) :]), sorted(set(lines))
    training = [line for line in lines if line.startswith("step ")]
    assert training and all(line.endswith(" · Find Parts: the object split into 2 parts that move apart")
                            for line in training)  # fmt: skip
    assert progress.parts_finding(str(tmp_path / "no.log")) is None
