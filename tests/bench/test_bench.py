"""A seconds-long ``bench`` (``python -m bench bench``) and ``estimate`` on a tiny synthetic clip: the
JSON schema, monotone best-so-far PSNR, scores in range, the recorded ETA, the plot; how clips and per-preset
overrides are resolved; the measurement tools stay out of the product. No timed assertions, and no outcome that
depends on the machine's speed: the bench's run reads a steady training clock (``SteadyClock``)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from bench.__main__ import main as bench_main
from bench.__main__ import parse_eval_at
from bench.bench import (
    BENCH_JSON,
    BENCH_PNG,
    BENCH_TAG,
    BenchPlan,
    bench_configs,
    run_bench,
)
from bench.bench_clip import resolve_clip
from bench.finished_fit import fit_eta_errors
from bench.tracking import Tracks, save_tracks
from engine import contract as C
from engine.cli import main
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.errors import InputError
from engine.fit import trainer as trainer_module
from engine.fit.estimate import BENCHMARK_TABLE
from engine.fit.eta import StepClock
from engine.fit.fit_inputs import FitInputs
from engine.fit.run_folder import RunFolder
from engine.terms.protocol import progress_line
from engine.terms.run_folder import BG_MOTIONS, RUN_LOG
from engine.terms.versions import SCHEMA_VERSION

SPEC = SceneSpec(width=64, height=48, frames=6, fg_size=(24, 18), fg_start=(12.0, 10.0), fg_velocity=(3.0, 1.0))
TINY = ["--threads", "1", "--set", "batch=400", "--set", "paper.batch=300", "--set", "paper.pretrain_iters=2"]


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    """``clip/frames``, ``clip/masks`` and ground-truth ``clip/tracks_tapvid.npz`` (the shared-data layout)."""
    root = tmp_path_factory.mktemp("bench") / "synth"
    scene = make_scene(SPEC)
    write_scene(scene, root)
    tex = np.array([[12.0, 9.0], [6.3, 8.2], [17.5, 10.4]])
    xy = np.stack([np.stack([scene.fg_point_in_frame(p, f) for f in range(SPEC.frames)]) for p in tex]) + 0.5
    occluded = np.zeros((3, SPEC.frames), bool)
    occluded[2, 4:] = True
    query = np.c_[[0, 2, 0], xy[[0, 1, 2], [0, 2, 0]]].astype(np.float32)
    save_tracks(root / "tracks_tapvid.npz", Tracks(xy.astype(np.float32), occluded, query, (SPEC.width, SPEC.height)))
    return root


class SteadyClock:
    """The trainer's ``time`` module with a ``perf_counter`` that advances TICK seconds per reading, so a step
    (read at its start and end) costs TICK training seconds on any machine under any load: whether a run ends by
    its steps or by the budget is then the bench's logic alone, not the machine's speed."""

    TICK = 0.025

    def __init__(self) -> None:
        self.now = 0.0

    def perf_counter(self) -> float:
        self.now += self.TICK
        return self.now

    def __getattr__(self, name: str):
        return getattr(time, name)


@pytest.fixture(scope="module")
def bench_record(clip, tmp_path_factory) -> tuple[dict, Path, str]:
    out = tmp_path_factory.mktemp("bench_out")
    args = ["bench", str(clip), "--presets", "draft,paper", "--budget-seconds", "2", "--out", str(out)]
    args += ["--evals", "3", "--eval-frames", "2", "--slice-seconds", "0.5", "--set", "draft.steps=12", *TINY]
    with pytest.MonkeyPatch.context() as mp:  # draft: 12 steps = 0.3 training s; paper: stopped at 2 s = 80 steps
        mp.setattr(trainer_module, "time", SteadyClock())
        assert bench_main(args) == C.EXIT_OK
    return json.loads((out / BENCH_JSON).read_text()), out, " ".join(args)


@pytest.mark.slow
def test_bench_json_schema(bench_record):
    rec, _, _ = bench_record
    assert rec[BENCH_TAG] == 1
    for key in ("created", "command", "machine", "versions", "settings", "clips", "runs", "peak_rss_mb"):
        assert key in rec
    assert {"cpu", "cores", "torch_threads", "load_average_at_start"} <= set(rec["machine"])
    assert {"engine", "torch", "numpy", "python"} <= set(rec["versions"])
    assert rec["settings"]["budget_seconds"] == 2.0 and rec["settings"]["mode"] == "interleaved"
    assert rec["command"][:4] == ["python", "-m", "bench", "bench"]
    (clip,) = rec["clips"]
    assert clip["name"] == "synth" and clip["working_size"] == [SPEC.width, SPEC.height]
    assert clip["eval_frames"] == [0, SPEC.frames - 1] and clip["track_queries"] == 3
    assert {"delta_avg", "delta", "scored_points", "coords", "delta_avg_256"} <= set(clip["tracking_baseline"])
    assert [r["preset"] for r in rec["runs"]] == ["draft", "paper"]
    for run in rec["runs"]:
        assert {"clip", "model", "steps", "train_seconds", "params", "curve", "eta", "config"} <= set(run)
        assert run["curve"], "every run is evaluated at least once"
        for point in run["curve"]:
            assert {
                "train_seconds",
                "step",
                "psnr",
                "best_psnr",
                "consistency_texels",
                "tracking",
                "eval_seconds",
                "rss_mb",
                "peak_rss_mb",
            } <= set(point)
            assert point["peak_rss_mb"] > 0


@pytest.mark.slow
def test_bench_curves_are_monotone_and_in_range(bench_record):
    rec, _, _ = bench_record
    for run in rec["runs"]:
        curve = run["curve"]
        best = [p["best_psnr"] for p in curve]
        assert best == sorted(best), "best-so-far PSNR never decreases"
        assert all(b >= p["psnr"] - 1e-9 for b, p in zip(best, curve, strict=True))
        times = [p["train_seconds"] for p in curve]
        assert times == sorted(times) and len(set(times)) == len(times)
        for p in curve:
            assert 0.0 <= p["tracking"]["delta_avg"] <= 1.0
            assert p["consistency_texels"] >= 0.0 and p["consistency_pixels"] > 0
            assert np.isfinite(p["psnr"])


@pytest.mark.slow
def test_bench_stops_at_steps_or_budget_and_records_the_eta(bench_record):
    rec, _, _ = bench_record
    draft, paper = rec["runs"]
    assert draft["finished_steps"] and draft["steps"] == 12  # done before the budget: its steps ran out
    assert [e["fraction"] for e in draft["eta"]] == [0.1, 0.25, 0.5]
    for e in draft["eta"]:
        assert e["actual_seconds"] > 0
        # both seconds are rounded to 1 ms: the recomputed ratio is exact only to about 1 ms / actual
        tol = 2e-3 + 2e-3 / e["actual_seconds"]
        assert e["error_mean"] == pytest.approx(e["eta_mean_seconds"] / e["actual_seconds"] - 1, abs=tol)
        assert (e["error"] is None) == (e["step"] == 1)  # the fit's ETA leaves the warm-up step out
    assert not paper["finished_steps"] and paper["train_seconds"] >= 2.0  # the budget ended it
    assert all("error" not in e for e in paper["eta"])


@pytest.mark.slow
def test_bench_writes_a_plot(bench_record):
    _, out, _ = bench_record
    assert (out / BENCH_PNG).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_estimate_json(clip, capsys):
    args = ["estimate", str(clip / "frames"), "--mask", str(clip / "masks"), "--presets", "draft,balanced"]
    assert main([*args, "--calib-seconds", "0.05", "--json", "--threads", "1", "--set", "batch=300"]) == C.EXIT_OK
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result[C.ESTIMATE_TAG] == SCHEMA_VERSION
    draft, balanced = result["presets"]
    assert (draft["preset"], draft["expected_psnr"]) == ("draft", BENCHMARK_TABLE["draft"]["psnr"])
    assert balanced["expected_psnr"] == BENCHMARK_TABLE["balanced"]["psnr"]
    assert "blackswan" in balanced["expected_psnr_note"]
    for row in (draft, balanced):
        assert row["total_seconds"] >= row["train_seconds"] > 0
        assert row["minutes"] == pytest.approx(row["total_seconds"] / 60, abs=0.06)
    assert balanced["train_seconds"] > draft["train_seconds"]  # 7.5x the steps at about the same cost


def test_estimate_table(clip, capsys):
    args = ["estimate", str(clip / "frames"), "--mask", str(clip / "masks"), "--presets", "draft"]
    assert main([*args, "--calib-seconds", "0.02", "--threads", "1", "--set", "batch=200"]) == C.EXIT_OK
    out = capsys.readouterr().out
    assert "| draft | fast | 800 |" in out and f"{BENCHMARK_TABLE['draft']['psnr']:.2f} dB" in out


def test_resolve_clip_layouts(clip):
    a = resolve_clip(clip)
    assert (a.name, a.frames.name, [m.name for m in a.masks], a.tracks.name) == (
        "synth",
        "frames",
        ["masks"],
        "tracks_tapvid.npz",
    )
    b = resolve_clip(clip / "frames", [clip / "masks"])
    assert (b.name, b.tracks) == ("synth", a.tracks)
    with pytest.raises(InputError):
        resolve_clip(clip / "nowhere")


def test_per_preset_overrides():
    draft, paper = bench_configs(["draft", "paper"], {"batch": "100", "paper.steps": "7"})
    assert (draft.batch, paper.batch, draft.steps, paper.steps) == (100, 100, 800, 7)
    with pytest.raises(InputError, match="not one of the benched presets"):
        bench_configs(["draft"], {"final.steps": "3"})
    with pytest.raises(InputError, match="long_edge"):
        bench_configs(["draft", "paper"], {"paper.long_edge": "100"})


def test_eta_error_of_a_fit_log(tmp_path):
    """Steps that get cheaper after the first half: the early ETA overestimates, the error says by how much."""
    lines = [progress_line(C.EVENT_STAGE, stage="train", message="x")]
    for step, elapsed in ((10, 20.0), (50, 100.0)):  # 2 s/step so far
        lines.append(progress_line(C.EVENT_PROGRESS, step=step, total=100, elapsed=elapsed, eta=(100 - step) * 2.0))
    (tmp_path / RUN_LOG).write_text("\n".join(lines) + "\n")
    metrics = {"psnr": 20.0, "mse": 0.01, "alpha_iou": [], "steps": 100, "train_seconds": 150.0}  # 2nd half: 1 s/step
    metrics |= {"seconds_per_step": 1.5, "preset": "draft", "model": "fast", "device": "cpu", "working_size": [8, 8]}
    RunFolder(tmp_path).write_metrics({**metrics, "frames": 2, "engine_version": "x", "torch_version": "y"})
    rows = fit_eta_errors(tmp_path)
    assert [(r["step"], r["eta_seconds"], r["actual_seconds"]) for r in rows] == [(10, 180.0, 130.0), (50, 100.0, 50.0)]
    assert rows[1]["error"] == pytest.approx(1.0) and rows[0]["fraction"] == 0.1


def test_expected_psnr_is_recorded_from_a_finished_fit(tmp_path):
    """``estimate``'s expected PSNR is data written from a fit's metrics.json, not numbers typed into code."""
    import shutil

    from bench.finished_fit import record_expected_psnr
    from engine.fit.estimate import EXPECTED_PSNR_FILE

    table = tmp_path / "expected_psnr.json"
    shutil.copy(EXPECTED_PSNR_FILE, table)
    metrics = {"psnr": 26.123, "mse": 0.01, "alpha_iou": [0.9], "steps": 800, "train_seconds": 150.0}
    metrics |= {"seconds_per_step": 0.19, "preset": "draft", "model": "fast", "device": "cpu", "working_size": [8, 8]}
    RunFolder(tmp_path / "run").write_metrics({**metrics, "frames": 2, "engine_version": "x", "torch_version": "y"})
    row = record_expected_psnr("draft", tmp_path / "run", "blackswan", "docs/engine.md", table)
    assert row == {"psnr": 26.12, "clip": "blackswan", "note": "docs/engine.md"}
    assert json.loads(table.read_text())["presets"]["draft"] == row
    with pytest.raises(InputError, match="not balanced"):
        record_expected_psnr("balanced", tmp_path / "run", "blackswan", "x", table)


def test_step_clock_extrapolates_each_regime_at_its_own_rate():
    clock = StepClock(boundary=4)
    assert clock.eta(0, 10) is None
    clock.add(0, 9.0)  # warm-up step: not a rate
    assert clock.eta(1, 10) is None
    for step in (1, 2, 3):
        clock.add(step, 2.0)
    assert clock.eta(4, 10) == pytest.approx(6 * 2.0)  # the late regime is not reached: assume the same rate
    for step in (4, 5):
        clock.add(step, 1.0)
    assert clock.eta(6, 10) == pytest.approx(4 * 1.0)
    assert clock.eta(2, 10) == pytest.approx(2 * 2.0 + 6 * 1.0)
    assert clock.eta(10, 10) == 0.0


def test_step_clock_scales_an_unreached_regime_by_the_measured_ratio():
    clock = StepClock(boundary=4, late_ratio=0.5)
    clock.add(0, 9.0)
    for step in (1, 2, 3):
        clock.add(step, 2.0)
    assert clock.eta(4, 10) == pytest.approx(6 * 2.0 * 0.5)  # late steps measured at half the cost
    resumed = StepClock(boundary=4, late_ratio=0.5)  # a resume past the boundary: the early rate is derived
    for step in (6, 7, 8):
        resumed.add(step, 1.0)
    assert resumed.rate(0) == pytest.approx(2.0) and resumed.eta(9, 10) == pytest.approx(1.0)
    for bad in (0.0, -1.0, float("inf"), float("nan")):  # guarded: an unusable ratio falls back to the same rate
        c = StepClock(boundary=4, late_ratio=bad)
        for step in (0, 1):
            c.add(step, 2.0)
        assert c.eta(4, 10) == pytest.approx(12.0)


def test_regime_cost_ratio_leaves_the_fit_untouched(clip):
    """The probe times both regimes without changing the model, its gradients or the fit's random state."""
    from engine.config import apply_overrides, preset_config
    from engine.data.video import build_video_tensors
    from engine.fit.model_build import build_model
    from engine.fit.prepare import prepare_clip
    from engine.fit.trainer import regime_cost_ratio

    cfg = apply_overrides(preset_config("draft"), {"batch": "300"})
    prepared = prepare_clip(FitInputs(clip / "frames", [clip / "masks"]), cfg, clip / "work")
    cpu = torch.device("cpu")
    video = build_video_tensors(prepared.frames, prepared.masks, prepared.flow, cfg.mask_prior_margin_px, cpu)
    model = build_model(cfg, prepared)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    ratio = regime_cost_ratio(model, video, cfg, cpu)
    # the late regime drops the global-rigidity passes; the ratio is timed, so on a machine shared with other work
    # only its sign and its upper bound say anything (0.06 was measured with three fits running beside it)
    assert ratio is not None and 0.0 < ratio < 2.0
    assert all(torch.equal(before[k], v) for k, v in model.state_dict().items())
    assert all(p.grad is None for p in model.parameters())
    assert regime_cost_ratio(model, video, apply_overrides(cfg, {"global_rigidity_steps": "0"}), cpu) is None
    paper_like = apply_overrides(cfg, {"steps": "400000", "global_rigidity_steps": "5000"})
    assert regime_cost_ratio(model, video, paper_like, cpu) is None  # 1.25%: not worth probing
    tiny = apply_overrides(cfg, {"steps": "24", "global_rigidity_steps": "12"})
    assert regime_cost_ratio(model, video, tiny, cpu) is None  # five probe steps would be 20% of this fit


def test_sequential_bench_runs_presets_in_turn(clip, tmp_path):
    spec = resolve_clip(clip)
    plan = BenchPlan(("draft", "final"), 30.0, {"steps": "4", "batch": "200"}, evals=1, eval_frames=0,
                     eval_at_start=True, sequential=True, device_name="cpu", threads=1)  # fmt: skip
    rec = run_bench([spec], plan, tmp_path, plot=False)
    assert rec["settings"]["mode"] == "sequential" and rec["clips"][0]["eval_frames"] == list(range(SPEC.frames))
    for run in rec["runs"]:
        assert run["finished_steps"] and run["steps"] == 4  # its steps ended it, long before the budget
        assert [p["step"] for p in run["curve"]] == [0, 4]  # before the first step, and at the end
    assert not (tmp_path / BENCH_PNG).exists() and (tmp_path / BENCH_JSON).exists()


def test_eval_schedule_adds_the_target_marks_within_the_budget():
    from bench.bench import _eval_schedule

    assert _eval_schedule(3600.0, 2, parse_eval_at("180, 600,1200,3600,9000")) == [112.5, 180.0, 600.0, 1200.0, 3600.0]
    assert _eval_schedule(60.0, 1) == [60.0]
    with pytest.raises(InputError, match="--eval-at"):
        parse_eval_at("3min")


@pytest.mark.slow
def test_the_tools_run_outside_the_product_cli(clip, tmp_path, capsys):
    """``bench``, ``speed`` and ``scene-speed`` are ``python -m bench`` tools: the product CLI has no such
    verbs, and nothing in the product (engine/ outside bench, which the extension zip leaves out) imports
    the bench."""
    import ast

    from engine.cli import build_parser
    from tests.paths import ROOT

    sub = next(a for a in build_parser()._actions if a.dest == "verb")
    assert not {"bench", "speed", "scene-speed"} & set(sub.choices)
    for py in (ROOT / "engine").rglob("*.py"):
        if "bench" in py.relative_to(ROOT / "engine").parts:
            continue
        for node in ast.walk(ast.parse(py.read_text(encoding="utf-8"))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom):
                names = [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names]
            assert not any(n.startswith("bench") for n in names), f"{py} imports the bench"
    args = [str(clip / "frames"), "--mask", str(clip / "masks"), "--presets", "draft,paper", "--steps", "1"]
    assert bench_main(["speed", *args, "--rounds", "1", "--device", "cpu", "--work", str(tmp_path)]) == C.EXIT_OK
    table = capsys.readouterr().out
    assert "| draft | fast |" in table and "| paper | paper |" in table
    assert bench_main(["bench", str(clip), "--budget-seconds", "1", "--eval-at", "3min"]) == C.EXIT_BAD_INPUT
    assert "--eval-at" in capsys.readouterr().err
    scene_args = [str(clip / "frames"), "--mask", str(clip / "masks"), "--steps", "2", "--out", str(tmp_path / "s")]
    assert bench_main(["scene-speed", *scene_args]) == C.EXIT_OK
    res = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert res["steps"] == 2 and res["auto"]["background_motion"] in BG_MOTIONS and res["speedup"] > 0


def test_speed_times_a_preset_beside_its_variant(clip, tmp_path, capsys):
    """``--presets draft,draft:KEY=VALUE`` times a candidate change beside the preset it changes, each entry its own
    row and model: the wider foreground mapping has more parameters, the background's is untouched; a bad key is
    one line."""
    from bench.speed import measure_step_times

    rows = measure_step_times(
        clip / "frames", [clip / "masks"], ["draft", "draft:mapping_hidden_fg=96"], tmp_path, steps=1, rounds=1,
        device_name="cpu", at_step=10_000,
    )  # fmt: skip
    assert [r.preset for r in rows] == ["draft", "draft:mapping_hidden_fg=96"]
    assert rows[1].params > rows[0].params and all(r.seconds_per_step > 0 for r in rows)
    args = [str(clip / "frames"), "--mask", str(clip / "masks"), "--presets", "draft:no_such_key=1", "--steps", "1"]
    assert bench_main(["speed", *args, "--device", "cpu", "--work", str(tmp_path)]) == C.EXIT_BAD_INPUT
    assert "no_such_key" in capsys.readouterr().err
    args[-3] = "draft,draft:long_edge=32"  # one prepared clip: the entries must share its working size
    assert bench_main(["speed", *args, "--device", "cpu", "--work", str(tmp_path)]) == C.EXIT_BAD_INPUT
    assert "long_edge" in capsys.readouterr().err
