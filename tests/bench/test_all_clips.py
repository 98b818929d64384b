"""``python -m bench clips`` end to end on two tiny synthetic clip folders, a few steps each: degraded masks
written per clip, every clip fitted and scored against its own precise masks, the markdown table and the JSON
agree with each other and with each clip's bench record."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from bench.__main__ import main as bench_main
from bench.all_clips import CLIPS_JSON, CLIPS_MD, COLUMNS, find_clips, format_table
from bench.bench import BENCH_JSON
from bench.degrade import dropped_frames, read_gt
from bench.tracking import Tracks, save_tracks
from engine import contract as C
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.errors import InputError

SPECS = {
    "alpha": SceneSpec(width=64, height=48, frames=6, fg_size=(24, 18), fg_start=(12.0, 10.0)),
    "beta": SceneSpec(width=64, height=48, frames=5, fg_size=(20, 20), fg_start=(30.0, 14.0), seed=3),
}
RECIPE = "dilated10_dropped10"


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    """Two clip folders (alpha with ground-truth tracks, beta without) and a folder that is not a clip."""
    base = tmp_path_factory.mktemp("clips")
    for name, spec in SPECS.items():
        scene = make_scene(spec)
        write_scene(scene, base / name)
        if name == "alpha":
            tex = np.array([[12.0, 9.0], [6.3, 8.2]])
            xy = np.stack([np.stack([scene.fg_point_in_frame(p, f) for f in range(spec.frames)]) for p in tex]) + 0.5
            query = np.c_[[0, 2], xy[[0, 1], [0, 2]]].astype(np.float32)
            occluded = np.zeros((2, spec.frames), bool)
            save_tracks(base / name / "tracks_tapvid.npz", Tracks(xy.astype(np.float32), occluded, query, (64, 48)))
    (base / "notes").mkdir()
    return base


@pytest.fixture(scope="module")
def result(root, tmp_path_factory) -> tuple[Path, str]:
    out = tmp_path_factory.mktemp("clips_out")
    args = ["clips", str(root), "--preset", "draft", "--degrade", RECIPE, "--out", str(out), "--threads", "1"]
    args += ["--set", "steps=4", "--set", "batch=200", "--device", "cpu"]
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert bench_main(args) == C.EXIT_OK
    return out, buf.getvalue()


def test_every_clip_gets_its_degraded_masks(root, result):
    out, _ = result
    assert [p.name for p in find_clips(root)] == ["alpha", "beta"]
    for name, spec in SPECS.items():
        folder = out / "masks" / RECIPE / name
        names = sorted(p.name for p in (root / name / "masks").iterdir())
        assert sorted(p.name for p in folder.iterdir()) == names
        deg = np.stack([read_gt(folder / n) for n in names])
        empty = [t for t in range(spec.frames) if not deg[t].any()]
        assert empty == dropped_frames(spec.frames, 0.1, 0)
        kept = [t for t in range(spec.frames) if t not in empty]
        assert (deg[kept] >= make_scene(spec).masks[kept]).all()


def test_the_table_json_and_bench_record_agree(root, result):
    out, stdout = result
    table = json.loads((out / CLIPS_JSON).read_text())
    assert table["benches"] == [f"runs/{name}/{BENCH_JSON}" for name in SPECS]
    benches = [json.loads((out / b).read_text()) for b in table["benches"]]
    assert table["preset"] == "draft" and table["degrade"] == RECIPE and table["seed"] == 0
    assert table["degradation"]["dilate_px"] == 10 and table["degradation"]["drop_fraction"] == 0.1
    rows = table["rows"]
    assert [r["clip"] for r in rows] == ["alpha", "beta"]
    for row, bench in zip(rows, benches, strict=True):
        (run,), (clip,) = bench["runs"], bench["clips"]
        last = run["curve"][-1]
        assert clip["score_masks"] == [str((root / row["clip"] / "masks").resolve())]
        assert clip["masks"] == [str((out / "masks" / RECIPE / row["clip"]).resolve())]
        assert run["steps"] == row["steps"] == 4 and run["finished_steps"] and len(run["curve"]) == 1
        assert row["psnr"] == last["psnr"] and np.isfinite(row["psnr"])
        assert row["fg_iou"] == last["fg_iou"] and 0.0 <= row["fg_iou"] <= 1.0
        assert row["train_seconds"] == run["train_seconds"] > 0
        # the masks the fit was given, scored like the fit: their IoU against the precise ones, and the snap
        deg = np.stack([read_gt(p) for p in sorted((out / "masks" / RECIPE / row["clip"]).iterdir())])
        gt = make_scene(SPECS[row["clip"]]).masks
        has = deg.any((1, 2))
        assert row["mask_iou"] == pytest.approx((deg & gt)[has].sum() / (deg | gt)[has].sum(), abs=1e-9)
        assert row["mask_iou"] < 0.9  # the recipe's 10 px on a small object
        assert row["snap_px"] == clip["mask_snap_px"][0] <= 0
        assert row["prior_coverage"] == clip["prior_coverage"][0] and 0.0 <= row["prior_coverage"] <= 1.0
    alpha, beta = rows
    assert 0.0 <= alpha["atlas_delta_avg"] <= 1.0 and 0.0 <= alpha["flow_delta_avg"] <= 1.0
    assert alpha["flow_delta_avg"] == benches[0]["clips"][0]["tracking_baseline"]["delta_avg"]
    assert beta["atlas_delta_avg"] is None and beta["flow_delta_avg"] is None  # beta has no tracks
    assert table["mean"]["fg_iou"] == pytest.approx((alpha["fg_iou"] + beta["fg_iou"]) / 2, abs=1e-4)
    assert table["mean"]["atlas_delta_avg"] == pytest.approx(alpha["atlas_delta_avg"], abs=1e-4)

    md = (out / CLIPS_MD).read_text()
    assert md.strip() == format_table(table) and md.strip() in stdout
    lines = [ln for ln in md.splitlines() if ln.startswith("| ")]
    assert lines[0] == "| " + " | ".join(h for h, _ in COLUMNS) + " |"
    cells = {ln.split(" | ")[0][2:]: [c.strip(" |") for c in ln.split(" | ")[1:]] for ln in lines[1:]}
    assert list(cells) == ["alpha", "beta", "mean"]
    for row in rows:
        given, snap, cover, psnr, iou, atlas, flow, secs = cells[row["clip"]]
        assert float(given) == pytest.approx(row["mask_iou"], abs=0.0005) and int(snap) == row["snap_px"]
        assert float(cover) == pytest.approx(row["prior_coverage"], abs=0.005)
        assert float(psnr) == pytest.approx(row["psnr"], abs=0.005)
        assert float(iou) == pytest.approx(row["fg_iou"], abs=0.0005)
        assert float(secs) == pytest.approx(row["train_seconds"], abs=0.5)
        if row["atlas_delta_avg"] is None:
            assert atlas == flow == "–"
        else:
            assert float(atlas) == pytest.approx(row["atlas_delta_avg"], abs=0.0005)
            assert float(flow) == pytest.approx(row["flow_delta_avg"], abs=0.0005)


def test_a_folder_without_clips_is_refused(tmp_path, capsys):
    with pytest.raises(InputError, match="no clip folder"):
        find_clips(tmp_path)
    assert bench_main(["clips", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == C.EXIT_BAD_INPUT
    assert "is not a folder" in capsys.readouterr().err
