"""Submit to Farm inside Blender (bpy 4.5 and 5.0): the shots file the add-on writes for a scene with a clip and masks
(checked against the engine's own reader), a submission to a stub Flamenco Manager on 127.0.0.1 through the real
engine's ``farm flamenco``, the refusal while online access is off (no request made), the OpenJD bundle written by
the real engine's ``farm openjd``, the greyed button and the panel's status line, and Import of a run folder exported
in farm chunks (``export --into vNNN --stage ...``), which must import as a plain export does.

The engine runs in its own interpreter: NEURAL_ATLAS_TEST_ENGINE_PYTHON, else the checkout's .venv (the bpy 5.0 venv
has no torch). A test is skipped where there is no engine Python, and fails where its CLI does.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from helpers import RecordingLayout, as_operator, drive_modal, fake_python, polygon_mask  # noqa: E402
from neural_atlas.addon import compat, preferences, ui  # noqa: E402
from neural_atlas.addon.core import farm as FM  # noqa: E402
from neural_atlas.addon.core import running  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402
from neural_atlas.addon.ops import farm as farm_ops  # noqa: E402

from engine import contract as C  # noqa: E402
from engine.terms.cli import EXPORT_STAGE_ARG  # noqa: E402
from engine.terms.farm import FLAMENCO_API_CHECK, FLAMENCO_API_SUBMIT, FLAMENCO_JOB_TYPE  # noqa: E402
from tests.farm.flamenco_helpers import NODE, StubManager  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
FRAMES, W, H = X.FRAMES, X.W, X.H
#: How long a stub-Manager test lets the engine take (it answers in well under a second).
SUBMIT_TIMEOUT = 120.0


def _engine_python(*verb: str, needs: str = "usage:") -> str:
    """The real engine's Python (skipped where there is none: a Blender without the checkout's environment); an
    engine there whose ``verb`` (e.g. ``farm flamenco``) fails or whose help does not say ``needs`` fails the test:
    the add-on and the engine ship together, so a broken engine CLI is a failure, not a reason to skip."""
    py = os.environ.get("NEURAL_ATLAS_TEST_ENGINE_PYTHON") or str(ROOT / ".venv" / "bin" / "python")
    if not os.path.exists(py):
        pytest.skip(f"no engine Python at {py}")
    probe = subprocess.run([py, "-m", C.CLI_MODULE, *verb, "-h"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert probe.returncode == 0 and needs in probe.stdout, (
        f"the engine at {py}: `{' '.join(verb)} -h` does not say {needs!r}: {probe.stderr.strip()[-200:]}"
    )
    return py


@pytest.fixture
def farm_prefs(blender):
    """The add-on's preferences (enabled as Blender enables it: an entry in preferences.addons); removed after."""
    addons = blender.context.preferences.addons
    entry = addons.new()
    entry.module = preferences.ADDON_ID
    prefs = preferences.addon_prefs(blender.context)
    assert prefs is not None
    system = blender.context.preferences.system
    online_before = system.use_online_access
    yield prefs
    system.use_online_access = online_before
    addons.remove(entry)


@pytest.fixture
def farm_scene(blender, farm_prefs, tmp_path, monkeypatch):
    """A clip (the fake export's plate: plate frames 3-5), one Mask layer and one folder layer, the fake engine."""
    X.make_export(tmp_path / "src")
    clip = bpy.data.movieclips.load(str(tmp_path / "src" / "plate" / f"{FRAMES[0]:05d}.png"))
    monkeypatch.setenv(preferences.ENGINE_PYTHON_ENV, fake_python(tmp_path))
    props = blender.context.scene.neural_atlas
    props.clip = clip
    props.layers.add().mask = polygon_mask(bpy.data, [(clip.frame_start, [(5, 5), (20, 5), (20, 15), (5, 15)])], W, H)
    folder = props.layers.add()
    folder.source = "FOLDER"
    folder.folder = str(tmp_path / "src" / "masks_by_hand")
    os.makedirs(folder.folder)
    props.preset = "draft"
    props.long_edge = 256
    props.overrides = "steps=30"
    props.run_dir = str(tmp_path / "sh010")
    return props, farm_prefs


def _expected_shots(tmp_path: Path, props) -> dict:
    return {
        C.SHOTS_TAG: C.SHOTS_VERSION,
        C.SHOTS_DEFAULTS_KEY: {"preset": "draft", "set": ["long_edge=256", "steps=30"]},
        C.SHOTS_LIST_KEY: [
            {
                "name": "00003",
                "plate": str(tmp_path / "src" / "plate" / "#####.png"),
                "masks": [str(tmp_path / "sh010.masks" / "layer1"), str(tmp_path / "src" / "masks_by_hand")],
                "frames": f"{FRAMES[0]}-{FRAMES[-1]}",
                "colorspace": C.COLOUR_SRGB,
                "run": str(tmp_path / "sh010"),
            }
        ],
    }


# --- the shots file ---------------------------------------------------------------------------------------------
def test_shots_file_of_a_clip_with_masks(farm_scene, tmp_path):
    props, prefs = farm_scene
    prefs.farm_kind = FM.FARM_OPENJD
    assert bpy.ops.neural_atlas.submit_farm("EXEC_DEFAULT") == {"FINISHED"}
    shots = tmp_path / "sh010.farm" / "shots.json"
    assert json.loads(shots.read_text()) == _expected_shots(tmp_path, props)
    # the Mask layer is rasterised as for Fit Atlas: one image per frame, named by the plate's numbers
    assert sorted(os.listdir(tmp_path / "sh010.masks" / "layer1")) == [f"{f:05d}.png" for f in FRAMES]
    bundle = tmp_path / "sh010.farm" / "openjd"
    assert props.farm_status == f"OpenJD bundle for Deadline Cloud: {bundle}"
    assert sorted(os.listdir(bundle)) == ["parameter_values.json", "template.json"]  # the stand-in engine's
    # a second submission gets a bundle folder of its own
    assert bpy.ops.neural_atlas.submit_farm("EXEC_DEFAULT") == {"FINISHED"}
    assert props.farm_status.endswith(str(tmp_path / "sh010.farm" / "openjd_2"))


#: The engine's reader and planner on a shots file, run by the engine's Python (``farm plan --json`` prints the plan
#: the same way): the shots as read, then the plan.
READ_SHOTS = (
    "import json, sys; from engine.farm import plan, shots; s = shots.load_shots(sys.argv[1]); "
    "print(json.dumps({'shots': [x.model_dump(mode='json') for x in s.shots], 'plan': plan.plan_shots(s).to_json()}))"
)


def test_shots_file_validates_with_the_engines_reader(farm_scene, tmp_path):
    """The engine's own reader and planner (engine/farm/shots.py, plan.py) take the file the add-on wrote: the fit
    task reads the plate, the masks and the frames the panel names, into the Run Folder."""
    props, prefs = farm_scene
    py = _engine_python(C.VERB_FIT)
    prefs.farm_kind = FM.FARM_OPENJD
    assert bpy.ops.neural_atlas.submit_farm("EXEC_DEFAULT") == {"FINISHED"}
    path = tmp_path / "sh010.farm" / "shots.json"
    proc = subprocess.run([py, "-c", READ_SHOTS, str(path)], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    read = json.loads(proc.stdout.strip().splitlines()[-1])
    (shot,) = read["shots"]
    expected = _expected_shots(tmp_path, props)[C.SHOTS_LIST_KEY][0]
    assert (shot["name"], shot["plate"], shot["run"]) == (expected["name"], expected["plate"], expected["run"])
    assert shot["masks"] == expected["masks"] and not shot["auto_masks"]
    assert shot["frames"] == [FRAMES[0], FRAMES[-1]] and shot["colorspace"] == C.COLOUR_SRGB
    assert (shot["preset"], shot["set"]) == ("draft", ["long_edge=256", "steps=30"])
    tasks = read["plan"]["tasks"]
    kinds = [t["kind"] for t in tasks]
    assert kinds[:3] == ["fit", "atlases", "passes"] and "masks" not in kinds  # masks given: no masks task
    fit = tasks[0]["args"]
    assert fit[:2] == [C.VERB_FIT, expected["plate"]]
    assert fit[fit.index("--out") + 1] == str(tmp_path / "sh010")
    assert [fit[i + 1] for i, a in enumerate(fit) if a == "--mask"] == expected["masks"]
    assert fit[fit.index("--frames") + 1].replace(":", "-") == f"{FRAMES[0]}-{FRAMES[-1]}"
    assert fit[fit.index("--preset") + 1] == "draft" and "long_edge=256" in fit and "steps=30" in fit
    assert fit[fit.index("--colorspace") + 1] == C.COLOUR_SRGB


def test_the_modal_path_shows_its_status_and_ends_with_the_bundle(farm_scene, tmp_path):
    """The UI path (invoke's modal operator, driven by hand-made TIMER events: no event loop runs headless)."""
    props, prefs = farm_scene
    prefs.farm_kind = FM.FARM_OPENJD
    seen = []

    def events(tick, job):
        seen.append(props.farm_status)
        return "TIMER"

    ret, op, job = drive_modal(farm_ops.NEURALATLAS_OT_submit_farm, bpy.context, events)
    assert ret == {"FINISHED"} and running.jobs() == {}
    assert FM.FarmJob.idle_text in seen and not props.running  # the status line moved; the fit's state is untouched
    assert job.bundle_dir == str(tmp_path / "sh010.farm" / "openjd")
    assert props.farm_status == f"OpenJD bundle for Deadline Cloud: {job.bundle_dir}"
    assert op.reports == [({"INFO"}, props.farm_status)]


def test_no_layers_means_auto_masks(farm_scene, tmp_path):
    props, prefs = farm_scene
    prefs.farm_kind = FM.FARM_OPENJD
    props.layers.clear()
    assert bpy.ops.neural_atlas.submit_farm("EXEC_DEFAULT") == {"FINISHED"}
    (shot,) = json.loads((tmp_path / "sh010.farm" / "shots.json").read_text())[C.SHOTS_LIST_KEY]
    assert shot["auto_masks"] is True and "masks" not in shot
    assert not (tmp_path / "sh010.masks").exists()


def test_scribbles_are_refused(farm_scene, tmp_path):
    props, prefs = farm_scene
    prefs.farm_kind = FM.FARM_OPENJD
    props.use_scribbles = True
    with pytest.raises(RuntimeError, match="Split with Scribbles is fitted here only"):
        bpy.ops.neural_atlas.submit_farm("EXEC_DEFAULT")
    assert not (tmp_path / "sh010.farm").exists() and running.jobs() == {}


def test_find_parts_off_goes_to_the_shot_and_on_leaves_it_to_the_fit(farm_scene, tmp_path):
    """Find Parts off: the shot's ``auto_parts`` is false (its fit task: ``--no-auto-parts``); on (the default): the
    key is left out, the fit's default (the parts that move apart, wherever that applies)."""
    props, prefs = farm_scene
    prefs.farm_kind = FM.FARM_OPENJD
    while len(props.layers) > 1:
        props.layers.remove(len(props.layers) - 1)
    shots = tmp_path / "sh010.farm" / "shots.json"
    for find_parts in (False, True):
        props.find_parts = find_parts
        shutil.rmtree(shots.parent, ignore_errors=True)
        assert bpy.ops.neural_atlas.submit_farm("EXEC_DEFAULT") == {"FINISHED"}
        (shot,) = json.loads(shots.read_text())[C.SHOTS_LIST_KEY]
        assert shot.get("auto_parts", "left out") == ("left out" if find_parts else False)
        assert len(shot["masks"]) == 1


def test_greyed_without_clip_or_engine(farm_scene, monkeypatch):
    props, prefs = farm_scene
    prefs.farm_kind = FM.FARM_OPENJD
    assert bpy.ops.neural_atlas.submit_farm.poll()
    clip, props.clip = props.clip, None
    assert not bpy.ops.neural_atlas.submit_farm.poll()
    props.clip = clip
    monkeypatch.delenv(preferences.ENGINE_PYTHON_ENV)
    prefs.engine_python = ""
    assert not bpy.ops.neural_atlas.submit_farm.poll()


def test_panel_shows_the_button_and_the_status_line(farm_scene):
    props, prefs = farm_scene
    prefs.farm_kind = FM.FARM_OPENJD
    props.farm_status = "OpenJD bundle for Deadline Cloud: /b"
    calls = RecordingLayout().draw(ui.NEURALATLAS_PT_fit, bpy.context)
    ops = [(a[0], kw.get("text")) for name, a, kw in calls if name == "operator"]
    assert ("neural_atlas.submit_farm", "Submit to Farm (OpenJD bundle)") in ops
    labels = [kw.get("text") for name, _, kw in calls if name == "label"]
    assert labels[-1] == "OpenJD bundle for Deadline Cloud: /b"
    prefs.farm_kind = FM.FARM_FLAMENCO
    bpy.context.preferences.system.use_online_access = False
    labels = [
        kw.get("text") for name, _, kw in RecordingLayout().draw(ui.NEURALATLAS_PT_fit, bpy.context) if name == "label"
    ]
    assert labels[-1] == ui.FARM_OFFLINE_TEXT


#: The job type's path on a Manager (the submitter reads its etag first).
JOB_TYPE_PATH = f"/api/v3/jobs/type/{FLAMENCO_JOB_TYPE}"


@pytest.mark.skipif(NODE is None, reason="node (v20): the stub Manager compiles each job with the real job type")
def test_submit_to_a_stub_flamenco_manager(farm_scene, tmp_path, monkeypatch):
    props, prefs = farm_scene
    py = _engine_python(C.VERB_FARM, C.FARM_FLAMENCO)
    monkeypatch.setenv(preferences.ENGINE_PYTHON_ENV, py)
    bpy.context.preferences.system.use_online_access = True
    with StubManager() as manager:
        prefs.farm_kind, prefs.farm_manager_url, prefs.farm_priority = FM.FARM_FLAMENCO, manager.url + "/", 73
        result = bpy.ops.neural_atlas.submit_farm("EXEC_DEFAULT", timeout=SUBMIT_TIMEOUT)
    assert result == {"FINISHED"}, props.farm_status
    # the stub answers a body that is no SubmittedJob, or that the real job type cannot compile, with an error
    assert len(manager.jobs) == 1
    calls = [(method, path) for method, path, _ in manager.requests()]
    assert calls[-2:] == [("POST", FLAMENCO_API_CHECK), ("POST", FLAMENCO_API_SUBMIT)]  # check, then submit
    assert {m for m, _ in calls[:-2]} == {"GET"} and ("GET", JOB_TYPE_PATH) in calls
    check, submitted = (body for _, _, body in manager.requests()[-2:])
    assert check == submitted
    assert submitted["type"] == FLAMENCO_JOB_TYPE and submitted["priority"] == 73
    assert submitted.get("type_etag") == manager.etag
    assert "00003" in submitted["name"]
    assert submitted["submitter_platform"] in ("linux", "windows", "darwin")
    settings = json.dumps(submitted["settings"])
    assert str(tmp_path / "sh010") in settings and str(tmp_path / "sh010.masks" / "layer1") in settings
    (job_id,) = manager.jobs
    assert props.farm_status == f"submitted to Flamenco at {manager.url}: job {job_id}"


def test_flamenco_manager_error_is_reported_as_the_engine_says_it(farm_scene, monkeypatch):
    props, prefs = farm_scene
    py = _engine_python(C.VERB_FARM, C.FARM_FLAMENCO)
    monkeypatch.setenv(preferences.ENGINE_PYTHON_ENV, py)
    bpy.context.preferences.system.use_online_access = True
    with StubManager() as manager:
        manager.server.server_close()  # nothing listens on its port any more
        prefs.farm_kind, prefs.farm_manager_url = FM.FARM_FLAMENCO, manager.url
        with pytest.raises(RuntimeError, match="Submit to Farm: ") as err:
            bpy.ops.neural_atlas.submit_farm("EXEC_DEFAULT", timeout=SUBMIT_TIMEOUT)
    assert manager.url.split("//")[1] in str(err.value) and "\n" not in props.farm_status
    assert "Traceback" not in props.farm_status


def test_online_access_off_refuses_without_a_request(farm_scene, tmp_path):
    props, prefs = farm_scene
    bpy.context.preferences.system.use_online_access = False
    refusal = FM.online_refusal(FM.FARM_FLAMENCO, False, False)
    with StubManager() as manager:
        prefs.farm_kind, prefs.farm_manager_url = FM.FARM_FLAMENCO, manager.url
        assert not bpy.ops.neural_atlas.submit_farm.poll()
        with pytest.raises(RuntimeError, match="online access is off in Blender"):
            bpy.ops.neural_atlas.submit_farm("EXEC_DEFAULT")
        # a call that skips poll (the job's own start) is refused the same way, before anything is written
        op = as_operator(farm_ops.NEURALATLAS_OT_submit_farm)
        assert op._begin(bpy.context) is None
    assert op.reports == [({"ERROR"}, refusal)] and props.farm_status == refusal
    assert "Preferences > System > Network > Allow Online Access" in refusal
    assert manager.calls == []
    assert not (tmp_path / "sh010.farm").exists() and not (tmp_path / "sh010.masks").exists()
    assert running.jobs() == {}
    prefs.farm_kind = FM.FARM_OPENJD  # a bundle is written offline
    assert bpy.ops.neural_atlas.submit_farm.poll()


# --- OpenJD: the real engine's bundle -----------------------------------------------------------------------------
def test_openjd_bundle_from_the_real_engine(farm_scene, tmp_path, monkeypatch):
    props, prefs = farm_scene
    py = _engine_python(C.VERB_FARM, C.FARM_OPENJD)
    monkeypatch.setenv(preferences.ENGINE_PYTHON_ENV, py)
    bpy.context.preferences.system.use_online_access = False  # writing a bundle needs no network
    prefs.farm_kind, prefs.farm_bundle_dir = FM.FARM_OPENJD, str(tmp_path / "bundles")
    assert bpy.ops.neural_atlas.submit_farm("EXEC_DEFAULT", timeout=SUBMIT_TIMEOUT) == {"FINISHED"}, props.farm_status
    bundle = tmp_path / "bundles" / "00003" / "openjd"
    assert props.farm_status == f"OpenJD bundle for Deadline Cloud: {bundle}"
    assert {"template.json", "parameter_values.json"} <= set(os.listdir(bundle))
    template = json.loads((bundle / "template.json").read_text())
    assert template["specificationVersion"] == "jobtemplate-2023-09"
    steps = [step["name"] for step in template["steps"]]
    assert [s.split("-", 1)[1] for s in steps[:3]] == ["fit", "atlases", "passes"], steps
    values = {
        v["name"]: v["value"] for v in json.loads((bundle / "parameter_values.json").read_text())["parameterValues"]
    }
    assert str(tmp_path / "sh010") in values.values()  # the Run Folder, an OUT path Deadline maps
    assert str(tmp_path / "sh010.masks" / "layer1") in values.values()  # the rasterised Mask layer, an IN path


# --- Import of a run folder the farm exported in chunks ------------------------------------------------------------
def _run(py: str, *args: str, timeout: float = 300) -> str:
    proc = subprocess.run([py, "-m", C.CLI_MODULE, *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, f"{args}: {proc.stderr[-2000:]}"
    return proc.stdout


def _imported(blender, manifest: Path) -> dict:
    """What Import Atlas built for ``manifest``: the tree's nodes, each image's file relative to the export, the
    scene's range, and a render of the first frame (Nearest)."""
    blender.ops.wm.read_factory_settings(use_empty=True)
    scene = blender.context.scene
    scene.neural_atlas.filter_type = P.FILTER_NEAREST
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    tree = compat.scene_tree(scene, create=False)
    export = manifest.parent
    images = {}
    for img in blender.data.images:
        if img.name.startswith(P.PREFIX) and img.filepath:
            path = Path(bpy.path.abspath(img.filepath))
            assert path.exists(), f"{img.name}: {path} is missing"
            images[img.name] = os.path.relpath(path, export)
    out = manifest.parent.parent.parent / f"render_{export.name}"
    imported_range = (scene.frame_start, scene.frame_end)
    scene.frame_end = scene.frame_start
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="exr") == {"FINISHED"}
    (frame,) = sorted(out.glob("edit.*"))
    return {
        "nodes": sorted(n.name for n in tree.nodes if n.name.startswith(P.PREFIX)),
        "images": images,
        "range": imported_range,
        "layers": scene.neural_atlas.imported_layers,
        "frame": X.read_exr_rgba(frame),
    }


@pytest.mark.slow
def test_a_farm_export_imports_as_a_plain_export(blender, tmp_path):
    """A run folder exported by the farm (``--stage atlases``, ``passes`` in two chunks, ``publish``) imports as the
    plain export of the same fit: the same tree, the same files (relative to the export), the same render."""
    py = _engine_python(C.VERB_EXPORT, needs=EXPORT_STAGE_ARG)
    clip = tmp_path / "clip"
    subprocess.run(
        [
            py,
            "-c",
            "import sys; from pathlib import Path; "
            "from engine.data.synthetic import SceneSpec, make_scene, write_scene; "
            "write_scene(make_scene(SceneSpec(width=48, height=32, frames=4)), Path(sys.argv[1]))",
            str(clip),
        ],
        cwd=ROOT,
        check=True,
        timeout=120,
    )
    run = tmp_path / "run"
    fast = [f"--set={s}" for s in ("steps=30", "bootstrap_steps=10", "global_rigidity_steps=10", "eval_every=10")]
    _run(py, C.VERB_FIT, str(clip / "frames"), "--mask", str(clip / "masks"), "--out", str(run), *fast, "--no-bar")
    plain = Path(_run(py, C.VERB_EXPORT, str(run), "--no-bar").strip().splitlines()[-1])
    into = ["--into", "v002"]
    _run(py, C.VERB_EXPORT, str(run), *into, EXPORT_STAGE_ARG, "atlases")
    _run(py, C.VERB_EXPORT, str(run), *into, EXPORT_STAGE_ARG, "passes", "--frames", "0-1")
    _run(py, C.VERB_EXPORT, str(run), *into, EXPORT_STAGE_ARG, "passes", "--frames", "2-3")
    staged = Path(_run(py, C.VERB_EXPORT, str(run), *into, EXPORT_STAGE_ARG, "publish").strip().splitlines()[-1])
    assert staged == run / C.EXPORTS_DIR / "v002" / C.MANIFEST_NAME and plain != staged
    a, b = _imported(blender, plain), _imported(blender, staged)
    assert a["nodes"] == b["nodes"] and "NA_Passes" in a["nodes"]
    assert a["images"] == b["images"] and a["range"] == b["range"] == (0, 3)
    assert a["layers"] == b["layers"] == "Background, Foreground"
    assert np.abs(a["frame"] - b["frame"]).max() <= 1e-6
