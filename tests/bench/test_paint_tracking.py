"""Paint tracking scored on an export, on hand-made exports whose UVs are known exactly: a textured square
translating by a sub-pixel step each frame (UV = (x - x0 - t * v) / side) over a static background. Exact UVs must
give delta_avg 1.0; UVs shifted by 3 px after the first frame must give exactly the thresholds 3 px passes; a frame
where the square's layer covers nothing must count as a miss."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from bench.__main__ import main as bench_main
from bench.paint_tracking import (
    MAX_STEP_PX,
    MISS,
    UV_JACOBIAN_MIN_DET,
    nearest_positions,
    score_export,
)
from bench.report_file import REPORT_TAG
from bench.tracking import Tracks, save_tracks
from engine import contract as C
from tests.engine.fake_export import make_fake_export

W, H, T = 64, 48, 6
SIDE = 20.0  # the square's side in pixels; its atlas is SIDE x SIDE texels, one texel per pixel
X0, Y0 = 10.0, 10.0  # its top-left corner at frame 0
V = np.array([2.5, 1.25])  # pixels per frame: sub-pixel, so the answer needs the sub-pixel step
#: Points on the square, 4+ px inside its edges in every frame (the shifted export moves them 3 px right).
FG_POINTS = np.array([[14.3, 15.1], [20.0, 20.0], [24.7, 26.2], [16.6, 25.4]])
#: A background point the square never reaches.
BG_POINT = np.array([[55.2, 40.7]])


def _square(t: int, xs: np.ndarray, ys: np.ndarray, shift: float, empty_frame: int | None) -> tuple:
    left, top = X0 + t * V[0], Y0 + t * V[1]
    inside = (xs >= left) & (xs < left + SIDE) & (ys >= top) & (ys < top + SIDE)
    if t == empty_frame:
        inside = np.zeros_like(inside)
    u = (xs - left - (shift if t >= 1 else 0.0)) / SIDE
    v = 1.0 - (ys - top) / SIDE  # v up
    return u, v, inside.astype(np.float32)


def _export(folder: Path, shift: float = 0.0, empty_frame: int | None = None) -> Path:
    def background(t, xs, ys):
        return xs / W, 1.0 - ys / H, 1.0 - _square(t, xs, ys, 0.0, empty_frame)[2]

    def foreground(t, xs, ys):
        return _square(t, xs, ys, shift, empty_frame)

    plate = np.full((T, H, W, 3), 0.5, np.float32)
    return make_fake_export(folder, plate, [(background, (W, H)), (foreground, (int(SIDE), int(SIDE)))])


def _tracks(points: np.ndarray, query_t: int = 0, occluded_frame: int | None = None) -> Tracks:
    """Ground truth: each point moves with its layer (the square's by V, the background's not)."""
    n = len(points)
    on_square = np.array([p[0] < 40.0 for p in points])
    steps = (np.arange(T) - query_t)[None, :, None] * V[None, None, :]
    xy = points[:, None, :] + np.where(on_square[:, None, None], steps, 0.0)
    occluded = np.zeros((n, T), bool)
    if occluded_frame is not None:
        occluded[:, occluded_frame] = True
    query = np.c_[np.full(n, query_t), xy[:, query_t]].astype(np.float32)
    return Tracks(xy.astype(np.float32), occluded, query, (W, H), on_square)


def test_exact_uvs_track_paint_exactly(tmp_path):
    manifest = _export(tmp_path)
    report = score_export(manifest, _tracks(np.r_[FG_POINTS, BG_POINT]))
    assert report["delta_avg"] == 1.0 and report["delta_avg_256"] == 1.0
    assert report["scored_points"] == 5 * (T - 1)
    assert report["misses"] == 0
    assert report["owners"] == {"Background": 1, "Foreground": 4}
    assert all(band["median_px"] is None or band["median_px"] < 1e-3 for band in report["by_gap"])


def test_queries_in_a_middle_frame_track_both_ways(tmp_path):
    points = FG_POINTS + 2 * V  # the same points of the square, queried at frame 2
    report = score_export(_export(tmp_path), _tracks(points, query_t=2))
    assert report["delta_avg"] == 1.0 and report["misses"] == 0


def test_uvs_shifted_three_pixels_pass_only_the_larger_thresholds(tmp_path):
    """Every prediction after frame 0 lands 3 px right of the truth: native thresholds 4, 8, 16 of 1..16 pass
    (0.6); at 256x256 the 3 px are 12 (x * 256 / 64), so only 16 passes (0.2)."""
    report = score_export(_export(tmp_path, shift=3.0), _tracks(FG_POINTS))
    assert report["delta"] == {"1": 0.0, "2": 0.0, "4": 1.0, "8": 1.0, "16": 1.0}
    assert report["delta_avg"] == pytest.approx(0.6, abs=1e-12)
    assert report["delta_avg_256"] == pytest.approx(0.2, abs=1e-12)
    assert report["by_gap"][0]["median_px"] == pytest.approx(3.0, abs=1e-3)


def test_a_frame_the_layer_does_not_cover_is_a_miss(tmp_path):
    report = score_export(_export(tmp_path, empty_frame=3), _tracks(FG_POINTS))
    assert report["misses"] == len(FG_POINTS)
    assert report["delta_avg"] == pytest.approx(4 / 5, abs=1e-12)  # 4 of 5 scored frames, each exact


def test_occluded_positions_are_not_scored(tmp_path):
    report = score_export(_export(tmp_path, empty_frame=3), _tracks(FG_POINTS, occluded_frame=3))
    assert report["misses"] == 0 and report["delta_avg"] == 1.0
    assert report["scored_points"] == len(FG_POINTS) * (T - 2)


def test_a_linear_uv_field_is_inverted_to_the_sub_pixel():
    ys, xs = np.mgrid[0:16, 0:16] + 0.5
    uv = np.stack((0.8 * xs + 0.3 * ys, -0.2 * xs + 1.1 * ys), -1)
    truth = np.array([[5.3, 7.9], [10.45, 3.6]])
    targets = np.stack((0.8 * truth[:, 0] + 0.3 * truth[:, 1], -0.2 * truth[:, 0] + 1.1 * truth[:, 1]), -1)
    got = nearest_positions(uv, np.ones((16, 16), bool), targets)
    np.testing.assert_allclose(got, truth, atol=1e-9)


def test_a_near_singular_jacobian_takes_no_step():
    """UVs that barely change with the pixel (det = 1e-8, below UV_JACOBIAN_MIN_DET): the nearest pixel's centre is
    the answer, not a step through a near-singular solve."""
    ys, xs = np.mgrid[0:8, 0:8] + 0.5
    scale = 1e-4
    assert scale * scale < UV_JACOBIAN_MIN_DET
    uv = np.stack((scale * xs, scale * ys), -1)
    got = nearest_positions(uv, np.ones((8, 8), bool), np.array([[scale * 3.2, scale * 4.9]]))
    np.testing.assert_array_equal(got, [[3.5, 4.5]])


def test_the_sub_pixel_step_is_bounded():
    """A target beyond every owned pixel's UV (the field ends): the step stops MAX_STEP_PX past the nearest pixel."""
    ys, xs = np.mgrid[0:8, 0:8] + 0.5
    uv = np.stack((xs, ys), -1)
    got = nearest_positions(uv, np.ones((8, 8), bool), np.array([[20.0, 4.5]]))
    np.testing.assert_allclose(got, [[7.5 + MAX_STEP_PX, 4.5]])


def test_no_owned_pixel_gives_the_miss_position():
    got = nearest_positions(np.zeros((4, 4, 2)), np.zeros((4, 4), bool), np.zeros((2, 2)))
    assert np.all(got == MISS)


def _run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = bench_main(list(argv))
    return rc, out.getvalue(), err.getvalue()


def test_cli_prints_and_writes_the_scores_and_refuses_a_file_it_did_not_write(tmp_path):
    manifest = _export(tmp_path)
    npz = tmp_path / "tracks_tapvid.npz"
    save_tracks(npz, _tracks(FG_POINTS))
    out = tmp_path / "paint.json"
    rc, stdout, _ = _run("paint-tracks", str(manifest), "--tracks", str(npz), "--json", str(out))
    assert rc == C.EXIT_OK
    assert stdout.splitlines()[0].startswith("paint-tracks: delta_avg 1.000 (native px), 1.000 (256x256), 20 positions")
    record = json.loads(out.read_text())
    assert record[REPORT_TAG] == 1 and record["tool"] == "paint-tracks" and record["delta_avg"] == 1.0
    assert _run("paint-tracks", str(manifest), "--tracks", str(npz), "--json", str(out))[0] == C.EXIT_OK
    mine = tmp_path / "mine.json"
    mine.write_text('{"mine": true}')
    rc, _, err = _run("paint-tracks", str(manifest), "--tracks", str(npz), "--json", str(mine))
    assert rc == C.EXIT_BAD_INPUT and len(err.strip().splitlines()) == 1 and "is not a paint-tracks report" in err
    assert mine.read_text() == '{"mine": true}'


def test_cli_missing_tracks_is_one_line(tmp_path):
    rc, _, err = _run("paint-tracks", str(_export(tmp_path)), "--tracks", str(tmp_path / "none.npz"))
    assert rc == C.EXIT_BAD_INPUT
    assert err.strip().splitlines() == [f"error: {tmp_path / 'none.npz'}: tracks file does not exist — "
                                        "pass a tracks_tapvid.npz (TAP-Vid layout) with --tracks"]  # fmt: skip


def test_an_export_without_every_tracked_frame_is_one_line(tmp_path):
    manifest = _export(tmp_path)
    data = json.loads(manifest.read_text())
    data["passes"]["frames"] = [0, 1, 2]
    manifest.write_text(json.dumps(data))
    rc, _, err = _run("paint-tracks", str(manifest), "--tracks", str(_save(tmp_path)))
    assert rc == C.EXIT_BAD_INPUT and len(err.strip().splitlines()) == 1
    assert "frame 3 has no passes" in err and "export without --frames" in err


def _save(folder: Path) -> Path:
    npz = folder / "tracks_tapvid.npz"
    save_tracks(npz, _tracks(FG_POINTS))
    return npz
