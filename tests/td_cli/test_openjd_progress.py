"""Deadline Cloud's view of a bundle's tasks: each task prints ``openjd_progress`` and ``openjd_status`` messages
(the Open Job Description stdout protocol), the job environment puts the engine IN FRONT of the worker's
PYTHONPATH instead of replacing it, and the run folder, which the fit writes and every later step reads, is
``dataFlow: INOUT``."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from engine import contract as C
from engine.farm import openjd
from engine.fit.progress import OpenJDProgress
from engine.terms.protocol import OPENJD_PROGRESS_ENV, progress_line
from tests.farm.farm_helpers import TINY_SET, write_clip, write_shots
from tests.paths import ROOT
from tests.td_cli.conftest import run_main

OPENJD = Path(sys.executable).parent / "openjd"
TIMEOUT = 300


def _bundle(tmp: Path) -> Path:
    write_clip(tmp / "clip")
    shot = {"name": "sh010", "plate": "clip/frames", "masks": ["clip/masks"]}
    defaults = {"preset": "draft", "set": TINY_SET, "preview": False}
    shots = write_shots(tmp, [shot], defaults)
    ran = run_main("farm", "openjd", shots, "--out", tmp / "bundle", "--engine-python", sys.executable,
                   "--engine-path", ROOT)  # fmt: skip
    assert ran.code == C.EXIT_OK, ran.err
    return tmp / "bundle"


def test_progress_lines_follow_the_job_fraction_and_stages_become_status() -> None:
    said = OpenJDProgress()
    lines = [
        progress_line(C.EVENT_STAGE, stage="flow", message="optical flow\n(cached)"),
        progress_line(C.EVENT_JOB, stage="flow", done=1, total=4, stage_eta=None, job_fraction=0.0125, job_eta=None),
        progress_line(C.EVENT_JOB, stage="flow", done=2, total=4, stage_eta=None, job_fraction=0.0125, job_eta=None),
        progress_line(C.EVENT_PROGRESS, step=3, total=4),  # a fraction was seen: its own steps say nothing
        "a line of something else",
        progress_line(C.EVENT_DONE, metrics={}, job_fraction=1.0, job_eta=0.0),
    ]
    out = "".join(said(line + "\n") for line in lines).splitlines()
    assert [line for line in out if line.startswith("openjd_")] == [
        "openjd_status: optical flow (cached)",
        "openjd_progress: 1.2",
        "openjd_progress: 100.0",
    ]
    assert [line for line in out if not line.startswith("openjd_")] == lines  # stdout itself unchanged


def test_a_command_without_fractions_reports_its_own_steps() -> None:
    said = OpenJDProgress()
    out = said(progress_line(C.EVENT_PROGRESS, step=1, total=3) + "\n")
    assert out.splitlines()[1:] == ["openjd_progress: 33.3"]


def test_a_verb_in_an_openjd_task_ends_at_100(tmp_path, monkeypatch) -> None:
    """Before: nothing but the JSON lines, which no OpenJD runner reads."""
    monkeypatch.setenv(OPENJD_PROGRESS_ENV, "1")
    frames, _ = write_clip(tmp_path / "clip")
    ran = run_main("masks", frames, "--out", tmp_path / "found")
    assert ran.code == C.EXIT_OK, ran.err
    lines = ran.out.splitlines()
    assert lines[-1] == "openjd_progress: 100.0" and lines[-2] == str((tmp_path / "found").resolve())
    assert any(line.startswith("openjd_status: ") for line in lines)
    monkeypatch.delenv(OPENJD_PROGRESS_ENV)
    plain = run_main("masks", frames, "--out", tmp_path / "found")  # the same, outside a task: no OpenJD lines
    assert plain.code == C.EXIT_OK and not [line for line in plain.out.splitlines() if line.startswith("openjd_")]


def test_the_environment_prepends_the_engine_to_pythonpath(tmp_path) -> None:
    """Before: ``variables: {PYTHONPATH: EnginePath}`` replaced the worker's own Python path."""
    template = json.loads((_bundle(tmp_path) / "template.json").read_text(encoding="utf-8"))
    (environment,) = template["jobEnvironments"]
    assert environment["variables"] == {OPENJD_PROGRESS_ENV: "1"}
    action = environment["script"]["actions"]["onEnter"]
    assert action["command"] == "{{Param.EnginePython}}" and action["args"][-1] == "{{Param.EnginePath}}"
    run = [sys.executable, *action["args"][:-1]]
    env = {**os.environ, "PYTHONPATH": "/studio/lib"}
    said = subprocess.run([*run, "/farm/engine"], capture_output=True, text=True, env=env, check=True).stdout
    assert said == f"openjd_env: PYTHONPATH=/farm/engine{os.pathsep}/studio/lib\n"
    env.pop("PYTHONPATH")
    assert subprocess.run([*run, "/farm/engine"], capture_output=True, text=True, env=env).stdout == (
        "openjd_env: PYTHONPATH=/farm/engine\n"
    )
    assert subprocess.run([*run, ""], capture_output=True, text=True, env=env).stdout == ""  # installed engine


def test_the_run_folder_is_in_and_out(tmp_path) -> None:
    bundle = _bundle(tmp_path)
    template = json.loads((bundle / "template.json").read_text(encoding="utf-8"))
    flows = {p["name"]: p.get("dataFlow") for p in template["parameterDefinitions"]}
    assert (flows["Plate_sh010"], flows["Mask1_sh010"], flows["Run_sh010"]) == ("IN", "IN", "INOUT")
    refs = json.loads((bundle / openjd.ASSET_REFERENCES_FILE).read_text(encoding="utf-8"))["assetReferences"]
    assert refs["outputs"]["directories"] == [str(tmp_path / "runs" / "sh010")]
    assert str(tmp_path / "runs" / "sh010") not in refs["inputs"]["directories"]  # not there yet: nothing to upload
    (tmp_path / "runs" / "sh010").mkdir(parents=True)  # a fit to continue: its folder goes up with the job
    _bundle_again = run_main("farm", "openjd", tmp_path / "shots.json", "--out", tmp_path / "b2")
    assert _bundle_again.code == C.EXIT_OK
    refs = json.loads((tmp_path / "b2" / openjd.ASSET_REFERENCES_FILE).read_text(encoding="utf-8"))["assetReferences"]
    assert str(tmp_path / "runs" / "sh010") in refs["inputs"]["directories"]


@pytest.mark.slow
@pytest.mark.skipif(not OPENJD.exists(), reason="openjd-cli is not installed (the farm extra)")
def test_openjd_run_of_the_fit_step_reports_progress_with_the_workers_path_kept(tmp_path) -> None:
    """The worker's PYTHONPATH holds a sitecustomize that notes the path it ran with: it runs in the task only if the
    job environment kept the worker's path (behind the engine's)."""
    bundle = _bundle(tmp_path)
    site = tmp_path / "site"
    site.mkdir()
    seen = tmp_path / "seen_path.txt"
    (site / "sitecustomize.py").write_text(
        "import os\nif 'NEURAL_ATLAS_SEEN' in os.environ:\n"
        "    open(os.environ['NEURAL_ATLAS_SEEN'], 'a').write(os.environ.get('PYTHONPATH', '') + '\\n')\n",
        encoding="utf-8",
    )
    env = {**os.environ, "PYTHONPATH": str(site), "NEURAL_ATLAS_SEEN": str(seen), "OMP_NUM_THREADS": "1"}
    argv = [str(OPENJD), "run", str(bundle / "template.json"), "-p", f"file://{bundle / 'job_parameters.json'}",
            "--step", "sh010-fit", "--no-run-dependencies"]  # fmt: skip
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=TIMEOUT, cwd=tmp_path, env=env)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    progress = [float(v) for v in re.findall(r"openjd_progress: ([\d.]+)", proc.stdout)]
    assert len(progress) >= 3 and progress == sorted(progress) and progress[-1] == 100.0
    assert "openjd_status: optical flow (cached per clip content)" in proc.stdout
    assert f"{ROOT}{os.pathsep}{site}" in seen.read_text(encoding="utf-8").splitlines()
