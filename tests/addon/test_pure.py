"""The add-on's logic that runs without Blender: the engine process runner, the tree plan, mask maths."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import pytest
from fake_export import FRAMES, make_export
from helpers import HERE, fake_python
from neural_atlas.addon import engine_process as EP
from neural_atlas.addon import engine_setup as ES
from neural_atlas.addon import estimate, mask_math
from neural_atlas.addon import tree_plan as P

from engine import contract as C

FAKE = [sys.executable, str(HERE / "fake_engine.py")]


def test_pure_modules_do_not_import_bpy():
    assert "bpy" not in sys.modules or sys.modules["bpy"] is not None  # importable either way
    for mod in (EP, ES, P, mask_math, estimate):
        src = Path(mod.__file__).read_text(encoding="utf-8")
        assert "import bpy" not in src, mod.__name__


# --- engine process -----------------------------------------------------------------------------------------
def test_job_reads_progress_and_ignores_noise(tmp_path):
    seen = []
    result = (
        EP.EngineJob([*FAKE, "fit", "clip", "--out", str(tmp_path / "run")], str(tmp_path / "log"))
        .start()
        .wait(on_message=seen.append)
    )
    assert result.status == EP.STATUS_OK and result.returncode == 0
    steps = [m["step"] for m in seen if m["event"] == C.EVENT_PROGRESS]
    assert steps == list(range(1, 11))
    assert result.metrics == {"psnr": 30.0, "steps": 10}
    log = (tmp_path / "log").read_text()
    assert "tqdm-like noise" in log and "[exit code 0]" in log


def test_job_state_summary_has_step_psnr_eta():
    st = EP.JobState()
    st.apply({"event": C.EVENT_PROGRESS, "step": 30, "total": 120, "psnr": 24.56, "eta": 95.0})
    assert st.fraction == 0.25
    assert st.summary() == "step 30/120 · 24.6 dB · ETA 1m35s"


def test_job_cancel_sends_sigterm_and_reports_cancelled(tmp_path, monkeypatch):
    monkeypatch.setenv("FAKE_ENGINE_MODE", "hang")
    job = EP.EngineJob([*FAKE, "fit", "clip", "--out", str(tmp_path / "run")], str(tmp_path / "log")).start()
    while job.state.step < 3:
        job.poll()
        time.sleep(0.02)
    t0 = time.monotonic()
    job.cancel()
    result = job.wait()
    assert time.monotonic() - t0 < 5
    assert result.status == EP.STATUS_CANCELLED and result.returncode == C.EXIT_CANCELLED
    assert "Resume" in result.message
    assert (tmp_path / "run" / C.RUN_CHECKPOINT).exists()


def test_jobs_still_running_at_exit_are_cancelled(tmp_path, monkeypatch):
    """Engines run in their own session; when Blender quits, atexit asks them to stop (checkpoint)."""
    monkeypatch.setenv("FAKE_ENGINE_MODE", "hang")
    job = EP.EngineJob([*FAKE, "fit", "c", "--out", str(tmp_path / "r")], str(tmp_path / "log")).start()
    while job.state.step < 1:
        job.poll()
        time.sleep(0.02)
    EP._stop_live_jobs()
    assert job.wait(timeout=10).status == EP.STATUS_CANCELLED


def test_job_timeout_cancels(tmp_path, monkeypatch):
    monkeypatch.setenv("FAKE_ENGINE_MODE", "hang")
    result = EP.EngineJob([*FAKE, "fit", "c", "--out", str(tmp_path / "r")], str(tmp_path / "log")).start().wait(0.5)
    assert result.status == EP.STATUS_CANCELLED


@pytest.mark.parametrize(
    ("mode", "status", "words"),
    [
        ("crash", EP.STATUS_FAILED, "killed by signal 9"),
        ("traceback", EP.STATUS_FAILED, "RuntimeError: simulated engine bug"),
        ("bad_input", EP.STATUS_BAD_INPUT, "mask folder does not exist"),
    ],
)
def test_job_failures_become_results(tmp_path, monkeypatch, mode, status, words):
    monkeypatch.setenv("FAKE_ENGINE_MODE", mode)
    result = EP.EngineJob([*FAKE, "fit", "c", "--out", str(tmp_path / "r")], str(tmp_path / "log")).start().wait()
    assert result.status == status
    assert words in result.message
    assert result.log_path == str(tmp_path / "log")


def test_job_missing_interpreter_is_a_result_not_an_exception(tmp_path):
    result = EP.EngineJob([str(tmp_path / "no_python"), "-m", "engine"], str(tmp_path / "log")).start().wait()
    assert result.status == EP.STATUS_FAILED and result.returncode is None
    assert "cannot start the engine" in result.message


def test_job_refuses_a_shell_string(tmp_path):
    with pytest.raises(TypeError):
        EP.EngineJob("python -m engine fit", str(tmp_path / "log"))


def test_export_manifest_from_last_stdout_line(tmp_path):
    result = EP.EngineJob([*FAKE, "export", str(tmp_path / "run")], str(tmp_path / "log")).start().wait()
    assert result.status == EP.STATUS_OK
    assert result.manifest and result.manifest.endswith(C.MANIFEST_NAME)
    C.load_manifest(result.manifest)


def test_fake_python_wrapper_speaks_version(tmp_path):
    job = EP.EngineJob(ES.version_argv(fake_python(tmp_path)), str(tmp_path / "log")).start()
    assert job.wait().status == EP.STATUS_OK
    assert job.state.last_stdout.startswith("neural-atlas engine")


# --- engine set-up ------------------------------------------------------------------------------------------
def test_setup_commands_install_the_contract_requirements():
    argv = ES.pip_install_argv("/x/bin/python")
    assert argv[:4] == ["/x/bin/python", "-m", "pip", "install"]
    assert tuple(argv[-len(C.ENGINE_REQUIREMENTS) :]) == C.ENGINE_REQUIREMENTS
    assert ES.engine_argv("py", "fit", "a") == ["py", "-m", "engine", "fit", "a"]
    cpu = ES.pip_install_argv("/x/bin/python", cpu_only=True)
    assert cpu[cpu.index("--extra-index-url") + 1] == "https://download.pytorch.org/whl/cpu"
    env = ES.engine_env({"PYTHONPATH": "/other"})
    assert env["PYTHONPATH"].split(":")[0] == ES.extension_root()
    assert (HERE.parents[1] / "engine" / "contract.py").samefile(f"{ES.extension_root()}/engine/contract.py")


def test_setup_failure_offline_is_explained():
    log = "WARNING: Retrying ... NewConnectionError('Failed to establish a new connection')\nERROR: No matching"
    assert "offline" in ES.explain_setup_failure(log)
    assert ES.explain_setup_failure("ERROR: torch wheel is broken\n") == "ERROR: torch wheel is broken"


# --- tree plan ----------------------------------------------------------------------------------------------
def test_plan_topology_two_layers(tmp_path):
    mp = make_export(tmp_path)
    plan = P.plan_tree(C.load_manifest(str(mp)), str(mp), P.FILTER_NEAREST)
    assert plan.kinds() == {
        P.PLATE: 1,
        P.IMAGE: 3,  # passes + one edit layer per layer
        P.MAP_UV: 2,
        P.SEPARATE: 2,
        P.ADD_COLOR: 1,
        P.ADD_VALUE: 1,
        P.SET_ALPHA: 1,
        P.ALPHA_OVER: 1,
        P.OUTPUT: 1,
    }
    assert all(n.name.startswith(P.PREFIX) for n in plan.nodes)
    assert all(i.name.startswith(P.PREFIX) for i in plan.images)
    links = {(lk.from_node, lk.from_socket, lk.to_node, lk.to_socket) for lk in plan.links}
    assert ("NA_Passes", "UVForeground", "NA_MapUV_Foreground", "uv") in links
    assert ("NA_Plate", "image", "NA_Over", "bg") in links
    assert ("NA_SetAlpha", "image", "NA_Over", "fg") in links
    assert ("NA_AddColor_1", "result", "NA_SetAlpha", "image") in links
    assert ("NA_AddAlpha_1", "value", "NA_SetAlpha", "alpha") in links
    assert (plan.frame_start, plan.frame_end) == (FRAMES[0], FRAMES[-1])
    assert plan.plate.sequence and plan.plate.frame_start == FRAMES[0]
    passes = next(i for i in plan.images if i.name == P.PASSES_IMAGE)
    assert passes.colorspace == "Non-Color" and passes.filepath.endswith(C.pass_file_name(FRAMES[0]))
    assert {i.colorspace for i in plan.images if i.name.startswith("NA_Edit_")} == {"sRGB"}


def test_plan_three_layers_sums_every_layer(tmp_path):
    mp = make_export(tmp_path)
    m = C.load_manifest(str(mp))
    extra = dict(m["layers"][1], name="Foreground2", index=2, uv_pass="UVForeground2")
    m["layers"].append(extra)
    plan = P.plan_tree(m, str(mp))
    k = plan.kinds()
    assert (k[P.MAP_UV], k[P.ADD_COLOR], k[P.ADD_VALUE], k[P.SEPARATE]) == (3, 2, 2, 3)


def test_float_edit_layer_wins_over_the_png_when_both_exist(tmp_path):
    """contract.edit_layer_file: the export makes <Layer>.png; an <Layer>.exr beside it is used instead."""
    mp = make_export(tmp_path)
    m = C.load_manifest(str(mp))
    png = P.resolve(str(mp), m["layers"][1]["edit_layer"])
    assert png.endswith(".png") and C.edit_layer_file(png) == png
    spec = next(i for i in P.plan_tree(m, str(mp)).images if i.name == P.edit_image_name("Foreground"))
    assert (spec.filepath, spec.colorspace) == (png, "sRGB")
    exr = png[: -len(".png")] + C.EDIT_LAYER_FLOAT_EXT
    Path(exr).write_bytes(b"")  # existence is the rule; the content is read by Blender / the engine
    assert C.edit_layer_file(png) == exr
    assert C.edit_layer_file(exr) == exr and C.edit_layer_file("elsewhere/paint.png") == "elsewhere/paint.png"
    spec = next(i for i in P.plan_tree(m, str(mp)).images if i.name == P.edit_image_name("Foreground"))
    assert (spec.filepath, spec.colorspace) == (exr, "Non-Color")
    # an explicit edit override is used as given
    spec = next(i for i in P.plan_tree(m, str(mp), edits={"Foreground": png}).images if i.name.endswith("Foreground"))
    assert spec.filepath == png


def test_plan_from_a_three_layer_export(tmp_path):
    mp = make_export(tmp_path, foregrounds=2)
    m = C.load_manifest(str(mp))
    plan = P.plan_tree(m, str(mp), P.FILTER_NEAREST)
    assert plan.layers == ["Background", "Foreground1", "Foreground2"]
    k = plan.kinds()
    assert (k[P.IMAGE], k[P.MAP_UV], k[P.SEPARATE], k[P.ADD_COLOR], k[P.ADD_VALUE]) == (4, 3, 3, 2, 2)
    assert (k[P.SET_ALPHA], k[P.ALPHA_OVER], k[P.OUTPUT], k[P.PLATE]) == (1, 1, 1, 1)
    links = {(lk.from_node, lk.from_socket, lk.to_node, lk.to_socket) for lk in plan.links}
    for name in plan.layers:
        assert ("NA_Passes", f"UV{name}", f"NA_MapUV_{name}", "uv") in links
        assert any(i.name == f"NA_Edit_{name}" for i in plan.images)
    # every Map UV output reaches the colour sum exactly once, every alpha the alpha sum exactly once
    adds = [lk for lk in plan.links if lk.to_node.startswith("NA_AddColor_")]
    assert {lk.from_node for lk in adds if lk.from_node.startswith("NA_MapUV_")} == {
        f"NA_MapUV_{n}" for n in plan.layers
    }


def test_plan_rejects_gaps_and_unknown_edits(tmp_path):
    mp = make_export(tmp_path)
    m = C.load_manifest(str(mp))
    with pytest.raises(P.PlanError, match="unknown layer"):
        P.plan_tree(m, str(mp), edits={"Nope": "x.png"})
    m["passes"]["frames"] = [3, 5]
    with pytest.raises(P.PlanError, match="gaps"):
        P.plan_tree(m, str(mp))


def test_manifest_paths_resolve_relative_to_the_manifest(tmp_path):
    mp = make_export(tmp_path)
    data = json.loads(mp.read_text())
    plan = P.plan_tree(data, str(mp))
    atlas = next(i for i in plan.images if i.name == "NA_Atlas_Foreground")
    assert atlas.filepath == str(mp.parent / "atlases" / "Foreground.png")


# --- mask maths ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("w", "h"), [(854, 480), (480, 854), (64, 64)])
def test_mask_space_round_trip(w, h):
    for x, y in ((0, 0), (w, h), (w / 3, h / 7)):
        u, v = mask_math.px_to_mask(x, y, w, h)
        assert mask_math.mask_to_px(u, v, w, h) == pytest.approx((x, y))
    assert mask_math.px_to_mask(w / 2, h / 2, w, h) == pytest.approx((0.5, 0.5))
    long_side = max(w, h)
    assert mask_math.px_to_mask(w, h, w, h) == pytest.approx((0.5 + w / long_side / 2, 0.5 + h / long_side / 2))


def test_reference_rasterizer_counts_pixel_centres():
    rows = mask_math.rasterize_polygon([(2, 1), (6, 1), (6, 4), (2, 4)], 8, 6)
    assert sum(map(sum, rows)) == 12
    assert rows[1][2] and not rows[0][2] and not rows[1][6]
    assert mask_math.iou(rows, rows) == 1.0


def test_mask_file_names_follow_plate_numbers():
    assert mask_math.file_number("/a/plate_0012.png") == 12
    assert mask_math.file_number("/a/clip.mov") is None
    assert mask_math.mask_file_names([1, 2], 12, 1) == ["00012.png", "00013.png"]
    assert mask_math.mask_file_names([5, 6], None, 1) == ["00000.png", "00001.png"]


def test_estimate_grows_with_frames_and_preset():
    draft = estimate.estimate_seconds("draft", 50, 854, 480)
    assert draft == pytest.approx(800 * 0.132 + 70.0, rel=0.02)  # the 60-min bench's 106 s of training + flow, eval
    assert estimate.estimate_seconds("balanced", 50, 854, 480) > draft
    assert estimate.working_size(854, 480, 768) == (768, 432)


def test_preset_menu_is_the_engines_presets():
    """The menu and the fallback estimate read the contract's budgets, the engine builds its presets with them."""
    from engine.config import PRESETS

    assert list(estimate.PRESET_STEPS) == list(PRESETS) == list(C.PRESET_STEPS)
    assert {name: steps for name, (steps, _) in estimate.PRESET_STEPS.items()} == {
        name: cfg.steps for name, cfg in PRESETS.items()
    }


def test_engine_estimate_parsed_and_preferred():
    row = {"preset": "draft", "total_seconds": 61.0, "expected_psnr": 25.7}
    text = "noise\n" + json.dumps({C.ESTIMATE_TAG: 1, "presets": [row]}) + "\n"
    rows = estimate.parse_engine_estimate(text, C.ESTIMATE_TAG)
    assert rows == {"draft": {"seconds": 61.0, "psnr": 25.7}}
    assert estimate.estimate_text("draft", rows, 999) == "about 1m01s here (engine estimate), ~25.7 dB"
    assert estimate.estimate_text("final", rows, 204) == "about 3m24s on a 2-core CPU (documented)"
    assert estimate.parse_engine_estimate("not json\n", C.ESTIMATE_TAG) == {}
