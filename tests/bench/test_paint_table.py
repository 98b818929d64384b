"""`bench paint-table`: a tiny turning scene fitted, exported and scored through the product's own commands. Its
numbers are the scorers' own on that export, the exported foreground's IoU is the fit's (same resolution), a
second run fits nothing, and the picture shows the checkerboard above the flow's dots. The IoU and the
true-texture ceiling are also checked on inputs whose answer is known by hand."""

from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from bench.__main__ import main as bench_main
from bench.flow_tracks import score_clip
from bench.motion_scenes import TEXTURE_PNG, write_motion_clips
from bench.paint_picture import draw_dots, grid_points, picture_frames
from bench.paint_slip import export_slip
from bench.paint_table import PAINT_JSON, PAINT_MD, TableFit, export_fg_iou, run_paint_table, true_sharpness
from bench.paint_tracking import score_export
from bench.report_file import read_tracks
from bench.sharpness import atlas_sharpness
from engine import contract as C
from engine.edit.preview import TILE_W
from engine.io.images import read_image, write_png
from engine.terms.cli import EXPORT_FOLLOW_FLOW_FLAG
from engine.terms.run_folder import AUTO_PARTS_DIR, FIT_AUTO_PARTS_FLAG
from tests.engine.fake_export import make_fake_export

STEPS = ("steps=100", "bootstrap_steps=100", "global_rigidity_steps=20")


@pytest.fixture(scope="module")
def scene_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("scenes")
    write_motion_clips(root, width=96, height=64, frames=6, kinds=("turning_depth",))
    return root


@pytest.fixture(scope="module")
def table(scene_root, tmp_path_factory) -> tuple[dict, Path]:
    out = tmp_path_factory.mktemp("paint")
    return run_paint_table(scene_root, out, TableFit(sets=STEPS, threads=1), pictures=True, log=lambda _: None), out


@pytest.mark.slow
def test_the_rows_are_the_scorers_on_the_export(scene_root, table):
    record, out = table
    (row,) = record["rows"]
    clip = scene_root / "turning_depth"
    tracks = read_tracks(clip / "tracks_tapvid.npz")
    paint = score_export(row["manifest"], tracks)
    flow = score_clip(clip / "frames", tracks)
    sharp = atlas_sharpness(row["manifest"], clip / "frames", [clip / "masks"])
    assert row["paint"] == paint["delta_avg"] and row["paint_256"] == paint["delta_avg_256"]
    assert row["flow"] == flow["delta_avg"]
    assert row["ratio"] == pytest.approx(paint["delta_avg"] / flow["delta_avg"])
    assert row["sharpness"] == sharp["psnr_pooled"]
    # the object's points apart from the rest: every query of the scene lies on the body
    assert row["paint_object"] == paint["by_query_mask"]["on_mask"]["delta_avg"] == row["paint"]
    assert row["flow_object"] == flow["by_query_mask"]["on_mask"]["delta_avg"] == row["flow"]
    assert row["ratio_object"] == pytest.approx(row["ratio"]) and row["paint_background"] is None
    assert row["slip"] == export_slip(row["manifest"], clip / "frames")["foreground"]["median_px"]
    metrics = json.loads((out / "runs" / "turning_depth" / C.RUN_METRICS).read_text())
    assert row["psnr"] == metrics["psnr"] and row["train_seconds"] == metrics["train_seconds"]
    assert row["steps"] == 100
    # 96x64 is fitted at its own size, so the exported alpha is the fit's: the same IoU against the same masks
    assert row["fg_iou"] == pytest.approx(metrics["alpha_iou"][0], abs=2e-3)
    assert row["true_sharpness"] == pytest.approx(true_sharpness(clip))
    assert row["given_masks_iou"] == 1.0  # exact masks
    md = (out / PAINT_MD).read_text()
    assert "| turning_depth | " in md and "| mean | " in md
    assert json.loads((out / PAINT_JSON).read_text())["rows"][0]["paint"] == row["paint"]


@pytest.mark.slow
def test_a_second_run_fits_and_exports_nothing(scene_root, table):
    record, out = table
    run = out / "runs" / "turning_depth"
    before = {p: p.stat().st_mtime_ns for p in (run / "checkpoint.pt", Path(record["rows"][0]["manifest"]))}
    again = run_paint_table(scene_root, out, TableFit(sets=STEPS, threads=1), log=lambda _: None)
    assert {p: p.stat().st_mtime_ns for p in before} == before
    keep = ("paint", "flow", "fg_iou", "sharpness", "psnr", "train_seconds")
    assert [{k: r[k] for k in keep} for r in again["rows"]] == [{k: r[k] for k in keep} for r in record["rows"]]


@pytest.mark.slow
def test_the_picture_is_two_rows_of_the_first_middle_and_last_frame(table):
    record, _ = table
    picture, _ = read_image(record["rows"][0]["picture"])
    tile_h = round(64 * TILE_W / 96)
    assert picture.shape[:2] == (2 * tile_h, 3 * TILE_W)
    assert picture_frames([10, 11, 12, 13, 14, 15]) == [10, 12, 15]
    assert picture_frames([7]) == [7]


def test_the_exported_foreground_iou_is_pooled_over_frames(tmp_path):
    """Foreground alpha 0.8 on a 10x10 square that moves 2 px a frame; the masks are the same square one pixel
    lower: per frame 90 pixels shared, 110 in the union; frame 1's mask is empty (all 100 foreground pixels in
    the union). Pooled: 180 / 320."""
    w, h, t_count = 32, 24, 3
    plate = np.full((t_count, h, w, 3), 0.5, np.float32)

    def square(t: int, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
        return (xs >= 4 + 2 * t) & (xs < 14 + 2 * t) & (ys >= 5) & (ys < 15)

    def bg(t, xs, ys):
        return xs / w, 1 - ys / h, np.where(square(t, xs, ys), 0.2, 1.0)

    def fg(t, xs, ys):
        return xs / w, 1 - ys / h, np.where(square(t, xs, ys), 0.8, 0.0)

    manifest = make_fake_export(tmp_path, plate, [(bg, (w, h)), (fg, (w, h))])
    ys, xs = np.mgrid[0:h, 0:w] + 0.5
    for t in range(t_count):
        m = square(t, xs, ys - 1) if t != 1 else np.zeros((h, w), bool)
        write_png(tmp_path / "masks" / f"{t:05d}.png", m[..., None].astype(np.float32), 8, srgb=False)
    assert export_fg_iou(manifest, tmp_path / "clip", tmp_path / "masks") == pytest.approx(180 / 320)


def test_the_true_texture_is_the_ceiling_and_a_wrong_one_scores_far_below(scene_root, tmp_path):
    clip = scene_root / "turning_depth"
    ceiling = true_sharpness(clip)
    assert ceiling is not None and ceiling > 30.0  # only the plate's anti-aliased edges and 8-bit codes differ
    wrong = tmp_path / "turning_depth"
    shutil.copytree(clip, wrong)
    texture = cv2.imread(str(clip / TEXTURE_PNG))
    cv2.imwrite(str(wrong / TEXTURE_PNG), texture[:, ::-1])
    assert true_sharpness(wrong) < ceiling - 10.0
    (wrong / TEXTURE_PNG).unlink()
    assert true_sharpness(wrong) is None  # a real clip has no true texture


def test_grid_points_lie_in_the_mask_and_dots_take_their_colour():
    mask = np.zeros((40, 60), bool)
    mask[10:30, 20:50] = True
    pts, step = grid_points(mask)
    assert step == 2.0  # 30 px / DOTS_ACROSS is under the 2 px floor
    assert len(pts) > 20
    assert mask[pts[:, 1].astype(int), pts[:, 0].astype(int)].all()
    assert grid_points(np.zeros((5, 5), bool))[0].shape == (0, 2)
    frame = np.zeros((40, 60, 3), np.uint8)
    out = draw_dots(frame, np.array([[30.5, 20.5], [1e6, 5.0]]), np.array([[200, 10, 20], [1, 2, 3]]), 3.0)
    assert out[20, 30].tolist() == [200, 10, 20]
    assert out[0:2].sum() == 0 and frame.sum() == 0  # the off-frame dot is skipped; the input is not drawn on


def tiny_limbs_table(tmp_path: Path, **split: bool) -> tuple[Path, dict]:
    """A 4-frame limbs_jump scene under ``tmp_path/scenes`` and its paint table after a 20-step draft fit, split as
    ``split`` says (``parts=True`` or ``scribbles=True``); (the clips' root, the record)."""
    root = tmp_path / "scenes"
    write_motion_clips(root, width=96, height=64, frames=4, kinds=("limbs_jump",))
    sets = ("steps=20", "bootstrap_steps=20", "global_rigidity_steps=5")
    return root, run_paint_table(
        root, tmp_path / "out", TableFit.of_flags(sets=sets, threads=1, **split), log=lambda _: None
    )


@pytest.mark.slow
def test_parts_fit_one_layer_per_part_and_are_scored_as_one_foreground(tmp_path):
    root, record = tiny_limbs_table(tmp_path, parts=True)
    (row,) = record["rows"]
    assert row["layers"] == 3 and row["given_masks_iou"] is None
    layers = json.loads(Path(row["manifest"]).read_text())["layers"]
    assert [layer["name"] for layer in layers] == ["Background", "Foreground1", "Foreground2"]
    clip = root / "limbs_jump"
    assert row["fg_iou"] == export_fg_iou(row["manifest"], clip / "frames", clip / "masks")
    assert "one layer per part" in (tmp_path / "out" / PAINT_MD).read_text().splitlines()[0]


@pytest.mark.slow
def test_auto_parts_fit_an_object_that_moves_as_one_piece_as_one_layer(tmp_path):
    _, record = tiny_limbs_table(tmp_path, auto_parts=True)
    (row,) = record["rows"]
    assert record["auto_parts"] and row["layers"] == 2 and row["scribbles"] is None
    assert "nothing to split" in row["auto_parts"] and "fitted as one layer" in row["auto_parts"]  # the fit's line
    assert not (tmp_path / "out" / "runs" / "limbs_jump" / AUTO_PARTS_DIR).exists()
    assert "the strokes `fit --auto-parts` draws" in (tmp_path / "out" / PAINT_MD).read_text().splitlines()[0]


@pytest.mark.parametrize(
    ("auto_parts", "flags"),
    [(None, []), (True, [FIT_AUTO_PARTS_FLAG]), (False, [C.FIT_NO_AUTO_PARTS_FLAG])],
    ids=["the-fits-default", "auto-parts", "no-auto-parts"],
)
def test_the_fit_gets_the_split_flag_the_table_asks_for(monkeypatch, tmp_path, auto_parts, flags):
    """The table's default fits and exports as the product does (no flag: the parts wherever that applies, and the
    export's own choice of following the flow, which leaves those parts as fitted); ``--auto-parts`` and
    ``--no-auto-parts`` (``one_layer``) reach the fit as those flags, the export gets neither."""
    import bench.paint_table as paint_table

    calls: list[list[str]] = []

    def engine(args: list[str], log_path: Path, threads: int | None) -> str:
        calls.append(args)
        return str(tmp_path / "manifest.json")

    monkeypatch.setattr(paint_table, "_engine", engine)
    split = {None: None, True: "auto", False: "one"}[auto_parts]
    how = paint_table.TableFit(threads=1, split=split)
    paint_table.fit_and_export(tmp_path / "f", [tmp_path / "m"], tmp_path / "run", how, tmp_path / "log")
    fit, export = calls
    parts = {FIT_AUTO_PARTS_FLAG, C.FIT_NO_AUTO_PARTS_FLAG}
    assert [a for a in fit if a in parts] == flags and not parts & set(export)
    assert not {EXPORT_FOLLOW_FLOW_FLAG, C.EXPORT_NO_FOLLOW_FLOW_FLAG} & set(export)


def test_one_way_to_split_a_clip_at_a_time(scene_root, tmp_path):
    with pytest.raises(ValueError, match="choose one"):
        TableFit.of_flags(parts=True, auto_parts=True)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), pytest.raises(SystemExit):
        bench_main(["paint-table", str(scene_root), "--scribbles", "--auto-parts"])
    assert "not allowed with argument" in err.getvalue()
    with pytest.raises(ValueError, match="choose one"):
        TableFit.of_flags(auto_parts=True, one_layer=True)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), pytest.raises(SystemExit):
        bench_main(["paint-table", str(scene_root), "--auto-parts", "--no-auto-parts"])
    assert "not allowed with argument" in err.getvalue()


def test_an_unknown_clip_is_one_line(scene_root, tmp_path):
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = bench_main(["paint-table", str(scene_root), "--only", "dog", "--out", str(tmp_path / "o")])
    assert rc == C.EXIT_BAD_INPUT
    assert err.getvalue().strip().splitlines() == [
        f"error: {scene_root}: holds no clip dog — name clip folders that are under it"
    ]
