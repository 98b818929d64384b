"""The plate laid on a layer's atlas through its UV (engine/export/plate_splat.py): on arrays whose answer is known,
then through a real export of a tiny fit, whose texture must show the plate better than the networks' colours."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

from bench.sharpness import atlas_sharpness
from engine.export import exporter
from engine.export import plate_splat as S
from engine.export.atlas_frame import LayerFrame
from tests.engine.export.test_flow_reach import _plate, _texture
from tests.engine.export.test_follow_flow import UV_PER_PX, _drifted, _inner, _true_uv
from tests.engine.export.tiny_run import export, make_run


def _frame(truth: np.ndarray, owned: np.ndarray) -> LayerFrame:
    """A texture frame over where the owned pixels land, with texels a third of a working pixel wide (the texture
    is finer than what landed: its texels between the splat's)."""
    pts = truth[owned]
    lo, hi = pts.min(0), pts.max(0)
    w, h = (int(v) for v in np.round((hi - lo) / UV_PER_PX * 3))
    return LayerFrame((float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])), (w, h))


def test_the_plate_laid_through_the_true_uv_is_the_atlas_texture():
    """Every frame shows the same smooth texture moved by the flow, laid through the UV that follows it: inside,
    each texel holds the texture's colour there (within what a bilinear splat read bilinearly smooths over one
    working pixel)."""
    truth, owned = _true_uv(), _inner()
    frame = _frame(truth, owned)
    laid = S.splat(truth, None, owned, _plate(truth), UV_PER_PX)
    assert laid is not None and laid.cell == pytest.approx(UV_PER_PX)
    network = np.full((frame.size[1], frame.size[0], 3), 0.5, np.float32)
    texture, full = S.plate_texture(laid, frame, network)
    inner = _seen_in_first_frame(truth, owned, frame)
    want = _texture(frame.texel_centres()[inner])
    assert np.abs(texture[inner] - want).max() < 0.03  # a bilinear splat read bilinearly: smoothed over a pixel
    assert full > 0.9
    blurred = np.abs(network[inner] - want).mean()
    assert np.abs(texture[inner] - want).mean() < blurred / 20


def _seen_in_first_frame(truth: np.ndarray, owned: np.ndarray, frame: LayerFrame) -> np.ndarray:
    """The texels [H, W] whose centre lies a working pixel inside where the first frame's owned pixels land: covered
    in full (the union of the frames' landings is not a rectangle, the texture's box is)."""
    pts = truth[0][owned[0]]
    lo, hi = pts.min(0) + UV_PER_PX, pts.max(0) - UV_PER_PX
    centres = frame.texel_centres()
    return ((centres >= lo) & (centres <= hi)).all(-1)


def test_a_corrected_uv_lays_the_plate_where_the_true_one_does():
    """A UV that drifts 1 px a frame, with the correction that undoes it: the same texture as the true UV's; without
    it, the frames' colours land on several texels and the texture blurs."""
    truth, owned = _true_uv(), _inner()
    frames, frame = _plate(truth), _frame(truth, owned)
    network = np.zeros((frame.size[1], frame.size[0], 3), np.float32)
    exact = S.plate_texture(S.splat(truth, None, owned, frames, UV_PER_PX), frame, network)[0]
    drifted = _drifted(truth)
    corrected = S.plate_texture(S.splat(drifted, truth - drifted, owned, frames, UV_PER_PX), frame, network)[0]
    np.testing.assert_allclose(corrected, exact, atol=1e-5)
    smeared = S.plate_texture(S.splat(drifted, None, owned, frames, UV_PER_PX), frame, network)[0]
    assert np.abs(smeared - exact)[_seen_in_first_frame(truth, owned, frame)].mean() > 0.01


def test_where_little_or_nothing_landed_the_network_colour_makes_up_the_rest():
    """One texel corner holds a quarter of a pixel's weight of red: the texel there is a quarter red, three quarters
    the network's grey; a texel nothing reached is the network's colour exactly; every value within [0, 1]."""
    weight = np.zeros((4, 4))
    weight[1, 1] = 0.25 * S.FULL_WEIGHT
    colour = np.zeros((4, 4, 3))
    colour[1, 1] = weight[1, 1] * np.array([3.0, 0.0, 0.0])  # a bright value: clipped as the network's are
    laid = S.Splat(np.zeros(2), 1.0, weight, colour)
    frame = LayerFrame((0.5, 0.5, 3.5, 3.5), (3, 3))  # texel centres on the corners 1, 2, 3
    grey = np.full((3, 3, 3), 0.5, np.float32)
    texture, full = S.plate_texture(laid, frame, grey)
    np.testing.assert_allclose(texture[0, 0], [1.0, 0.75 * 0.5, 0.75 * 0.5], atol=1e-6)  # red 0.75 + 0.375: clipped
    np.testing.assert_array_equal(texture[1:, 1:], grey[1:, 1:])
    assert full == 0.0


def test_nothing_owned_or_no_finite_uv_lays_nothing_and_a_bad_plate_value_lays_black():
    truth, owned = _true_uv(), _inner()
    frames = _plate(truth)
    assert S.splat(truth, None, np.zeros_like(owned), frames, UV_PER_PX) is None
    assert S.splat(np.full_like(truth, np.nan), None, owned, frames, UV_PER_PX) is None
    hot = frames.copy()
    hot[:, 20, 28] = (np.nan, np.inf, -np.inf)
    laid = S.splat(truth, None, owned, hot, UV_PER_PX)
    assert laid is not None and np.isfinite(laid.colour).all() and np.isfinite(laid.texture()).all()
    one = truth.copy()
    one[:, 20, 28] = np.nan  # a pixel whose UV is not finite is left out, the rest laid
    assert S.splat(one, None, owned, frames, UV_PER_PX).weight.sum() == pytest.approx(owned.sum() - len(owned))


@pytest.mark.slow
def test_a_layer_that_follows_the_flow_gets_the_plate_laid_through_its_moved_uv_as_its_texture(tmp_path, monkeypatch):
    """A real export of a tiny fit whose layers follow the flow: the plate re-rendered from the exported atlas
    textures through the exported passes (``bench sharpness``) is closer to the plate than with the networks'
    colours, which lie under the UV as fitted, not the moved one; the export says so per layer."""
    frames_dir, masks_dir, run = make_run(tmp_path)
    monkeypatch.setattr(exporter, "MIN_SLIP_PX", 0.0)  # every layer follows the flow
    monkeypatch.setattr(exporter, "OWNED_ALPHA", 0.4)  # twelve steps: each layer's weight is soft
    monkeypatch.setattr(exporter, "SOLID_ALPHA", 0.4)
    stream = io.StringIO()
    laid = atlas_sharpness(export(run, stream=stream), frames_dir, [masks_dir])["psnr_pooled"]
    said = [json.loads(line).get("message", "") for line in stream.getvalue().splitlines()]
    assert sum("the atlas texture from the plate" in m for m in said) == 2
    monkeypatch.setattr(exporter, "_plate_splats", lambda *_: {})
    networks = atlas_sharpness(export(run), frames_dir, [masks_dir])["psnr_pooled"]
    assert laid > networks + 1.0, (laid, networks)
