"""``tracking.track_report`` on hand-made predictions: the same errors scored in native pixels and at TAP-Vid's
256x256 (a wide plate's native score is the stricter one), and a position a tracker could not give (infinite) as a
miss that leaves the band's median finite while most positions have one."""

from __future__ import annotations

import numpy as np
import pytest

from bench.tracking import Tracks, track_report

W, H, T = 512, 256, 5  # 256x256 halves x and keeps y


def _tracks() -> Tracks:
    xy = np.full((2, T, 2), 100.0, np.float32)
    query = np.array([[0, 100.0, 100.0], [0, 100.0, 100.0]], np.float32)
    return Tracks(xy, np.zeros((2, T), bool), query, (W, H), np.array([True, False]))


def test_an_error_along_x_scores_higher_at_256_on_a_wide_plate():
    pred = _tracks().xy.astype(np.float64).copy()
    pred[:, 1:, 0] += 3.0  # 3 native px; 1.5 at 256 wide
    report = track_report(pred, _tracks())
    assert report["delta"] == {"1": 0.0, "2": 0.0, "4": 1.0, "8": 1.0, "16": 1.0}
    assert report["delta_avg"] == pytest.approx(0.6)
    assert report["delta_256"] == {"1": 0.0, "2": 1.0, "4": 1.0, "8": 1.0, "16": 1.0}
    assert report["delta_avg_256"] == pytest.approx(0.8)
    assert report["by_query_mask"] == {
        "on_mask": {"delta_avg": pytest.approx(0.6), "delta_avg_256": pytest.approx(0.8)},
        "off_mask": {"delta_avg": pytest.approx(0.6), "delta_avg_256": pytest.approx(0.8)},
    }


def test_an_infinite_position_is_a_miss_and_the_median_stays_finite_while_most_have_one():
    pred = _tracks().xy.astype(np.float64).copy()
    pred[0, 1] = np.inf  # one miss among the two positions of gap 1
    pred[:, 3] = np.inf  # both positions of gap 3 missed
    report = track_report(pred, _tracks())
    assert report["scored_points"] == 8
    assert report["delta_avg"] == pytest.approx(5 / 8)
    gap_1_2, gap_3_7 = report["by_gap"][0], report["by_gap"][1]
    assert gap_1_2["scored_points"] == 4 and gap_1_2["median_px"] == 0.0  # 3 of 4 exact
    assert gap_3_7["scored_points"] == 4 and gap_3_7["median_px"] is None  # half of them missed: no median
