"""``python -m bench farm``: two tiny synthetic shots one after another and through local Dask workers.

The table names both routes with their wall times and the ratio of the two, and both routes' exports are the
same files with the same bytes (the same argv but for the run folder, the same seeds)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from bench.__main__ import main
from bench.farm import FARM_BENCH_JSON, ROUTE_DASK, ROUTE_SEQUENTIAL, export_files
from engine import contract as C
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.terms.export_names import PASSES_DIR, pass_file_name

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the farm's engines die with their worker")

TINY = ["steps=30", "batch=1000", "eval_every=10", "bootstrap_steps=10", "global_rigidity_steps=10"]


@pytest.mark.slow
def test_bench_farm_times_both_routes_and_their_exports_agree(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    clips = []
    for seed, name in enumerate(("shot-a", "shot-b")):
        write_scene(make_scene(SceneSpec(frames=6, width=96, height=64, seed=seed)), tmp_path / name)
        clips.append(str(tmp_path / name))
    out = tmp_path / "bench"
    argv = ["farm", *clips, "--out", str(out), "--cores", "1", "--export-chunk", "6"]
    for override in TINY:
        argv += ["--set", override]
    assert main(argv) == C.EXIT_OK
    printed = capsys.readouterr().out.splitlines()
    assert printed[-1] == str(out / FARM_BENCH_JSON)
    record = json.loads((out / FARM_BENCH_JSON).read_text())
    assert record["command"] == ["python -m bench", *argv]
    assert record["machine"]["cores_used"] == 1 and record["machine"]["cpu"]
    routes = record["routes"]
    assert routes[ROUTE_SEQUENTIAL]["threads_per_engine"] == 1 and routes[ROUTE_SEQUENTIAL]["workers"] == 1
    assert routes[ROUTE_DASK]["threads_per_engine"] == 1 and routes[ROUTE_DASK]["workers"] == 2
    seconds = (routes[ROUTE_SEQUENTIAL]["seconds"], routes[ROUTE_DASK]["seconds"])
    assert all(s > 0 for s in seconds)
    assert record["ratio"] == pytest.approx(seconds[0] / seconds[1], rel=1e-2)
    rows = [line for line in printed if line.startswith("| ")]
    assert rows == [
        "| route | engines at once | torch threads each | wall time (s) |",
        f"| one after another | 1 | 1 | {seconds[0]:.1f} |",
        f"| Dask, 2 workers | 2 | 1 | {seconds[1]:.1f} |",
    ]
    assert f"Ratio (one after another / Dask): **{record['ratio']:.2f}x**." in printed
    assert any(line == "Command: `python -m bench " + " ".join(argv) + "`" for line in printed)
    # both routes published one export per shot with every frame's pass; one torch thread per engine in both,
    # so the same bytes but for the manifest's creation time and training seconds
    for name in ("shot-a", "shot-b"):
        files = [export_files(out / route / "runs" / name) for route in (ROUTE_SEQUENTIAL, ROUTE_DASK)]
        passes = sorted(f for f in files[0] if f.startswith(f"{C.EXPORTS_DIR}/v001/{PASSES_DIR}/"))
        assert passes == [f"{C.EXPORTS_DIR}/v001/{PASSES_DIR}/{pass_file_name(n)}" for n in range(6)]
        assert sorted(files[0]) == sorted(files[1])
        manifest = f"{C.EXPORTS_DIR}/v001/{C.MANIFEST_NAME}"
        assert [f for f in files[0] if files[0][f] != files[1][f]] == [manifest]
        psnr = record["exports"][name]["psnr"]
        assert isinstance(psnr[0], float) and psnr[0] == psnr[1]
        assert record["exports"][name] == {
            "files": len(files[0]),
            "same_files": True,
            "identical_files": len(files[0]) - 1,
            "max_float_diff": 0.0,
            "max_png_diff": 0.0,
            "psnr": psnr,
        }
    psnr = record["exports"]["shot-a"]["psnr"][0]
    summary = f"shot-a: the same files, 11/12 byte for byte, values within 0, PSNR {psnr:.2f} / {psnr:.2f} dB; "
    assert any(line.startswith("Exports of the two routes (one after another / Dask): " + summary) for line in printed)
