"""The benchmark's accuracy metrics on cases with a known answer: TAP-Vid scoring on hand-made numbers,
chained flow on a pure translation, and atlas tracking / mapping consistency of a perfect mapping of a
synthetic scene (whose ground truth is exact)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bench.tracking import (
    Tracks,
    anchor_spread,
    atlas_tracks,
    chained_flow_tracks,
    load_tracks,
    mapping_consistency,
    save_tracks,
    tapvid_scores,
)
from engine.data.synthetic import SceneSpec, SyntheticScene, make_scene
from engine.model.atlas_model import AtlasModel

SPEC = SceneSpec(width=64, height=48, frames=6, fg_size=(24, 18), fg_start=(12.0, 10.0), fg_velocity=(3.0, 1.0))


class PerfectModel(AtlasModel):
    """The scene's true decomposition: UV = texture coordinate / HALF, alpha = the sprite's ellipse.
    ``shift`` moves the foreground's UV by that many pixels in frames >= 1 (a known tracking error)."""

    HALF = 32.0

    def __init__(self, scene: SyntheticScene, shift: float = 0.0) -> None:
        super().__init__()
        self.scene = scene
        self.num_layers = 2
        self.width, self.height, self.frames = scene.spec.width, scene.spec.height, scene.spec.frames
        self.shift = shift

    def uv(self, layer, xy, t):
        p = xy.double() - 0.5  # model pixel centres are at i + 0.5, the scene's at i
        if layer == 0:
            return ((p + torch.as_tensor(self.scene.bg_offset)[t]) / self.HALF).float()
        tex = p - torch.as_tensor(self.scene.fg_offset)[t].double()
        tex[:, 0] += self.shift * (t >= 1).double()
        return (tex / self.HALF).float()

    def uv_per_px(self, layer):
        return 1.0 / self.HALF

    def alpha(self, xy, t):
        tex = xy.double() - 0.5 - torch.as_tensor(self.scene.fg_offset)[t].double()
        a, b = self.scene.spec.fg_size[0] / 2.0, self.scene.spec.fg_size[1] / 2.0
        inside = (((tex[:, 0] - a) / a) ** 2 + ((tex[:, 1] - b) / b) ** 2 < 1.0).float()
        return torch.stack((1.0 - inside, inside), -1)


@pytest.fixture(scope="module")
def scene() -> SyntheticScene:
    return make_scene(SPEC)


def test_tapvid_scores_hand_made():
    gt = np.zeros((2, 3, 2))
    pred = np.zeros((2, 3, 2))
    pred[0, 1] = (0.5, 0.0)  # within 1
    pred[0, 2] = (3.0, 0.0)  # within 4, 8, 16
    pred[1, 0] = (100.0, 0.0)  # the query frame of track 1: not scored
    pred[1, 2] = (0.0, 16.0)  # exactly 16: strictly-less fails every threshold
    occluded = np.array([[False, False, False], [False, True, False]])
    s = tapvid_scores(pred, gt, occluded, np.array([0, 0]))
    assert s["scored_points"] == 3  # (0,1), (0,2), (1,2)
    assert s["delta"] == {"1": 1 / 3, "2": 1 / 3, "4": 2 / 3, "8": 2 / 3, "16": 2 / 3}
    assert s["delta_avg"] == pytest.approx((1 + 1 + 2 + 2 + 2) / 15)


def test_tapvid_scores_scale_and_empty():
    gt = np.zeros((1, 2, 2))
    pred = np.full((1, 2, 2), 3.0)  # 4.24 px off
    s = tapvid_scores(pred, gt, np.zeros((1, 2), bool), np.array([0]), scale=(0.25, 0.25))
    assert s["delta"]["2"] == 1.0 and s["delta"]["1"] == 0.0
    empty = tapvid_scores(pred, gt, np.ones((1, 2), bool), np.array([0]))
    assert empty["delta_avg"] is None and empty["scored_points"] == 0


def test_chained_flow_on_pure_translation():
    t, h, w = 5, 20, 30
    fwd = np.zeros((t - 1, h, w, 2), np.float32)
    fwd[...] = (1.5, -0.5)
    bwd = -fwd
    queries = np.array([[0, 5.0, 12.0], [2, 10.25, 8.75], [4, 20.0, 10.0]])
    out = chained_flow_tracks(fwd, bwd, queries, t)
    for (tq, x, y), track in zip(queries, out, strict=True):
        expect = np.array([x, y]) + (np.arange(t) - tq)[:, None] * np.array([1.5, -0.5])
        np.testing.assert_allclose(track, expect, atol=1e-9)


def test_chained_flow_follows_true_flow_of_the_scene(scene):
    t = SPEC.frames
    fwd = np.stack([scene.true_flow(i) for i in range(t - 1)])
    bwd = -fwd  # both layers translate, so the backward flow at the target is the negated vector
    tex = np.array([[12.0, 9.0], [8.0, 8.0]])  # sprite texture points, far from its rim
    q = scene.fg_point_in_frame(tex, 0) + 0.5
    out = chained_flow_tracks(fwd, bwd, np.c_[np.zeros(2), q], t)
    for f in range(t):
        np.testing.assert_allclose(out[:, f], scene.fg_point_in_frame(tex, f) + 0.5, atol=1e-4)


def test_atlas_tracks_of_a_perfect_mapping_are_exact(scene):
    model = PerfectModel(scene)
    tex_fg = np.array([[12.0, 9.0], [6.3, 8.2], [17.5, 10.4]])
    tex_bg = np.array([[3.0, 40.0], [55.2, 4.7]])
    query_t = np.array([0, 2, 5, 0, 3])
    q = np.concatenate(
        [
            [scene.fg_point_in_frame(p, int(tq)) for p, tq in zip(tex_fg, query_t[:3], strict=True)],
            [scene.bg_point_in_frame(p, int(tq)) for p, tq in zip(tex_bg, query_t[3:], strict=True)],
        ]
    )
    pred, owner = atlas_tracks(model, q + 0.5, query_t, SPEC.frames, (SPEC.width, SPEC.height), torch.device("cpu"))
    assert owner.tolist() == [1, 1, 1, 0, 0]
    gt = np.stack(
        [np.stack([scene.fg_point_in_frame(p, f) for f in range(SPEC.frames)]) for p in tex_fg]
        + [np.stack([scene.bg_point_in_frame(p, f) for f in range(SPEC.frames)]) for p in tex_bg]
    )
    inside = (gt >= 0).all(-1) & (gt[..., 0] <= SPEC.width - 1) & (gt[..., 1] <= SPEC.height - 1)
    np.testing.assert_allclose(pred[inside], gt[inside] + 0.5, atol=1e-2)
    s = tapvid_scores(pred, gt + 0.5, ~inside, query_t)
    assert s["delta_avg"] == 1.0


def test_atlas_tracks_report_a_known_slip(scene):
    """A foreground mapping that slips 3 px in frames >= 1: tracks are 3 px off there, so exactly the
    4, 8 and 16 px thresholds hold (delta_avg 0.6)."""
    model = PerfectModel(scene, shift=3.0)
    tex = np.array([[12.0, 9.0], [8.0, 8.0]])
    q = scene.fg_point_in_frame(tex, 0) + 0.5
    pred, _ = atlas_tracks(model, q, np.zeros(2, int), SPEC.frames, (SPEC.width, SPEC.height), torch.device("cpu"))
    gt = np.stack([np.stack([scene.fg_point_in_frame(p, f) for f in range(SPEC.frames)]) for p in tex]) + 0.5
    np.testing.assert_allclose(np.abs(pred[:, 1:] - gt[:, 1:])[..., 0], 3.0, atol=1e-2)
    s = tapvid_scores(pred, gt, np.zeros((2, SPEC.frames), bool), np.zeros(2, int))
    assert s["delta_avg"] == pytest.approx(0.6)


class AnchoredModel(PerfectModel):
    """The perfect mapping, started from a motion that slips ``anchor_shift`` px in frames >= 1."""

    def __init__(self, scene: SyntheticScene, anchor_shift: float) -> None:
        super().__init__(scene)
        self.anchor = PerfectModel(scene, shift=anchor_shift)

    def uv_anchor(self, layer, xy, t):
        return self.anchor.uv(layer, xy, t)


def test_anchor_spread_reports_a_known_slip_of_the_starting_motion(scene):
    """Tracks in native pixels at twice the working size; the starting motion slips 3 working px in frames >= 1,
    so every scored on-mask position lands 6 native px from its query; the background point (off the mask) is not
    counted, and a model without a starting motion reports none."""
    tex = np.array([[12.0, 9.0], [8.0, 8.0]])
    fg = np.stack([np.stack([scene.fg_point_in_frame(p, f) for f in range(SPEC.frames)]) for p in tex]) + 0.5
    bg = np.stack([scene.bg_point_in_frame(np.array([3.0, 40.0]), f) for f in range(SPEC.frames)])[None] + 0.5
    native = np.array([2.0, 2.0])
    tracks = Tracks(
        xy=(np.concatenate([fg, bg]) * native).astype(np.float32),
        occluded=np.zeros((3, SPEC.frames), bool),
        query_txy=np.array([[0, *fg[0, 0] * native], [2, *fg[1, 2] * native], [0, *bg[0, 0] * native]], np.float32),
        image_size=(2 * SPEC.width, 2 * SPEC.height),
        on_mask=np.array([True, True, False]),
    )
    spread = anchor_spread(AnchoredModel(scene, 3.0), tracks, native, torch.device("cpu"))
    # point 0 (queried in frame 0): 5 positions, all 6 px off; point 1 (queried in frame 2): frame 0 only
    assert spread is not None and spread["positions"] == 10 and spread["on_mask_only"]
    assert spread["mean_px"] == pytest.approx(6.0 * 6 / 10, abs=1e-3)
    assert spread["median_px"] == pytest.approx(6.0, abs=1e-3)
    assert anchor_spread(AnchoredModel(scene, 0.0), tracks, native, torch.device("cpu"))["mean_px"] == 0.0
    assert anchor_spread(PerfectModel(scene), tracks, native, torch.device("cpu")) is None


def test_consistency_of_a_perfect_mapping_is_zero(scene):
    t = SPEC.frames
    fwd = np.stack([scene.true_flow(i) for i in range(t - 1)])
    ys, xs = np.mgrid[0 : SPEC.height, 0 : SPEC.width]
    tx, ty = xs + fwd[..., 0], ys + fwd[..., 1]
    ok = (tx >= 0) & (tx <= SPEC.width - 1) & (ty >= 0) & (ty <= SPEC.height - 1)
    res = mapping_consistency(PerfectModel(scene), fwd, ok, list(range(t)), torch.device("cpu"), stride=2)
    assert res["pixels"] > 1000
    assert set(res["per_layer"]) == {"0", "1"}
    assert res["mean_texels"] < 1e-4
    slipping = mapping_consistency(PerfectModel(scene, shift=3.0), fwd, ok, [0], torch.device("cpu"), stride=2)
    assert slipping["per_layer"]["1"] == pytest.approx(3.0, abs=1e-3)  # frame 0 -> 1 crosses the slip


def test_tracks_file_round_trip(tmp_path):
    occ = np.array([[False, True, False]])
    tr = Tracks(np.ones((1, 3, 2), np.float32), occ, np.array([[0, 1, 1]], np.float32), (64, 48))
    save_tracks(tmp_path / "tracks_tapvid.npz", tr)
    back = load_tracks(tmp_path / "tracks_tapvid.npz")
    assert back.image_size == (64, 48) and back.num_frames == 3
    np.testing.assert_array_equal(back.occluded, occ)
    assert back.xy[0, 1].tolist() == [0.0, 0.0]  # occluded positions are zeroed, as in the shared files


def test_track_scores_split_by_the_query_mask(tmp_path):
    """Points on the masked object and background points are scored apart (bench JSON: ``by_query_mask``)."""
    from bench.tracking import track_scores

    t = 4
    gt = np.zeros((2, t, 2), np.float32)
    gt[:, :, 0] = np.arange(t)[None, :] * 5.0  # both points move 5 px per frame
    occ = np.zeros((2, t), bool)
    query = np.array([[0, 0, 0], [0, 0, 0]], np.float32)
    tr = Tracks(gt, occ, query, (64, 48), on_mask=np.array([True, False]))
    save_tracks(tmp_path / "tracks_tapvid.npz", tr)
    back = load_tracks(tmp_path / "tracks_tapvid.npz")
    np.testing.assert_array_equal(back.on_mask, [True, False])
    pred = gt.copy()
    pred[1] = 0.0  # the background point is left where it started
    s = track_scores(pred, back.subset(np.array([True, True]), t))
    assert s["by_query_mask"]["on_mask"]["delta_avg"] == pytest.approx(1.0)
    # 5, 10, 15 px off: within 8 px once, within 16 px thrice -> (0 + 0 + 0 + 1/3 + 1) / 5
    assert s["by_query_mask"]["off_mask"]["delta_avg"] == pytest.approx(4 / 15)
    assert s["delta_avg"] == pytest.approx((1.0 + 4 / 15) / 2)
    # each point's own score and median error (native px), in the file's order
    on, off = s["per_point"]
    assert on == {"delta_avg": pytest.approx(1.0), "scored_points": 3, "median_px": 0.0}
    assert off == {"delta_avg": pytest.approx(4 / 15), "scored_points": 3, "median_px": 10.0}


def test_per_point_scores_weighted_by_their_counts_give_the_aggregate():
    """``per_point`` is a breakdown, not a second metric: count-weighted it is ``delta_avg`` exactly, with
    occluded frames and each track's own query frame left out as TAP-Vid does."""
    from bench.tracking import track_scores

    rng = np.random.default_rng(3)
    n, t = 6, 9
    gt = rng.uniform(0, 60, (n, t, 2)).astype(np.float32)
    occ = rng.random((n, t)) < 0.3
    occ[5] = True  # a track never visible after its query: nothing to score
    qt = rng.integers(0, t, n)
    occ[np.arange(n), qt] = False
    query = np.c_[qt, gt[np.arange(n), qt]].astype(np.float32)
    pred = gt + rng.normal(0, 6, gt.shape)
    s = track_scores(pred, Tracks(gt, occ, query, (64, 48)))
    pts = s["per_point"]
    assert len(pts) == n and pts[5] == {"delta_avg": None, "scored_points": 0, "median_px": None}
    total = sum(p["scored_points"] for p in pts)
    assert total == s["scored_points"]
    weighted = sum(p["delta_avg"] * p["scored_points"] for p in pts if p["scored_points"]) / total
    assert weighted == pytest.approx(s["delta_avg"])


def test_scores_by_frame_gap_tell_imprecision_from_drift():
    """A tracker that drifts 0.5 px a frame is exact one frame away and lost 32 frames away: ``by_gap`` shows
    where it goes wrong. Each band scores only its own positions (query frame and occluded ones left out), and
    the bands together are the aggregate."""
    from bench.tracking import track_scores

    t = 40
    gt = np.zeros((2, t, 2), np.float32)
    frames = np.arange(t)
    occ = np.zeros((2, t), bool)
    occ[1, 20:] = True  # the second track is hidden from frame 20 on
    qt = np.array([0, 10])
    pred = gt.copy()
    pred[:, :, 0] = 0.5 * np.abs(frames[None, :] - qt[:, None])
    s = track_scores(pred, Tracks(gt, occ, np.c_[qt, np.zeros((2, 2))].astype(np.float32), (64, 48)))
    bands = {tuple(b["gap"]): b for b in s["by_gap"]}
    assert list(bands) == [(1, 3), (3, 8), (8, 16), (16, 32), (32, None)]
    # gaps 1 and 2: track 0 at frames 1, 2; track 1 at 8, 9, 11, 12 -> three positions 0.5 px off, three 1.0 px
    assert bands[(1, 3)]["scored_points"] == 6 and bands[(1, 3)]["median_px"] == pytest.approx(0.75)
    assert bands[(1, 3)]["delta_avg"] == pytest.approx((3 / 6 + 1 + 1 + 1 + 1) / 5)  # 1.0 px is not within 1
    # 32 frames or more: track 0's frames 32-39 only (track 1 is hidden), 16-19.5 px off: outside every threshold
    assert bands[(32, None)]["scored_points"] == 8 and bands[(32, None)]["delta_avg"] == 0.0
    assert bands[(32, None)]["median_px"] == pytest.approx(17.75)
    assert sum(b["scored_points"] for b in s["by_gap"]) == s["scored_points"]
    # a band nothing falls in
    empty = track_scores(pred[:, :3], Tracks(gt[:, :3], occ[:, :3], np.zeros((2, 3), np.float32), (64, 48)))
    assert {tuple(b["gap"]): b for b in empty["by_gap"]}[(8, 16)] == {
        "gap": [8, 16],
        "delta_avg": None,
        "scored_points": 0,
        "median_px": None,
    }
