"""Hostile names and layouts for the farm: braces that OpenJD or Flamenco would expand, shell metacharacters,
newlines, non-UTF-8 bytes, folders that overlap, a deeply nested file. Each case is one line and exit 2, or a
bundle / plan / job whose commands are exactly the plan's, byte for byte; nothing outside the run and output
folders changes."""

from __future__ import annotations

import json
import os
import shlex
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from engine import contract as C
from engine.errors import InputError
from engine.farm import dask_backend, flamenco, openjd
from engine.farm.openjd import MAX_STEP_TASKS
from engine.farm.plan import load_plan, task_graph_text
from engine.farm.shots import load_shots
from engine.terms.farm import FARM_DASK, FARM_PLAN
from tests.engine_cli import run_cli
from tests.farm.farm_helpers import TINY_SET, openjd_commands, write_clip, write_shots
from tests.folders import non_utf8_folder, tree_digest

OPENJD = Path(sys.executable).parent / "openjd"
#: What OpenJD would have evaluated: the worker got this parameter's value instead of the file's name.
EXPANDED = "{{Param.EnginePython}}"
#: Name parts a studio's folders really have, and the ones that break a template or a shell.
HOSTILE = ["br[a]ck", "cur{ly}", EXPANDED, "{{Task.Param.Frames}}", "$HOME", 'q"uote', "back\\slash", "new\nline",
           "#hash", "%04d", "sp ace", "semi;colon", "tick'", "é"]  # fmt: skip


def _check(template: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(OPENJD), "check", str(template)], capture_output=True, text=True, timeout=60)


def _one_line_exit_2(*args: str | os.PathLike[str]) -> str:
    code, err = run_cli(*args)
    assert code == C.EXIT_BAD_INPUT and len(err) == 1, (code, err)
    return err[0]


def _plate(root: Path, name: str, pattern_prefix: str = "") -> Path:
    """A tiny clip's frames copied into ``root/name`` (with ``pattern_prefix`` before each frame number)."""
    frames, _masks = write_clip(root / ".clip")
    folder = root / name
    folder.mkdir(parents=True, exist_ok=True)
    for frame in sorted(frames.iterdir()):
        shutil.copy(frame, folder / f"{pattern_prefix}{frame.name}")
    return folder


# --- OpenJD: literals are never evaluated, every bundle passes openjd check -------------------------------------

needs_openjd = pytest.mark.skipif(not OPENJD.exists(), reason="openjd-cli is not installed (the farm extra)")


@needs_openjd
def test_a_plate_pattern_named_like_an_openjd_expression_reaches_the_worker_as_it_is(tmp_path):
    _plate(tmp_path, "plates", pattern_prefix=f"{EXPANDED}.")
    shots = write_shots(tmp_path, [{"name": "p", "plate": f"plates/{EXPANDED}.#####.png", "export_chunk": 2}],
                        {"preset": "draft", "set": TINY_SET})  # fmt: skip
    bundle = tmp_path / "bundle"
    code, err = run_cli(C.VERB_FARM, C.FARM_OPENJD, shots, "--out", bundle, "--engine-python", "/opt/py")
    assert code == C.EXIT_OK, err
    assert _check(bundle / "template.json").returncode == 0
    plan = load_plan(shots)
    assert openjd_commands(bundle) == [(f"{t.shot}-{t.kind}", t.argv("/opt/py")) for t in plan.tasks]
    fit = next(s for s in json.loads((bundle / "template.json").read_text())["steps"] if s["name"] == "p-fit")
    assert fit["script"]["actions"]["onRun"]["args"][3] == "{{Param.Plate_p}}/{{Param.Text1}}"
    values = json.loads((bundle / "job_parameters.json").read_text(encoding="utf-8"))
    assert values["Text1"] == f"{EXPANDED}.#####.png"


@needs_openjd
@pytest.mark.parametrize(
    ("name", "says"),
    [("seq {{Param.Missing}}", None), ("seq\nline", "holds a control character"), ("tab\there", "control character")],
)
def test_a_job_name_is_carried_as_it_is_or_refused_in_one_line(tmp_path, name, says):
    write_clip(tmp_path / "c")
    shots = write_shots(tmp_path, [{"name": "a", "plate": "c/frames"}])
    bundle = tmp_path / "bundle"
    if says is None:
        assert run_cli(C.VERB_FARM, C.FARM_OPENJD, shots, "--out", bundle, "--name", name)[0] == C.EXIT_OK
        assert _check(bundle / "template.json").returncode == 0
        template = json.loads((bundle / "template.json").read_text(encoding="utf-8"))
        values = json.loads((bundle / "job_parameters.json").read_text(encoding="utf-8"))
        assert values[template["name"][len("{{Param.") : -2]] == name
    else:
        assert says in _one_line_exit_2(C.VERB_FARM, C.FARM_OPENJD, shots, "--out", bundle, "--name", name)
        assert not bundle.exists()


@needs_openjd
def test_more_chunks_than_an_openjd_step_takes_is_one_line_naming_the_chunk_size(tmp_path):
    frames, _ = write_clip(tmp_path / "c")
    first = sorted(frames.iterdir())[0]
    many = tmp_path / "many"
    many.mkdir()
    for n in range(MAX_STEP_TASKS + 1):  # the plan lists the frames; it never decodes them
        shutil.copy(first, many / f"{n:05d}.png")
    shots = write_shots(tmp_path, [{"name": "long", "plate": "many", "export_chunk": 1}])
    line = _one_line_exit_2(C.VERB_FARM, C.FARM_OPENJD, shots, "--out", tmp_path / "bundle")
    assert line.endswith(
        f"shot long: {MAX_STEP_TASKS + 1} passes chunks, more than the {MAX_STEP_TASKS} tasks OpenJD takes in a step "
        "— give the shot export_chunk = 2 or more"
    )
    assert not (tmp_path / "bundle").exists()


@needs_openjd
def test_openjd_run_of_a_hostile_shot_passes_every_argument_byte_exact_and_runs_nothing_else(tmp_path):
    """A stub engine records its argv: every task's arguments arrive as the plan has them, no shell expands
    ``$HOME``, quotes or newlines, and no file outside the run and render folders appears or changes."""
    name = "".join(HOSTILE)
    _plate(tmp_path, name)
    shots = write_shots(tmp_path, [{"name": "h", "plate": name, "render": f"r {name}", "export_chunk": 2,
                                    "render_chunk": 3}], {"preset": "draft", "set": TINY_SET})  # fmt: skip
    record = tmp_path / "argv.jsonl"
    stub = tmp_path / "stub_engine.py"
    stub.write_text(
        f"#!{sys.executable}\nimport json, os, sys\n"
        f"with open({str(record)!r}, 'a') as f:\n"
        "    f.write(json.dumps([os.fsencode(a).hex() for a in sys.argv[1:]]) + '\\n')\n",
        encoding="utf-8",
    )
    stub.chmod(0o755)
    bundle = tmp_path / "bundle"
    assert run_cli(C.VERB_FARM, C.FARM_OPENJD, shots, "--out", bundle, "--engine-python", str(stub))[0] == C.EXIT_OK
    assert _check(bundle / "template.json").returncode == 0
    before = {k: v for k, v in tree_digest(tmp_path).items() if not k.startswith("bundle")}
    proc = subprocess.run(
        [str(OPENJD), "run", str(bundle / "template.json"), "-p", f"file://{bundle / 'job_parameters.json'}",
         "--step", "h-render", "--run-dependencies"],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    got = [[bytes.fromhex(a) for a in json.loads(line)] for line in record.read_text().splitlines()]
    plan = load_plan(shots)
    want = [[os.fsencode(a) for a in t.argv(str(stub))[1:]] for t in plan.tasks if t.kind != "preview"]
    # the job environment's onEnter runs the engine's Python once, to put EnginePath in front of PYTHONPATH
    engine_path = json.loads((bundle / openjd.JOB_PARAMETERS_FILE).read_text(encoding="utf-8"))[
        openjd.ENGINE_PATH_PARAMETER
    ]
    assert got[0] == [b"-c", openjd.PREPEND_PYTHONPATH.encode(), os.fsencode(engine_path)]
    assert got[1:] == want
    after = {k: v for k, v in tree_digest(tmp_path).items() if not k.startswith("bundle") and k != record.name}
    assert after == before


@needs_openjd
@pytest.mark.parametrize("part", HOSTILE)
def test_every_hostile_name_gives_a_checked_bundle_the_plans_commands_and_flamencos(tmp_path, part):
    _plate(tmp_path, f"plate {part}")
    (tmp_path / f"masks {part}").mkdir()
    shutil.copytree(tmp_path / ".clip" / "masks", tmp_path / f"masks {part}", dirs_exist_ok=True)
    shots = write_shots(tmp_path, [{"name": "h", "plate": f"plate {part}", "masks": [f"masks {part}"],
                                    "render": f"render {part}", "run": f"run {part}"}])  # fmt: skip
    before = tree_digest(tmp_path)
    bundle = tmp_path / "bundle"
    assert run_cli(C.VERB_FARM, C.FARM_OPENJD, shots, "--out", bundle, "--engine-python", "/opt/py")[0] == C.EXIT_OK
    checked = _check(bundle / "template.json")
    assert checked.returncode == 0, checked.stdout + checked.stderr
    plan = load_plan(shots)
    assert [argv for _, argv in openjd_commands(bundle)] == [t.argv("/opt/py") for t in plan.tasks]
    # farm plan prints what a shell runs: each command line splits back into the plan's argv
    lines = task_graph_text(plan).split("\n      ")[1:]
    assert [shlex.split(line.split("\n  ")[0]) for line in lines] == [t.argv("python") for t in plan.tasks]
    if "{" in part and "}" in part:
        with pytest.raises(InputError, match=r"which a Flamenco Manager replaces with its variable"):
            flamenco.submitted_job("h", plan.shot_tasks("h"), platform="linux")
    else:
        job = flamenco.submitted_job("h", plan.shot_tasks("h"), platform="linux")
        sent = json.loads(job["settings"]["plan"])["tasks"]
        assert [task["args"] for task in sent] == [list(t.args) for t in plan.tasks]
    assert {k: v for k, v in tree_digest(tmp_path).items() if not k.startswith("bundle")} == before


def test_a_name_that_is_not_utf8_is_refused_in_one_line(tmp_path):
    folder = non_utf8_folder(tmp_path, b"plate\xff")
    _plate(tmp_path, folder.name)
    shots = tmp_path / "shots.json"
    shots.write_text(json.dumps({C.SHOTS_TAG: 1, "shots": [{"name": "u", "plate": folder.name}]}))
    line = _one_line_exit_2(C.VERB_FARM, FARM_PLAN, shots)
    assert "shot 'u': 'plate' " in line and "plate\\xff is not UTF-8 text" in line


# --- Flamenco -------------------------------------------------------------------------------------------------


def test_flamenco_path_mapping_is_case_sensitive_on_linux_only():
    two_way = {"shared": "/mnt/shots"}
    assert flamenco.to_variables("/mnt/Shots/a.exr", two_way, "linux") == "/mnt/Shots/a.exr"
    assert flamenco.to_variables("/mnt/shots/a.exr", two_way, "linux") == "{shared}/a.exr"
    assert flamenco.to_variables("/mnt/Shots/a.exr", two_way, "darwin") == "{shared}/a.exr"
    assert flamenco.to_variables("C:/Shots/a.exr", {"shared": "c:\\shots"}, "windows") == "{shared}/a.exr"


def test_a_flamenco_variable_reference_in_a_path_is_refused_before_the_manager_is_asked(tmp_path):
    _plate(tmp_path, "{storage}")
    plan = load_plan(write_shots(tmp_path, [{"name": "f", "plate": "{storage}"}]))
    with pytest.raises(InputError) as info:
        flamenco.submit_plan(plan, "http://127.0.0.1:9", timeout=0.5)  # nothing listens there: no request is made
    assert "holds {storage}, which a Flamenco Manager replaces with its variable" in str(info.value)


# --- the shots file: overlapping folders, what the workers would refuse, nesting ---------------------------------


@pytest.fixture
def two_plates(tmp_path) -> Path:
    for shot in ("a", "b"):
        _plate(tmp_path, f"plates/{shot}")
    shutil.copytree(tmp_path / ".clip" / "masks", tmp_path / "masks" / "a")
    return tmp_path


@pytest.mark.parametrize(
    ("shots", "says"),
    [
        ([{"name": "a", "plate": "plates/a", "render": "plates/b"}, {"name": "b", "plate": "plates/b"}],
         "shot 'a': the 'render' folder {T}/plates/b is shot 'b''s 'plate' {T}/plates/b"),
        ([{"name": "a", "plate": "plates/a", "run": "plates/a/run"}],
         "shot 'a': the 'run' folder {T}/plates/a/run is inside its own 'plate' {T}/plates/a"),
        ([{"name": "a", "plate": "plates/a", "masks": ["masks/a"], "run": "masks"}],
         "shot 'a': the 'run' folder {T}/masks holds its own 'masks' folder 1 {T}/masks/a"),
        ([{"name": "a", "plate": "plates/a", "run": "runs/a"}, {"name": "b", "plate": "plates/b", "run": "runs/a/b"}],
         "shot 'a': the 'run' folder {T}/runs/a holds shot 'b''s 'run' folder {T}/runs/a/b"),
        ([{"name": "a", "plate": "plates/a", "run": "link/a"}],
         "shot 'a': the 'run' folder {T}/link/a is inside its own 'plate' {T}/plates/a (through links: "
         "{T}/plates/a/a and {T}/plates/a)"),
        ([{"name": "a", "plate": "plates/a", "device": "cuda:1"}], "shot 'a': 'device' is 'cuda:1'"),
        ([{"name": "a", "plate": "plates/a", "atlas_size": 4}], "shot 'a': 'atlas_size' is 4 — give atlas_size a"),
        ([{"name": "a", "plate": "plates/a", "atlas_size": 20000}], "'atlas_size' is 20000 — give atlas_size 8..16384"),
        ([{"name": "a", "plate": "plates/a", "colorspace": "ACEScgg"}], "shot 'a': 'colorspace' ACEScgg: "),
        ([{"name": "a", "plate": "plates/a", "fps": 1e-9}], "'1e-09' is not a number or fraction of 1 to 1000"),
        ([{"name": "a", "plate": "plates/a", "masks": ["masks/a"], "auto_parts": True, "set": ["model=paper"]}],
         "shot 'a': 'auto_parts' with the paper model"),
        ([{"name": "a", "plate": "plates/a", "start_frame": 2000000}], "shot 'a': 'start_frame'"),
    ],
)  # fmt: skip
def test_what_the_farm_would_break_or_refuse_is_refused_at_plan_time(two_plates, shots, says):
    (two_plates / "link").symlink_to(two_plates / "plates" / "a")
    path = write_shots(two_plates, shots)
    before = tree_digest(two_plates)
    line = _one_line_exit_2(C.VERB_FARM, FARM_PLAN, path)
    assert says.replace("{T}", str(two_plates)) in line
    assert tree_digest(two_plates) == before


def test_folders_side_by_side_are_accepted(two_plates):
    shots = write_shots(two_plates, [
        {"name": "a", "plate": "plates/a", "masks": ["masks/a"], "render": "renders/a"},
        {"name": "b", "plate": "plates/b", "render": "renders/b", "colorspace": "sRGB", "device": "cuda",
         "atlas_size": 8, "fps": "24000/1001"},
    ])  # fmt: skip
    assert [s.run for s in load_shots(shots).shots] == [str(two_plates / "runs" / "a"), str(two_plates / "runs" / "b")]


@pytest.mark.parametrize("kind", ["json", "toml"])
def test_a_deeply_nested_shots_file_is_one_line(tmp_path, kind):
    depth = 100_000
    path = tmp_path / f"deep.{kind}"
    if kind == "json":
        path.write_text(f'{{"{C.SHOTS_TAG}": 1, "shots": ' + "[" * depth + "]" * depth + "}")
    else:
        path.write_text(f"{C.SHOTS_TAG} = 1\nshots = " + "[" * depth + "]" * depth + "\n")
    line = _one_line_exit_2(C.VERB_FARM, FARM_PLAN, path)
    assert line == (
        f"error: {path}: nests lists or tables too deeply to be a shots file — write {C.SHOTS_TAG}, a [defaults] "
        "table and one table per shot (docs/farm.md)"
    )


def test_farm_plan_prints_each_command_as_a_shell_runs_it(tmp_path):
    _plate(tmp_path, "my plate $X")
    plan = load_plan(write_shots(tmp_path, [{"name": "s", "plate": "my plate $X", "preview": False}]))
    code, _err = run_cli(C.VERB_FARM, FARM_PLAN, tmp_path / "shots.json")
    assert code == C.EXIT_OK
    fit_line = task_graph_text(plan).splitlines()[2].strip()
    assert fit_line.startswith(f"python -m engine fit '{tmp_path}/my plate $X' --out {tmp_path}/runs/s ")
    assert shlex.split(fit_line) == plan.task("s.fit").argv("python")


# --- Dask: a scheduler that cannot import the engine ---------------------------------------------------------------


def test_a_task_dask_could_not_read_is_its_own_failure_with_the_whole_message_and_the_fix():
    cause = ModuleNotFoundError("No module named 'engine'")
    error = RuntimeError("Error during deserialization of the task graph. This frequently\noccurs if the Scheduler "
                         "and Client have different environments.")  # fmt: skip
    error.__cause__ = cause
    root = dask_backend._failure("a.fit", "key", error, dependencies_done=True)
    assert root["state"] == "failed"
    assert root["error"].startswith(
        "RuntimeError: Error during deserialization of the task graph. This frequently occurs if the Scheduler and "
        "Client have different environments.; caused by ModuleNotFoundError: No module named 'engine' — install the "
        "engine into the Python of the Dask scheduler and of every worker"
    )
    assert dask_backend._failure("a.atlases", "key2", error, dependencies_done=False)["state"] == "skipped"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the processes are stopped by PID on Linux")
def test_farm_dask_against_a_scheduler_without_the_engine_is_one_line_naming_it_and_the_fix(tmp_path):
    _plate(tmp_path, "p")
    shots = write_shots(tmp_path, [{"name": "d", "plate": "p"}])
    port = _free_port()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}  # its Python has no engine on its path
    dask = str(Path(sys.executable).parent / "dask")
    argv = [dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"]
    scheduler = subprocess.Popen(argv, cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        address = f"tcp://127.0.0.1:{port}"
        before = tree_digest(tmp_path)
        line = _one_line_exit_2(C.VERB_FARM, FARM_DASK, shots, "--scheduler", address, "--connect-timeout", "30")
        assert line == (
            f"error: {address}: the Dask scheduler cannot import the engine (ModuleNotFoundError: No module named "
            f"'engine') — {dask_backend.ENGINE_IMPORT_FIX}"
        )
        assert tree_digest(tmp_path) == before
    finally:
        scheduler.terminate()
        scheduler.wait(30)


def _free_port() -> int:
    """A free TCP port on 127.0.0.1 (closed again before the scheduler takes it)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
