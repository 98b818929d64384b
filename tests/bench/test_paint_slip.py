"""Paint slip on exports whose UVs are known exactly: a textured square moving 2 px a frame over a textured,
static background. UVs that follow the square slip a fraction of a pixel (DIS's error); UVs that lag 2 px behind
it each frame slip 2 px; pixels whose flow fails its round trip, or a frame the layer does not cover, give nothing
to measure."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from bench.__main__ import main as bench_main
from bench.paint_slip import ROUND_TRIP_PX, export_slip, frame_slip
from engine import contract as C
from engine.errors import InputError
from tests.engine.fake_export import make_fake_export

W, H, T = 128, 96, 4
SIDE = 40  # the square's side in pixels, one atlas texel per pixel
X0, Y0 = 30, 28  # its top-left corner at frame 0
STEP = 2  # pixels per frame, to the right


def _texture(h: int, w: int, seed: int) -> np.ndarray:
    """Smooth random texture (blurred noise): DIS finds its motion to a fraction of a pixel."""
    noise = np.random.default_rng(seed).random((h, w, 3)).astype(np.float32)
    return np.clip(cv2.GaussianBlur(noise, (0, 0), 2.0) * 1.6 - 0.3, 0.0, 1.0)


def _export(folder, lag_px: float):
    background, square = _texture(H, W, 1), _texture(SIDE, SIDE, 2)
    plate = np.repeat(background[None], T, 0)
    for t in range(T):
        plate[t, Y0 : Y0 + SIDE, X0 + STEP * t : X0 + STEP * t + SIDE] = square

    def inside(t, xs, ys):
        left = X0 + STEP * t
        return (xs >= left) & (xs < left + SIDE) & (ys >= Y0) & (ys < Y0 + SIDE)

    def bg(t, xs, ys):
        return xs / W, 1.0 - ys / H, 1.0 - inside(t, xs, ys).astype(np.float32)

    def fg(t, xs, ys):
        u = (xs - X0 - STEP * t + lag_px * t) / SIDE  # lag_px: the UVs fall that far behind each frame
        return u, 1.0 - (ys - Y0) / SIDE, inside(t, xs, ys).astype(np.float32)

    return make_fake_export(folder, plate, [(bg, (W, H)), (fg, (SIDE, SIDE))])


def _ramp(h: int, w: int, shift: float = 0.0) -> np.ndarray:
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    return np.stack((xs - shift, ys), -1)


def test_uvs_that_follow_the_flow_slip_nothing_and_a_lag_is_measured_in_pixels():
    h, w = 20, 30
    owned = np.zeros((h, w), bool)
    owned[5:15, 5:20] = True
    forward = np.zeros((h, w, 2))
    forward[..., 0] = 1.5
    backward = -forward
    rng = np.random.default_rng(0)
    follows = frame_slip(_ramp(h, w), owned, _ramp(h, w, 1.5), np.roll(owned, 2, 1), forward, backward, 500, rng)
    assert follows.size == owned.sum() and np.abs(follows).max() < 1e-9
    lags = frame_slip(_ramp(h, w), owned, _ramp(h, w, 1.5 - 0.75), owned | np.roll(owned, 2, 1), forward, backward,
                      500, rng)  # fmt: skip
    np.testing.assert_allclose(lags, 0.75, atol=1e-9)
    assert frame_slip(_ramp(h, w), owned, _ramp(h, w), owned, forward, backward, 40, rng).size == 40  # sampled
    # a round trip that misses by more than ROUND_TRIP_PX, or nothing owned in the next frame: nothing to measure
    near, far = backward.copy(), backward.copy()
    near[..., 0] += 0.9 * ROUND_TRIP_PX
    far[..., 0] += 1.1 * ROUND_TRIP_PX
    assert frame_slip(_ramp(h, w), owned, _ramp(h, w), owned, forward, near, 500, rng).size == owned.sum()
    assert frame_slip(_ramp(h, w), owned, _ramp(h, w), owned, forward, far, 500, rng).size == 0
    assert frame_slip(_ramp(h, w), owned, _ramp(h, w), np.zeros_like(owned), forward, backward, 500, rng).size == 0


def test_an_export_that_follows_its_plate_slips_a_fraction_of_a_pixel_and_a_lag_shows(tmp_path, capsys):
    follows = _export(tmp_path / "a", 0.0)
    report = export_slip(follows, tmp_path / "a" / "clip")
    fg = report["layers"]["Foreground"]
    assert report["frame_pairs"] == T - 1 and fg["pixels"] > 1000 and report["foreground"] == fg
    assert fg["median_px"] < 0.3, fg  # DIS's own error on 8-bit frames (the exact flow gives 0: above)
    lagging = export_slip(_export(tmp_path / "b", 2.0), tmp_path / "b" / "clip")["foreground"]
    assert lagging["median_px"] == pytest.approx(2.0, abs=0.3), lagging
    out = tmp_path / "slip.json"
    args = ["paint-slip", str(follows), "--plate", str(tmp_path / "a" / "clip"), "--json", str(out)]
    assert bench_main(args) == C.EXIT_OK
    assert "paint-slip: Foreground: median" in capsys.readouterr().out
    assert json.loads(out.read_text())["foreground"]["median_px"] == fg["median_px"]  # the same seed, the same pixels


def test_a_plate_that_is_not_the_exports_is_one_line(tmp_path):
    manifest = _export(tmp_path / "a", 0.0)
    small = tmp_path / "small"
    small.mkdir()
    cv2.imwrite(str(small / "00000.png"), np.zeros((10, 12, 3), np.uint8))
    with pytest.raises(InputError, match="is 12x10, the export's passes are 128x96"):
        export_slip(manifest, small)
