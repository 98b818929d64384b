"""Which reach each layer follows the flow over (engine/export/flow_reach.py): the plate read back through the atlas
on arrays whose answer is known, then through real exports of a tiny fit whose plate is there, changed or gone."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from engine.export import exporter
from engine.export import flow_reach as R
from engine.export import follow_flow as FF
from engine.export import plate_splat as S
from engine.export.manifest import Manifest
from engine.io.images import read_image, write_png
from tests.engine.export.test_follow_flow import UV_PER_PX, _drifted, _flow, _inner, _true_uv
from tests.engine.export.tiny_run import export, make_run


def _plate(uv: np.ndarray) -> np.ndarray:
    """Frames [T, H, W, 3] whose colour at each pixel is a smooth texture of its true UV: what a layer of an object
    that moves as the flow says shows."""
    px = uv / UV_PER_PX
    return np.stack(
        (
            0.5 + 0.4 * np.sin(px[..., 0] / 3.0),
            0.5 + 0.4 * np.cos(px[..., 1] / 4.0),
            0.5 + 0.2 * np.sin(px.sum(-1) / 5.0),
        ),
        -1,
    ).astype(np.float32)


def test_the_plate_reads_back_sharper_through_the_uv_that_keeps_each_point_on_one_texel():
    truth, owned = _true_uv(), _inner()
    frames, none = _plate(truth), np.zeros_like(truth)
    exact = R.splat_psnr(truth, none, owned, frames, UV_PER_PX)
    drifted = R.splat_psnr(_drifted(truth), none, owned, frames, UV_PER_PX)
    assert exact is not None and drifted is not None
    assert exact > 35.0 and drifted < exact - 10.0
    # the correction is what is read through: adding back the drift's opposite is the exact UV again
    assert R.splat_psnr(_drifted(truth), truth - _drifted(truth), owned, frames, UV_PER_PX) == pytest.approx(exact)
    assert R.layer_scale(truth, owned) == pytest.approx(UV_PER_PX, rel=1e-4)


def test_nothing_to_read_back_is_none_not_a_division_by_zero():
    truth, owned = _true_uv(), _inner()
    frames, none = _plate(truth), np.zeros_like(truth)
    nobody = np.zeros_like(owned)
    assert R.splat_psnr(truth, none, nobody, frames, UV_PER_PX) is None
    assert R.layer_scale(truth, nobody) is None
    nan = np.full_like(truth, np.nan)  # a mapping that gave no number anywhere
    assert R.splat_psnr(nan, none, owned, frames, UV_PER_PX) is None
    one = truth.copy()
    one[:, :, :, 0] = 0.25  # every point on one column of texels: all colours mixed, yet a finite PSNR
    assert np.isfinite(R.splat_psnr(one, none, owned, frames, UV_PER_PX))
    same = np.full_like(frames, 0.5)  # identical colours: capped by the error floor, not infinite
    assert R.splat_psnr(truth, none, owned, same, UV_PER_PX) == pytest.approx(100.0)


@pytest.mark.parametrize("stretch", [(1e4, 1e4), (1e9, 1.0), (1.0, 1e9)])
def test_a_uv_spread_wider_than_the_texture_allows_is_read_through_wider_texels(stretch, monkeypatch):
    """A collapsed scale or a mapping thrown far apart, evenly or along one axis: the test's texture keeps under
    ``MAX_TEXELS`` and ``MAX_SIDE`` (OpenCV reads nothing wider), the texels wider, and the PSNR a number."""
    truth, owned = _true_uv(), _inner()
    frames, none = _plate(truth), np.zeros_like(truth)
    shapes: list[tuple[int, ...]] = []
    read = R.sample_points

    def sample_points(texture, pts):  # type: ignore[no-untyped-def]
        shapes.append(texture.shape)
        return read(texture, pts)

    monkeypatch.setattr(R, "sample_points", sample_points)
    wide = truth * np.array(stretch, np.float32)
    assert np.isfinite(R.splat_psnr(wide, none, owned, frames, UV_PER_PX))
    assert np.isfinite(R.splat_psnr(truth, none, owned, frames, 0.0))  # no scale at all: the floor
    for h, w, _ in shapes:
        assert h * w <= S.MAX_TEXELS * 1.01 and max(h, w) <= S.MAX_SIDE


def test_the_reach_that_reads_back_sharper_is_chosen():
    truth, owned = _true_uv(), _inner()
    frames = _plate(truth)
    drifting = R.choose_reach(_drifted(truth), owned, _flow(), frames)  # the flow is right: follow it all the way
    assert drifting.name == R.LONG and drifting.long_db > drifting.short_db + 3.0
    assert np.array_equal(drifting.correction, FF.follow_flow(_drifted(truth), owned, _flow(), FF.LONG_WEIGHT, True))
    assert f"{drifting.long_db:.2f} dB along whole trajectories" in drifting.said
    wrong = _flow()
    wrong.forward[...] *= -1.0  # a flow that carries every point the wrong way: the atlas knows better
    wrong.backward[...] *= -1.0
    kept = R.choose_reach(truth, owned, wrong, frames)
    assert kept.name == R.SHORT and kept.short_db > kept.long_db
    assert np.array_equal(kept.correction, FF.follow_flow(truth, owned, wrong, FF.SHORT_WEIGHT))


def _texture(pts: np.ndarray) -> np.ndarray:
    """The atlas texture of ``_plate``: the colour each atlas point shows."""
    return _plate(pts.reshape(1, 1, -1, 2))[0, 0]


def test_the_texture_shows_the_plate_best_through_the_uv_it_was_drawn_for(monkeypatch):
    truth, owned = _true_uv(), _inner()
    frames, none = _plate(truth), np.zeros_like(truth)
    exact = R.texture_psnr(truth, none, owned, frames, _texture)
    assert exact == pytest.approx(100.0)  # the floor: the same colours
    drifted = R.texture_psnr(_drifted(truth), none, owned, frames, _texture)
    assert drifted is not None and drifted < 30.0
    monkeypatch.setattr(R, "TEXTURE_SAMPLES", 500)  # a sample of the pixels: the same sample for every reach
    sampled = R.texture_psnr(_drifted(truth), none, owned, frames, _texture)
    assert sampled == pytest.approx(drifted, abs=1.0)
    assert sampled == R.texture_psnr(_drifted(truth), none, owned, frames, _texture)
    assert R.texture_psnr(np.full_like(truth, np.nan), none, owned, frames, _texture) is None


@pytest.mark.parametrize(("short_tex", "long_tex", "reach"), [(28.0, 15.2, R.SHORT), (28.0, 25.5, R.LONG)])
def test_the_long_reach_is_held_back_where_the_texture_would_no_longer_show_the_plate(
    short_tex, long_tex, reach, monkeypatch
):
    """The long reach reads back sharper (a drifting UV, a right flow), and the atlas texture through it shows the
    plate 12.8 dB worse than through the short one (a body turning 180 degrees): it keeps to a few frames, and says
    why. 2.5 dB worse (a camel turning: 0.8 dB): it follows the long reach."""
    truth, owned = _true_uv(), _inner()
    said = iter([short_tex, long_tex])
    monkeypatch.setattr(R, "texture_psnr", lambda *_: next(said))
    chosen = R.choose_reach(_drifted(truth), owned, _flow(), _plate(truth), _texture)
    assert chosen.name == reach and chosen.long_db > chosen.short_db
    assert (chosen.short_texture_db, chosen.long_texture_db) == (short_tex, long_tex)
    assert chosen.held == (reach == R.SHORT)
    if chosen.held:
        assert chosen.said.endswith(
            f"{R.LONG} the points drift from where the fit placed them: its atlas shows the plate 15.20 dB against "
            "28.00 dB)"
        )
        assert np.array_equal(chosen.correction, FF.follow_flow(_drifted(truth), owned, _flow(), FF.SHORT_WEIGHT))


def test_without_the_plate_or_anything_owned_the_layer_follows_over_a_few_frames():
    truth, owned = _true_uv(), _inner()
    for reach in (
        R.choose_reach(_drifted(truth), owned, _flow(), None),
        R.choose_reach(_drifted(truth), np.zeros_like(owned), _flow(), _plate(truth)),
    ):
        assert reach.name == R.SHORT and reach.short_db is None and reach.long_db is None
        assert reach.said == "following the flow over a few frames"


@pytest.mark.slow
def test_the_export_tests_each_layer_on_its_plate_and_says_so_when_the_plate_is_gone_or_changed(
    tmp_path, monkeypatch, capsys
):
    """The plate there: each layer is tested on it. Changed since the fit (one frame repainted) or gone: one warning
    line naming the plate, and every layer follows over a few frames, as an export without the test would."""
    frames_dir, _, run = make_run(tmp_path)
    monkeypatch.setattr(exporter, "MIN_SLIP_PX", 0.0)
    monkeypatch.setattr(exporter, "OWNED_ALPHA", 0.4)  # each layer owns the frame (test_follow_flow's _gate_open)
    said: list[str] = []
    monkeypatch.setattr(exporter, "choose_reach", _noting(said, exporter.choose_reach))
    export(run)
    assert said == ["tested", "tested"] and "warning" not in capsys.readouterr().err
    first = sorted(frames_dir.iterdir())[0]
    pixels, _ = read_image(first)
    write_png(first, 1.0 - pixels)
    said.clear()
    manifest = Manifest(export(run))
    err = capsys.readouterr().err
    assert said == ["untested", "untested"] and all(layer["follows_flow"] for layer in manifest.data["layers"])
    assert f"warning: {frames_dir}: the plate has changed since the fit" in err and err.count("\n") == 1
    shutil.rmtree(frames_dir)
    said.clear()
    export(run)
    assert said == ["untested", "untested"]
    assert f"warning: {frames_dir}: the plate cannot be read" in capsys.readouterr().err


def _noting(said: list[str], choose):  # type: ignore[no-untyped-def]
    """``choose_reach`` that notes whether it was given the plate."""

    def choose_reach(uv, owned, flow, frames, colours):  # type: ignore[no-untyped-def]
        said.append("untested" if frames is None else "tested")
        assert colours is not None  # the texture guard reads the model's atlas
        return choose(uv, owned, flow, frames, colours)

    return choose_reach
