"""Refine's job (``core.jobs.RefineJob``) with a stand-in engine and no Blender: ``fit --refine`` of the finished
fit, its export, then ``realign`` into one log; the argv the engine gets; refusals before anything runs; and what
Fit Atlas says of a Run Folder holding a finished fit."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from helpers import fake_python
from neural_atlas.addon.core import engine_commands as EC
from neural_atlas.addon.core import engine_process as EP
from neural_atlas.addon.core import needs
from neural_atlas.addon.core.errors import UserError
from neural_atlas.addon.core.jobs import FitJob, RefineJob
from neural_atlas.addon.core.run_files import RunFiles

from engine import contract as C


def _finished_run(tmp_path: Path) -> str:
    run = tmp_path / "run"
    run.mkdir()
    (run / C.RUN_CHECKPOINT).write_text("fake")
    (run / C.RUN_METRICS).write_text("{}")
    return str(run)


def test_refine_argv_names_the_steps_and_the_preset():
    base = ["py", "-m", C.CLI_MODULE, C.VERB_FIT, "--out", "/r", C.FIT_REFINE_FLAG]
    assert EC.refine_argv("py", "/r", 1500) == [*base, "1500", EC.NO_BAR_FLAG]
    assert EC.refine_argv("py", "/r", 0, "balanced") == [*base, "--preset", "balanced", EC.NO_BAR_FLAG]
    assert EC.refine_argv("py", "/r", 200, "final") == [*base, "200", "--preset", "final", EC.NO_BAR_FLAG]
    assert EC.realign_argv("py", "/r") == ["py", "-m", C.CLI_MODULE, C.VERB_REALIGN, "/r"]


def test_refine_job_refines_exports_then_realigns_into_one_log(tmp_path):
    run = _finished_run(tmp_path)
    log = Path(RunFiles(run).fit_log)
    log.write_text("the fit's own lines\n")
    job = RefineJob(fake_python(tmp_path), run, 300, "balanced")
    assert [c.label for c in job.commands] == ["fit", "export", "realign"]
    assert job.commands[0].argv[3:] == [C.VERB_FIT, "--out", run, C.FIT_REFINE_FLAG, "300", "--preset", "balanced",
                                        EC.NO_BAR_FLAG]  # fmt: skip
    assert job.commands[1].argv[3:] == [C.VERB_EXPORT, run]  # the export's default: the UV follows the flow
    off = RefineJob(fake_python(tmp_path), run, 300, "balanced", follow_flow=False)
    assert off.commands[1].argv[3:] == [C.VERB_EXPORT, run, C.EXPORT_NO_FOLLOW_FLOW_FLAG]
    job.start()
    for _ in range(2000):
        if not job.step():
            break
        time.sleep(0.01)
    assert job.result is not None and job.result.status == EP.STATUS_OK, job.result
    assert job.manifest is not None and job.manifest.endswith(C.MANIFEST_NAME) and Path(job.manifest).is_file()
    assert (Path(run) / "fake_realign_argv.txt").read_text().split("\n") == [C.VERB_REALIGN, run]
    assert log.read_text().startswith("the fit's own lines\n")  # a refine continues the fit's log
    assert job.label == "realign" and job.status_text() == "carrying the paint over to the refined fit…"


def test_refine_is_refused_before_anything_runs(tmp_path):
    py = fake_python(tmp_path)
    with pytest.raises(UserError, match="no finished fit to refine"):
        RefineJob(py, str(tmp_path / "empty"), 100)
    run = tmp_path / "unfinished"
    run.mkdir()
    (run / C.RUN_CHECKPOINT).write_text("fake")
    with pytest.raises(UserError, match="no finished fit to refine"):
        RefineJob(py, str(run), 100)
    with pytest.raises(UserError, match="number of steps, or a preset"):
        RefineJob(py, _finished_run(tmp_path), 0)


def test_fit_atlas_on_a_finished_fit_says_refine_it(tmp_path):
    run = _finished_run(tmp_path)
    with pytest.raises(UserError, match="already holds a fit: Refine it"):
        FitJob(fake_python(tmp_path), run, lambda: EC.ClipInputs("p", (), 0, 1), "draft", [])
    assert needs.refine_need(False, True) is None
    assert needs.refine_need(False, False) == needs.NO_FINISHED_FIT
    assert needs.refine_need(True, True) is not None
