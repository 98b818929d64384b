"""``farm openjd``: the plan as an Open Job Description bundle, checked by ``openjd check``, its commands equal to
the plan's, and run for real by ``openjd run`` on a tiny shot: the export and the render chunks it makes equal a
direct fit + export + render."""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from engine import cli
from engine import contract as C
from engine.farm.plan import load_plan
from engine.terms.export_names import EDITS_DIR
from tests.engine_cli import run_cli
from tests.farm.farm_helpers import TINY_SET, openjd_commands, two_shot_file, write_clip, write_shots
from tests.folders import tree_digest, visible_names
from tests.paths import ROOT

OPENJD = Path(sys.executable).parent / "openjd"
TIMEOUT = 300
#: One thread for every fit here: the same seed and thread count give the same numbers.
THREADS_ENV = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

pytestmark = pytest.mark.skipif(not OPENJD.exists(), reason="openjd-cli is not installed (the farm extra)")


def _bundle(shots: Path, out: Path, *extra: str) -> dict:
    code, err = run_cli(C.VERB_FARM, C.FARM_OPENJD, shots, "--out", out, "--engine-python", sys.executable,
                        "--engine-path", str(ROOT), *extra)  # fmt: skip
    assert code == C.EXIT_OK, err
    return json.loads((out / "template.json").read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("seq")
    two_shot_file(folder)
    return folder


def test_openjd_check_passes(seq, tmp_path):
    _bundle(seq / "shots.json", tmp_path / "bundle")
    proc = subprocess.run([str(OPENJD), "check", str(tmp_path / "bundle" / "template.json")],
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "passes validation checks" in proc.stdout


def test_the_bundles_commands_with_parameters_substituted_are_the_plans(seq, tmp_path):
    template = _bundle(seq / "shots.json", tmp_path / "bundle")
    values = json.loads((tmp_path / "bundle" / "job_parameters.json").read_text(encoding="utf-8"))
    deadline = json.loads((tmp_path / "bundle" / "parameter_values.json").read_text(encoding="utf-8"))
    assert {v["name"]: v["value"] for v in deadline["parameterValues"]} == values
    commands = openjd_commands(tmp_path / "bundle")
    plan = load_plan(seq / "shots.json")
    assert commands == [(f"{t.shot}-{t.kind}", t.argv(sys.executable)) for t in plan.tasks]
    # step dependencies are the plan's, per step
    deps = {s["name"]: sorted(d["dependsOn"] for d in s.get("dependencies", [])) for s in template["steps"]}
    want: dict[str, set[str]] = {}
    for t in plan.tasks:
        step = f"{t.shot}-{t.kind}"
        want.setdefault(step, set()).update(f"{plan.task(d).shot}-{plan.task(d).kind}" for d in t.depends)
    assert deps == {step: sorted(d - {step}) for step, d in want.items()}


def test_paths_are_parameters_in_and_out_and_gpu_steps_ask_for_a_gpu(seq, tmp_path):
    template = _bundle(seq / "shots.json", tmp_path / "bundle")
    kinds = {p["name"]: (p["type"], p.get("objectType"), p.get("dataFlow")) for p in template["parameterDefinitions"]}
    assert kinds == {
        "EnginePython": ("STRING", None, None),
        "EnginePath": ("STRING", None, None),
        "Plate_sh010": ("PATH", "DIRECTORY", "IN"),
        "Mask1_sh010": ("PATH", "DIRECTORY", "IN"),
        "Run_sh010": ("PATH", "DIRECTORY", "INOUT"),
        "Render_sh010": ("PATH", "DIRECTORY", "OUT"),
        "Plate_sh020": ("PATH", "DIRECTORY", "IN"),
        "Run_sh020": ("PATH", "DIRECTORY", "INOUT"),
    }
    gpu = {s["name"] for s in template["steps"] if "hostRequirements" in s}
    assert gpu == {f"{shot}-{kind}" for shot in ("sh010", "sh020") for kind in ("fit", "atlases", "passes")}
    assert all(
        s["hostRequirements"] == {"amounts": [{"name": "amount.worker.gpu", "min": 1}]}
        for s in template["steps"] if "hostRequirements" in s
    )  # fmt: skip
    assert not any("hostRequirements" in s for s in _bundle(seq / "shots.json", tmp_path / "cpu", "--no-gpu")["steps"])
    refs = json.loads((tmp_path / "bundle" / "asset_references.json").read_text(encoding="utf-8"))["assetReferences"]
    assert refs["inputs"]["directories"] == [
        f"{seq}/clips/a/frames", f"{seq}/clips/a/masks", f"{seq}/clips/b/frames"]  # fmt: skip
    assert refs["outputs"]["directories"] == [f"{seq}/runs/sh010", f"{seq}/renders/sh010", f"{seq}/runs/sh020"]
    passes = next(s for s in template["steps"] if s["name"] == "sh010-passes")
    assert passes["parameterSpace"]["taskParameterDefinitions"] == [
        {"name": "Frames", "type": "STRING", "range": ["0-1", "2-3", "4-4"]}]  # fmt: skip


def test_a_sequence_pattern_plate_is_its_folder_as_the_parameter(tmp_path):
    write_clip(tmp_path / "c")
    shots = write_shots(tmp_path, [{"name": "p", "plate": "c/frames/#####.png"}])
    template = _bundle(shots, tmp_path / "bundle")
    plate = next(p for p in template["parameterDefinitions"] if p["name"] == "Plate_p")
    assert (plate["objectType"], plate["dataFlow"]) == ("DIRECTORY", "IN")
    fit = next(s for s in template["steps"] if s["name"] == "p-fit")["script"]["actions"]["onRun"]["args"]
    assert fit[3] == "{{Param.Plate_p}}/#####.png"
    values = json.loads((tmp_path / "bundle" / "job_parameters.json").read_text(encoding="utf-8"))
    assert values["Plate_p"] == str(tmp_path / "c" / "frames")


# --- end to end: openjd run of a tiny shot, against a direct fit + export ----------------------------------------


def _run(argv: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, **THREADS_ENV, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=TIMEOUT, cwd=cwd, env=env)
    assert proc.returncode == 0, (argv, proc.stdout[-4000:], proc.stderr[-4000:])
    return proc


def _pixels(path: Path) -> tuple[list[str], np.ndarray]:
    image = oiio.ImageInput.open(str(path))
    assert image is not None, oiio.geterror()
    try:
        spec = image.spec()
        return list(spec.channelnames), image.read_image(format=spec.format)
    finally:
        image.close()


def _manifest(path: Path, run: Path) -> dict:
    """The manifest without its creation time and the fit's wall-clock training seconds (they differ run to run)."""
    data = json.loads(path.read_text(encoding="utf-8").replace(str(run), "RUN"))
    data.pop("created")
    data["fit"].pop("train_seconds")
    return data


@dataclass(frozen=True)
class _Runs:
    """One tiny shot through ``openjd run`` and the same fit + export + render run directly."""

    tmp: Path
    farm_stdout: str
    direct: Path  # the direct run folder

    @property
    def farm(self) -> Path:
        return self.tmp / "runs" / "sh010"


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> _Runs:
    tmp = tmp_path_factory.mktemp("e2e")
    frames, masks = write_clip(tmp / "clip")
    shot = {"name": "sh010", "plate": "clip/frames", "masks": ["clip/masks"], "render": "renders/sh010"}
    defaults = {"preset": "draft", "set": TINY_SET, "export_chunk": 2, "render_chunk": 3, "preview": False}
    _bundle(write_shots(tmp, [shot], defaults), tmp / "bundle")  # GPU requirements on: openjd run ignores them
    bundle = tmp / "bundle"
    openjd = [str(OPENJD), "run", str(bundle / "template.json"), "-p", f"file://{bundle / 'job_parameters.json'}"]
    farm = _run([*openjd, "--step", "sh010-publish", "--run-dependencies"], tmp).stdout

    direct = tmp / "direct" / "sh010"  # as deep as runs/sh010: the manifests' relative paths agree
    sets = [x for s in TINY_SET for x in ("--set", s)]
    python = [sys.executable, "-m", C.CLI_MODULE]
    _run([*python, "fit", str(frames), "--out", str(direct), "--preset", "draft", *sets, "--mask", str(masks),
          "--frames", "0-4", "--no-bar"], tmp)  # fmt: skip
    _run([*python, "export", str(direct), "--frames", "0-4", "--no-bar"], tmp)
    return _Runs(tmp, farm, direct)


@pytest.mark.slow
def test_openjd_run_of_a_tiny_shot_equals_a_direct_fit_and_export(runs):
    ran = re.findall(r"Running step '([^']+)'", runs.farm_stdout)
    assert ran == ["sh010-fit", "sh010-atlases", "sh010-passes", "sh010-publish"]
    assert re.findall(r"Frames\(STRING\) = (\S+)", runs.farm_stdout) == ["0-1", "2-3", "4-4"]
    assert "Chunks run: 6" in runs.farm_stdout

    farm, ours = runs.farm / C.EXPORTS_DIR / "v001", runs.direct / C.EXPORTS_DIR / "v001"
    assert _manifest(farm / C.MANIFEST_NAME, runs.farm) == _manifest(ours / C.MANIFEST_NAME, runs.direct)
    files = sorted(p.relative_to(ours).as_posix() for p in ours.rglob("*") if p.is_file())
    assert sorted(p.relative_to(farm).as_posix() for p in farm.rglob("*") if p.is_file()) == files
    images = [f for f in files if f.endswith((".exr", ".png"))]
    assert sum(f.startswith("passes/") for f in images) == 5 and any(f.startswith("atlases/") for f in images)
    for name in images:
        (farm_channels, farm_pixels), (our_channels, our_pixels) = _pixels(farm / name), _pixels(ours / name)
        assert farm_channels == our_channels, name
        assert farm_pixels.dtype == our_pixels.dtype and np.array_equal(farm_pixels, our_pixels), name
    for edit in sorted((runs.direct / EDITS_DIR).glob("*.png")):
        assert np.array_equal(_pixels(edit)[1], _pixels(runs.farm / EDITS_DIR / edit.name)[1])
    assert not list((farm.parent).glob(".v*")), "the staging folder became v001"


@pytest.mark.slow
def test_openjd_render_chunks_equal_a_direct_render(runs):
    bundle = runs.tmp / "bundle"
    proc = _run([str(OPENJD), "run", str(bundle / "template.json"), "-p", f"file://{bundle / 'job_parameters.json'}",
                 "--step", "sh010-render", "--no-run-dependencies"], runs.tmp)  # fmt: skip
    assert re.findall(r"Frames\(STRING\) = (\S+)", proc.stdout) == ["0-2", "3-4"]
    manifest = runs.direct / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME
    our_render, farm_render = runs.tmp / "direct_render", runs.tmp / "renders" / "sh010"
    _run([sys.executable, "-m", C.CLI_MODULE, "render", str(manifest), "--out", str(our_render), "--no-bar"], runs.tmp)
    rendered = visible_names(our_render)
    assert len(rendered) == 5 and visible_names(farm_render) == rendered
    for name in rendered:
        farm_frame, our_frame = _pixels(farm_render / name), _pixels(our_render / name)
        assert farm_frame[0] == our_frame[0] and np.array_equal(farm_frame[1], our_frame[1]), name


@pytest.mark.slow
def test_the_whole_job_run_again_is_a_no_op(runs):
    """What a farm's retry of any task does: the fit is finished, the version published; nothing changes."""
    exports, checkpoint = runs.farm / C.EXPORTS_DIR, runs.farm / C.RUN_CHECKPOINT
    before = (tree_digest(exports), checkpoint.read_bytes())
    bundle = runs.tmp / "bundle"
    proc = _run([str(OPENJD), "run", str(bundle / "template.json"), "-p", f"file://{bundle / 'job_parameters.json'}",
                 "--step", "sh010-publish", "--run-dependencies"], runs.tmp)  # fmt: skip
    assert "Chunks run: 6" in proc.stdout
    assert (tree_digest(exports), checkpoint.read_bytes()) == before
    assert sorted(p.name for p in exports.iterdir()) == ["v001"]


def test_farm_openjd_prints_a_progress_line_per_shot_then_the_templates_path(seq, tmp_path):
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = cli.main([C.VERB_FARM, C.FARM_OPENJD, str(seq / "shots.json"), "--out", str(tmp_path / "b")])
    assert code == C.EXIT_OK
    lines = out.getvalue().splitlines()
    assert lines[-1] == str(tmp_path / "b" / "template.json")
    progress = [C.parse_progress_line(line) for line in lines[:-1]]
    stages = [(p["shot"], p["tasks"], p["stage"]) for p in progress if p and p["event"] == C.EVENT_STAGE]
    assert stages == [("sh010", 8, "farm"), ("sh020", 6, "farm")]
    assert progress[-1] == {"neural_atlas": 1, "event": "written", "paths": [lines[-1]]}
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == [
        "asset_references.json", "job_parameters.json", "parameter_values.json", "template.json"]  # fmt: skip
    # the defaults: this Python, this engine's folder on PYTHONPATH
    values = json.loads((tmp_path / "b" / "job_parameters.json").read_text(encoding="utf-8"))
    assert (values["EnginePython"], values["EnginePath"]) == (sys.executable, str(ROOT))
