"""Every back end runs the very same command lines: the plan's. One shots file of two shots (found masks, chunked
export and render) goes through the OpenJD bundle (its step commands with the job and task parameters
substituted), the Flamenco job type (compiled under Node against the stub of Flamenco's author API, the Manager
variable replaced) and the Dask back end (the argv a worker runs); the three lists of (task, argv) are equal, task
for task, to the plan's."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import pytest

from engine import contract as C
from engine.farm import dask_backend, flamenco
from engine.farm.plan import load_plan
from engine.terms.farm import FLAMENCO_PYTHON_VARIABLE
from tests.engine_cli import run_cli
from tests.farm.farm_helpers import openjd_commands
from tests.farm.flamenco_helpers import NODE, compile_job, write_shots
from tests.paths import ROOT

pytestmark = pytest.mark.skipif(NODE is None, reason="node (v20) is not on PATH")

PYTHON = sys.executable


def _openjd(shots: Path, bundle: Path) -> list[tuple[str, list[str]]]:
    code, err = run_cli(C.VERB_FARM, C.FARM_OPENJD, shots, "--out", bundle, "--engine-python", PYTHON,
                        "--engine-path", str(ROOT))  # fmt: skip
    assert code == C.EXIT_OK, err
    return openjd_commands(bundle)


def _flamenco(plan: Any) -> list[tuple[str, list[str]]]:
    variable = "{" + FLAMENCO_PYTHON_VARIABLE + "}"
    out = []
    for shot in plan.shots:
        code, compiled, stderr = compile_job(flamenco.submitted_job(shot, plan.shot_tasks(shot), platform="linux"))
        assert code == 0 and compiled is not None, stderr
        for task in compiled["tasks"]:
            (command,) = task["commands"]
            params = command["parameters"]
            out.append((task["name"], [params["exe"].replace(variable, PYTHON), *params["args"]]))
    return out


def test_openjd_flamenco_and_dask_run_the_plans_command_lines(tmp_path: Path) -> None:
    shots = write_shots(tmp_path)
    plan = load_plan(shots)
    want = [task.argv(PYTHON) for task in plan.tasks]
    assert {task.kind for task in plan.tasks} >= {"masks", "fit", "atlases", "passes", "publish", "render"}

    openjd = _openjd(shots, tmp_path / "bundle")
    assert [name for name, _ in openjd] == [f"{t.shot}-{t.kind}" for t in plan.tasks]
    flamenco_jobs = _flamenco(plan)
    assert [name for name, _ in flamenco_jobs] == [t.id for t in plan.tasks]
    dask = [dask_backend.engine_argv(task.args, PYTHON) for task in plan.tasks]

    assert [argv for _, argv in openjd] == want
    assert [argv for _, argv in flamenco_jobs] == want
    assert dask == want
