"""The jobs the operators drive (``core.jobs``), with a stand-in engine and no Blender: a fit then its export,
refusals before anything runs, a cancelled fit, Find Masks' folder and log, the estimate's rows."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest
from helpers import fake_python
from neural_atlas.addon.core import engine_commands as EC
from neural_atlas.addon.core import engine_process as EP
from neural_atlas.addon.core.errors import UserError
from neural_atlas.addon.core.jobs import EstimateJob, FitJob, MasksJob, failed

from engine import contract as C
from engine.terms.protocol import progress_line


def _clip(tmp_path) -> EC.ClipInputs:
    return EC.ClipInputs(str(tmp_path / "plate"), (str(tmp_path / "masks"),), 0, 2)


def _drive(job, limit: int = 2000) -> list[str]:
    """Start and step the job to its end as the modal timer does; the status line after each step."""
    job.start()
    statuses = []
    for _ in range(limit):
        more = job.step()
        statuses.append(job.status_text())
        if not more:
            return statuses
        time.sleep(0.01)
    raise AssertionError("the job never finished")


def test_fit_job_fits_then_exports_into_one_log(tmp_path):
    run = str(tmp_path / "run")
    job = FitJob(fake_python(tmp_path), run, lambda: _clip(tmp_path), "draft", EC.set_args(768))
    assert [c.label for c in job.commands] == ["fit", "export"] and job.status_text() == "starting…"
    statuses = _drive(job)
    assert job.result is not None and job.result.status == EP.STATUS_OK
    assert job.manifest and job.manifest.endswith(C.MANIFEST_NAME)
    assert any(s.startswith("step ") and " dB · ETA " in s for s in statuses)
    log = Path(job.log_path).read_text().splitlines()
    commands = [ln for ln in log if ln.startswith("$ ")]
    assert len(commands) == 2 and f" {C.VERB_FIT} " in commands[0] and f" {C.VERB_EXPORT} {run}" in commands[1]
    assert job.log_path == run + ".blender.log" and not job.can_resume()


def test_fit_job_refuses_before_gathering_inputs(tmp_path):
    run = tmp_path / "run"

    def never():
        raise AssertionError("inputs gathered although the run folder was refused")

    with pytest.raises(UserError, match="nothing to resume in"):
        FitJob("py", str(run), None, "draft", [])
    run.mkdir()
    (run / C.RUN_CHECKPOINT).write_text("x")
    with pytest.raises(UserError, match="already holds a fit: Resume it, or choose another Run Folder"):
        FitJob("py", str(run), never, "draft", [])
    resume = FitJob("py", str(run), None, "draft", [])
    assert "--resume" in resume.commands[0].argv and resume.keep_log and resume.can_resume()


def test_cancelled_fit_stops_before_the_export_and_can_resume(tmp_path, monkeypatch):
    monkeypatch.setenv("FAKE_ENGINE_MODE", "hang")
    job = FitJob(fake_python(tmp_path), str(tmp_path / "run"), lambda: _clip(tmp_path), "draft", [])
    job.start()
    while job.state.step < 2:
        job.step()
        time.sleep(0.01)
    job.cancel()
    assert job.status_text() == "cancelling: writing a checkpoint…"
    while job.step():
        time.sleep(0.01)
    assert job.result is not None and job.result.status == EP.STATUS_CANCELLED
    assert job.label == "fit" and job.manifest is None and job.can_resume()


def test_an_export_without_a_manifest_is_a_failure(tmp_path):
    job = FitJob("py", str(tmp_path / "run"), lambda: _clip(tmp_path), "draft", [])
    job.index = 1  # the export ran
    ok = EP.JobResult(EP.STATUS_OK, 0, "done", job.log_path)
    result = job.finish(ok)
    assert (result.status, result.message, result.returncode) == (EP.STATUS_FAILED, "export wrote no manifest", 0)
    assert failed(ok, "why").log_path == job.log_path


def test_masks_job_writes_a_fresh_folder_and_reads_its_event(tmp_path):
    run = tmp_path / "run"
    (run / C.AUTO_MASKS_DIR).mkdir(parents=True)
    (run / C.AUTO_MASKS_DIR / "00000.png").write_bytes(b"an artist's fix")
    with pytest.raises(UserError, match="needs at least two frames"):
        MasksJob("py", str(run), "/plate", 3, 3)
    job = MasksJob("py", str(run), "/plate", 0, 5)
    assert job.out_dir == str(run / C.AUTO_MASKS_DIR) + "_2" and job.created
    assert job.commands[0].argv[-4:] == ["--out", job.out_dir, "--frames", "0:5"]
    assert job.status_text() == "finding what moves…"
    # what the engine's stdout left in the log: the last masks event wins
    events = [progress_line(C.EVENT_MASKS, found=True, message="first"), "noise"]
    events.append(progress_line(C.EVENT_MASKS, found=False, message="no foreground found (static camera)"))
    (tmp_path / "run.masks.log").write_text("\n".join(events) + "\n")
    result = job.finish(EP.JobResult(EP.STATUS_OK, 0, "done", job.log_path))
    assert result.status == EP.STATUS_OK and job.found is False and job.summary.startswith("no foreground found")
    os.makedirs(job.out_dir)
    open(os.path.join(job.out_dir, "00000.png"), "wb").close()
    assert job.mask_files() == [os.path.join(job.out_dir, "00000.png")]
    job.discard()
    assert not os.path.exists(job.out_dir) and (run / C.AUTO_MASKS_DIR / "00000.png").exists()


def test_estimate_job_reads_the_rows_the_engine_printed(tmp_path):
    job = EstimateJob(fake_python(tmp_path), str(tmp_path / "run"), _clip(tmp_path), EC.set_args(768))
    statuses = _drive(job)
    assert job.result is not None and job.result.status == EP.STATUS_OK
    # its progress lines move the bar and the line (Estimate Time is modal, with Cancel, as Fit Atlas is)
    assert statuses[-1] == "timing the presets 1/1 · ETA 0s for the whole estimate" and job.fraction == 1.0
    assert job.rows == {"draft": {"seconds": 61.0, "psnr": 25.7}}
    logged = json.loads(Path(job.log_path).read_text().splitlines()[-2])
    assert logged["argv"][-1] == "--json" and C.SCRIBBLE_ARG not in logged["argv"]
    os.remove(job.log_path)  # an engine that printed nothing
    empty = job.finish(EP.JobResult(EP.STATUS_OK, 0, "done", job.log_path))
    assert job.rows == {} and empty.status == EP.STATUS_FAILED and "no estimate" in empty.message


def test_a_job_is_started_before_it_is_stepped(tmp_path):
    job = MasksJob("py", str(tmp_path / "run"), "/plate", 0, 5)
    with pytest.raises(AssertionError, match="start"):
        job.step()


def test_fit_job_bar_runs_on_through_the_export(tmp_path):
    """The fit command's whole-job fraction leaves the export's share; the export's frames fill it (the bar
    never drops back to 0 when the export starts). An engine without whole-job fractions: each command's own."""
    from types import SimpleNamespace

    from neural_atlas.addon.core.progress import JobState

    job = FitJob(fake_python(tmp_path), str(tmp_path / "run"), lambda: _clip(tmp_path), "draft", [])
    job.index, job.process = 0, SimpleNamespace(state=JobState(step=2000, total=2000, job_fraction=0.9, job_eta=20.0))
    assert job.fraction == 0.9
    job.fit_fraction = job.process.state.job_fraction  # what _run keeps when the export starts
    job.index = 1
    job.process = SimpleNamespace(state=JobState(job_stage="export", stage_done=3, stage_total=6, job_fraction=0.5,
                                                 job_eta=12.0))  # fmt: skip
    assert job.fraction == pytest.approx(0.95)
    assert job.status_text() == "exporting passes 3/6 · ETA 12s for the whole fit"
    job.fit_fraction = None
    job.process = SimpleNamespace(state=JobState(step=3, total=6))
    assert job.fraction == 0.5 and job.status_text() == "exporting passes 3/6"
