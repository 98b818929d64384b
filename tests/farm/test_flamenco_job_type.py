"""Contract test of the Flamenco job type (engine/farm/flamenco/neural-atlas.js).

Flamenco is on no package registry, so the job compiler runs under Node against a stub of the Manager's
documented job compiler API (``flamenco_author_stub.js``: author.Task, author.Command, addCommand, addDependency,
job.addTask, job.settings). The compiled tasks' command lines, with the Manager variable replaced by a Python,
must be the plan's ``[python, -m, engine, *args]`` and their dependencies the plan's.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest

from engine import contract as C
from engine.farm import flamenco
from engine.farm.plan import TASK_KINDS
from engine.terms.farm import FLAMENCO_JOB_TYPE, FLAMENCO_PYTHON_VARIABLE
from tests.farm.flamenco_helpers import NODE, compile_job, two_shot_plan

pytestmark = pytest.mark.skipif(NODE is None, reason="node (v20) is not on PATH")

PYTHON = "/opt/neural-atlas/.venv/bin/python"
VARIABLE = "{" + FLAMENCO_PYTHON_VARIABLE + "}"
SCRIPT = Path(__file__).resolve().parents[2] / "engine" / "farm" / "flamenco" / flamenco.JOB_TYPE_SCRIPT


def _argv(command: dict[str, Any]) -> list[str]:
    params = command["parameters"]
    return [params["exe"].replace(VARIABLE, PYTHON), *params["args"]]


def test_compiled_tasks_run_the_plans_command_lines(tmp_path: Path) -> None:
    plan = two_shot_plan(tmp_path)
    for shot in plan.shots:
        tasks = plan.shot_tasks(shot)
        code, compiled, stderr = compile_job(flamenco.submitted_job(shot, tasks, platform="linux"))
        assert code == 0, stderr
        assert compiled is not None
        got = compiled["tasks"]
        assert [t["name"] for t in got] == [t.id for t in tasks]
        for task, authored in zip(tasks, got, strict=True):
            assert len(authored["commands"]) == 1
            command = authored["commands"][0]
            assert command["name"] == "exec"
            assert command["parameters"]["exe"] == VARIABLE
            assert _argv(command) == [PYTHON, "-m", C.CLI_MODULE, *task.args]
            assert authored["dependencies"] == list(task.depends)
            assert authored["type"] == (flamenco.TASK_TYPE_GPU if task.accelerator else flamenco.TASK_TYPE)
    # the fit and the passes chunks go to GPU workers, the rest anywhere
    types = {t.kind: flamenco.TASK_TYPE_GPU if t.accelerator else flamenco.TASK_TYPE for t in plan.tasks}
    assert types["fit"] == types["passes"] == flamenco.TASK_TYPE_GPU
    assert types["render"] == types["preview"] == flamenco.TASK_TYPE


def test_job_type_declares_the_settings_and_names_the_python_agree_on(tmp_path: Path) -> None:
    plan = two_shot_plan(tmp_path)
    code, compiled, stderr = compile_job(flamenco.submitted_job("sh010", plan.shot_tasks("sh010")))
    assert code == 0, stderr
    assert compiled is not None
    settings = {s["key"]: s for s in compiled["job_type"]["settings"]}
    assert set(settings) == {flamenco.PLAN_SETTING, flamenco.SHOT_SETTING}
    assert all(s["required"] and s["type"] == "string" for s in settings.values())
    text = SCRIPT.read_text(encoding="utf-8")

    def const(name: str) -> Any:
        found = re.search(rf"^const {name} = (.+);$", text, re.MULTILINE)
        assert found, name
        return json.loads(found.group(1))

    assert const("PLAN_TAG") == flamenco.PLAN_TAG
    assert const("PLAN_VERSION") == flamenco.PLAN_VERSION
    assert const("PYTHON_EXE") == VARIABLE
    assert const("TASK_TYPE") == flamenco.TASK_TYPE
    assert const("TASK_TYPE_GPU") == flamenco.TASK_TYPE_GPU
    assert const("TASK_KINDS") == list(TASK_KINDS)
    # Flamenco names a job type after its script's file
    assert SCRIPT.stem.replace("_", "-") == FLAMENCO_JOB_TYPE


def _plan_json(tmp_path: Path) -> dict[str, Any]:
    plan = two_shot_plan(tmp_path)
    return json.loads(flamenco.plan_setting("sh010", plan.shot_tasks("sh010")))


BAD_PLANS = {
    "not JSON": (lambda p: "{not json", "is not JSON"),
    "other tag": (lambda p: {**p, flamenco.PLAN_TAG: 99}, "version 1 plan"),
    "other shot": (lambda p: {**p, "shot": "sh999"}, "the plan is for shot"),
    "no tasks": (lambda p: {**p, "tasks": []}, "has no tasks"),
    "unknown kind": (lambda p: {**p, "tasks": [{**p["tasks"][0], "kind": "bake"}]}, "unknown kind"),
    "empty args": (lambda p: {**p, "tasks": [{**p["tasks"][0], "args": []}]}, "args must be"),
    "args not strings": (lambda p: {**p, "tasks": [{**p["tasks"][0], "args": ["fit", 3]}]}, "args must be"),
    "unknown dependency": (
        lambda p: {**p, "tasks": [{**p["tasks"][0], "depends": ["sh010.nothing"]}]},
        'depends on "sh010.nothing"',
    ),
    "later dependency": (lambda p: {**p, "tasks": list(reversed(p["tasks"]))}, "not an earlier task"),
    "id twice": (lambda p: {**p, "tasks": [p["tasks"][0], p["tasks"][0]]}, "is used twice"),
    "accelerator missing": (
        lambda p: {**p, "tasks": [{k: v for k, v in p["tasks"][0].items() if k != "accelerator"}]},
        "accelerator must be",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_PLANS))
def test_a_bad_plan_setting_throws_one_line(tmp_path: Path, case: str) -> None:
    mutate, expected = BAD_PLANS[case]
    plan = mutate(_plan_json(tmp_path))
    job = flamenco.submitted_job("sh010", two_shot_plan(tmp_path).shot_tasks("sh010"))
    job["settings"]["plan"] = plan if isinstance(plan, str) else json.dumps(plan)
    code, compiled, stderr = compile_job(job)
    assert code == 3 and compiled is None
    lines = [line for line in stderr.splitlines() if not line.startswith("print:")]
    assert len(lines) == 1, stderr
    assert expected in lines[0]
    assert lines[0].startswith('neural-atlas job "sh010": ')
    assert "farm flamenco" in lines[0]  # the fix


def test_a_job_without_the_plan_setting_is_refused(tmp_path: Path) -> None:
    job = flamenco.submitted_job("sh010", two_shot_plan(tmp_path).shot_tasks("sh010"))
    del job["settings"]["plan"]
    code, compiled, stderr = compile_job(job)
    assert code == 3 and compiled is None
    assert "required setting plan" in stderr


def test_job_type_out_writes_the_packaged_script_which_compiles(tmp_path: Path) -> None:
    written = flamenco.write_job_type(tmp_path / "scripts")
    assert written == tmp_path / "scripts" / "neural-atlas.js"
    assert written.read_bytes() == SCRIPT.read_bytes()
    assert flamenco.job_type_script() == SCRIPT.read_text(encoding="utf-8")
    plan = two_shot_plan(tmp_path)
    code, compiled, stderr = compile_job(flamenco.submitted_job("sh020", plan.shot_tasks("sh020")), written)
    assert code == 0, stderr
    assert compiled is not None
    assert len(compiled["tasks"]) == len(plan.shot_tasks("sh020"))


def test_two_way_variables_map_path_arguments_and_expand_back(tmp_path: Path) -> None:
    """The submitter writes ``{storage}/...`` for paths under a two-way variable's submitter-platform value; the
    Manager expands it to a worker's value. Expanded with the same platform's value, the argv is the plan's."""
    root = tmp_path / "Studio"
    plan = two_shot_plan(root)
    two_way = {"storage": str(root).upper() + "/", "other": "/elsewhere"}  # macOS ignores case; trailing slash
    tasks = plan.shot_tasks("sh010")
    code, compiled, stderr = compile_job(flamenco.submitted_job("sh010", tasks, two_way=two_way, platform="darwin"))
    assert code == 0, stderr
    assert compiled is not None
    for task, authored in zip(tasks, compiled["tasks"], strict=True):
        argv = _argv(authored["commands"][0])
        mapped = [a for a in argv if a.startswith("{storage}")]
        assert mapped, argv  # every task has a path under the root
        assert not any(str(root) in a for a in argv)
        assert [a.replace("{storage}", str(root)) for a in argv] == [PYTHON, "-m", C.CLI_MODULE, *task.args]


def test_to_variables_matches_whole_components_and_windows_paths() -> None:
    two_way = {"storage": "F:\\flamenco", "deep": "/mnt/a/b", "a": "/mnt/a"}
    assert flamenco.to_variables("/mnt/a/b/c.exr", two_way) == "{deep}/c.exr"  # the longest value wins
    assert flamenco.to_variables("/mnt/a/x", two_way) == "{a}/x"
    assert flamenco.to_variables("/mnt/ab/x", two_way) == "/mnt/ab/x"  # not a path component
    assert flamenco.to_variables("f:/Flamenco/shots/p.exr", two_way, "windows") == "{storage}/shots/p.exr"
    assert flamenco.to_variables("F:\\flamenco\\shots", two_way) == "{storage}\\shots"
    assert flamenco.to_variables("--frames", two_way) == "--frames"
