"""Colour through OCIO on real files: an ACEScg EXR plate, a log (ACEScct) 10-bit DPX plate and an 8-bit sRGB PNG
plate. An empty edit renders the plate back bit for bit (float) or to the last code value (integer); a painted
colour lands in the render with the value it has in the edit layer; the default colour space of each file type."""

from __future__ import annotations

import av
import numpy as np
import OpenImageIO as oiio
import pytest

from engine import contract as C
from engine.edit.equations import load_edit
from engine.edit.movie import MOVIE_COLOUR_TAGS
from engine.edit.render import RenderSettings, render_manifest
from engine.errors import InputError
from engine.fit import run_files
from engine.fit.prepare import to_fitting_values
from engine.fit.run_folder import ClipRecord, RunFolder
from engine.fit.run_plan import _check_resume_colour
from engine.io import colour
from engine.io.clip import open_clip
from engine.terms.colour import COLOUR_BUILTIN_CONFIG, EXR_COLORSPACE_ATTRIBUTE
from engine.terms.run_folder import RUN_CLIP
from tests.colour_plates import AP1, KINDS, H, T, W, _half_layer, _read, _write, export_plate, paint
from tests.engine_cli import run_cli


@pytest.mark.parametrize("kind", list(KINDS))
def test_an_empty_edit_renders_the_plate_back_exactly(tmp_path, kind):
    manifest, _ = export_plate(tmp_path, kind)
    out = render_manifest(manifest, tmp_path / "out", settings=RenderSettings("plate"), progress_bar=False)
    ext = KINDS[kind][0]
    for t in range(T):
        plate, render = tmp_path / "clip" / f"plate.{t:04d}{ext}", out / f"edit.{t:04d}{ext}"
        got, want = _read(render), _read(plate)
        assert got.dtype == want.dtype and np.array_equal(got, want)  # bit for bit / every code value
    if kind == "acescg":  # the EXR output of a float plate is in the plate's space: the same bits, as float32
        exr = render_manifest(manifest, tmp_path / "exr", progress_bar=False)
        assert np.array_equal(_read(exr / "edit.0001.exr", native=False), _read(plate, native=False))


@pytest.mark.parametrize("kind", list(KINDS))
def test_a_painted_colour_lands_with_its_value(tmp_path, kind):
    """A PNG edit layer painted one sRGB colour (200, 3, 50) over the left half: the render holds that colour
    (decoded by OCIO to scene-linear, then encoded in the plate's space) there, and the plate, untouched, on the
    right."""
    manifest, _ = export_plate(tmp_path, kind, _half_layer)
    edit = paint(manifest)
    out = render_manifest(manifest, tmp_path / "out", settings=RenderSettings("plate"), progress_bar=False)
    ext, _, space = KINDS[kind]
    linear = load_edit(edit)[0, 0, :3]
    expected = colour.from_linear(linear[None, None], space, COLOUR_BUILTIN_CONFIG)[0, 0]
    got = _read(out / f"edit.0001{ext}", native=False)
    if kind == "acescg":  # written as half, like the plate
        np.testing.assert_array_equal(got[:, : W // 2], np.broadcast_to(expected.astype(np.float16), (H, W // 2, 3)))
    else:  # the code value of the colour, exactly
        top = 1023.0 if kind == "acescct" else 255.0
        np.testing.assert_array_equal(
            np.rint(got[:, : W // 2] * top), np.broadcast_to(np.rint(expected * top), (H, W // 2, 3))
        )
    plate = _read(tmp_path / "clip" / f"plate.0001{ext}", native=False)
    np.testing.assert_array_equal(got[:, W // 2 :], plate[:, W // 2 :])  # untouched: the plate's own values
    # back in scene-linear, the colour is the edit layer's (as exact as the file's precision allows)
    back = colour.to_linear(got[0, 0][None, None], space, COLOUR_BUILTIN_CONFIG)[0, 0]
    rtol, atol = {"acescg": (1e-3, 0.0), "acescct": (7e-3, 1e-3), "srgb": (1e-2, 0.0)}[kind]  # the file's step
    np.testing.assert_allclose(back, linear, rtol=rtol, atol=atol)


def test_render_exr_of_an_integer_plate_is_scene_linear_rec709_and_tagged(tmp_path):
    manifest, _ = export_plate(tmp_path, "srgb")
    render_manifest(manifest, tmp_path / "exr", progress_bar=False, movie=tmp_path / "edit.mp4")
    inp = oiio.ImageInput.open(str(tmp_path / "exr" / "edit.0000.exr"))
    spec = inp.spec()
    got = np.asarray(inp.read_image(0, 0, 0, 3, "float"))
    inp.close()
    plate = _read(tmp_path / "clip" / "plate.0000.png", native=False)  # the code values as OIIO reads them
    np.testing.assert_array_equal(got, colour.srgb_to_linear(plate))
    assert spec.getattribute("chromaticities") == pytest.approx(colour.REC709_CHROMATICITIES, abs=1e-6)
    assert spec.getattribute(EXR_COLORSPACE_ATTRIBUTE) == C.COLOUR_SCENE_LINEAR
    with av.open(str(tmp_path / "edit.mp4")) as container:
        cc = container.streams.video[0].codec_context
        assert (cc.color_primaries, cc.color_trc, cc.colorspace, cc.color_range) == MOVIE_COLOUR_TAGS


def test_the_default_colour_space_of_each_file_type(tmp_path):
    linear, acescg, log_dpx, lin_dpx = (tmp_path / n for n in ("lin", "ap1", "log", "lindpx"))
    for folder in (linear, acescg, log_dpx, lin_dpx):
        folder.mkdir()
    _write(linear / "f.0001.exr", np.full((H, W, 3), 0.5), oiio.HALF)
    _write(acescg / "f.0001.exr", np.full((H, W, 3), 0.5), oiio.HALF, chromaticities=AP1)
    _write(log_dpx / "f.0001.dpx", np.full((H, W, 3), 0.5), oiio.UINT16, **{"dpx:Transfer": "Printing density"})
    _write(lin_dpx / "f.0001.dpx", np.full((H, W, 3), 0.5), oiio.UINT16, **{"dpx:Transfer": "Linear"})
    assert open_clip(linear).colorspace == C.COLOUR_SCENE_LINEAR
    assert open_clip(acescg).colorspace == "ACEScg"
    assert open_clip(lin_dpx).colorspace == C.COLOUR_SCENE_LINEAR
    with pytest.raises(InputError) as err:
        open_clip(log_dpx)
    assert "log transfer (Printing density)" in str(err.value) and "--colorspace ACEScct" in str(err.value)
    assert open_clip(log_dpx, colorspace="acescct").colorspace == "ACEScct"  # an alias, any case
    assert open_clip(log_dpx, colorspace="lin_ap1").colorspace == "ACEScg"
    assert open_clip(linear, colorspace="sRGB").colorspace == C.COLOUR_SRGB  # the engine's earlier name
    with pytest.raises(InputError) as err:
        open_clip(linear, colorspace="ACEScgg")
    assert str(err.value).count("\n") == 0 and "has no colour space 'ACEScgg'" in str(err.value)
    assert "'ACEScg'" in str(err.value)


def test_ocio_file_rules_choose_the_plate_space(tmp_path, monkeypatch):
    config = tmp_path / "studio.ocio"
    config.write_text(CONFIG_WITH_RULES)
    plate = tmp_path / "plate"
    plate.mkdir()
    _write(plate / "shot_acescg.0001.exr", np.full((H, W, 3), 0.5), oiio.HALF)
    monkeypatch.setenv("OCIO", str(config))
    info = open_clip(plate)
    assert (info.colorspace, info.colour_config) == ("ACEScg", str(config))


def test_the_fit_works_in_srgb_encoded_rec709(tmp_path):
    """An ACEScg plate is converted by OCIO to the fit's working encoding; an sRGB plate is taken bit for bit."""
    srgb = np.random.default_rng(1).uniform(0, 1, (2, 4, 4, 3)).astype(np.float32)
    assert np.array_equal(to_fitting_values(srgb, C.COLOUR_SRGB)[0], srgb)
    assert np.array_equal(to_fitting_values(srgb, "sRGB")[0], srgb)  # an old run's record
    acescg = colour.convert(colour.srgb_to_linear(srgb), C.COLOUR_SCENE_LINEAR, "ACEScg")
    np.testing.assert_allclose(
        to_fitting_values(acescg, "ACEScg", colour_config=COLOUR_BUILTIN_CONFIG)[0], srgb, atol=2e-5
    )


def test_resume_refuses_another_colour_space(tmp_path):
    record = ClipRecord("/clip", "sequence", (0, 1), (0, 1), (), (4, 4), (4, 4), None, "sRGB", (), None, 2, "f")
    run = RunFolder(tmp_path)
    assert _check_resume_colour(run, record, None) == ("sRGB", None)  # an old run: resumed as it was fitted
    assert _check_resume_colour(run, record, "srgb_tx") == ("sRGB", None)
    with pytest.raises(InputError) as err:
        _check_resume_colour(run, record, "ACEScg")
    assert "--resume with --colorspace ACEScg, but this run fitted the plate as 'sRGB Encoded" in str(err.value)


def test_old_records_are_read():
    assert run_files.validate_run_file(RUN_CLIP, {**_clip_json(), "colorspace": "linear"})
    with pytest.raises(run_files.RunFileError):
        run_files.validate_run_file(RUN_CLIP, {**_clip_json(), "colorspace": "ACEScg"})  # a name needs its config
    assert run_files.validate_run_file(
        RUN_CLIP, {**_clip_json(), "colorspace": "ACEScg", "colour_config": "ocio://default"}
    )
    assert colour.recorded_space("linear", None) == (C.COLOUR_SCENE_LINEAR, COLOUR_BUILTIN_CONFIG)


def _clip_json() -> dict:
    record = ClipRecord("/clip", "sequence", (0, 1), (0, 1), (), (4, 4), (4, 4), None, "sRGB", (), None, 2, "f")
    return record.to_dict()


CONFIG_WITH_RULES = """ocio_profile_version: 2.1
roles:
  default: lin_rec709
  scene_linear: lin_rec709
  data: Raw
file_rules:
  - !<Rule> {name: acescg, colorspace: ACEScg, pattern: "*_acescg*", extension: "*"}
  - !<Rule> {name: Default, colorspace: lin_rec709}
displays:
  sRGB:
    - !<View> {name: Raw, colorspace: Raw}
colorspaces:
  - !<ColorSpace>
    name: lin_rec709
    aliases: [Linear Rec.709 (sRGB)]
    isdata: false
  - !<ColorSpace>
    name: ACEScg
    isdata: false
    to_scene_reference: !<MatrixTransform> {matrix: [1.705051, -0.621792, -0.083259, 0, -0.130256, 1.140805,
                                                      -0.010548, 0, -0.024003, -0.128969, 1.152972, 0, 0, 0, 0, 1]}
  - !<ColorSpace>
    name: sRGB
    isdata: false
    from_scene_reference: !<ExponentWithLinearTransform> {gamma: 2.4, offset: 0.055, direction: inverse}
  - !<ColorSpace>
    name: Raw
    isdata: true
"""


def test_fit_refuses_an_unknown_colour_space_and_an_unnamed_log_dpx(tmp_path):
    """Before anything is written: one line, exit 2, no run folder."""
    log_dpx = tmp_path / "plate"
    log_dpx.mkdir()
    for t in range(2):
        _write(log_dpx / f"p.{t:04d}.dpx", np.full((H, W, 3), 0.5), oiio.UINT16, **{"dpx:Transfer": "Logarithmic"})
    code, lines = run_cli("fit", log_dpx, "--out", tmp_path / "run", "--no-bar")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and "--colorspace ACEScct" in lines[0]
    code, lines = run_cli("fit", log_dpx, "--out", tmp_path / "run", "--colorspace", "ACEScgg", "--no-bar")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and "has no colour space 'ACEScgg'" in lines[0]
    code, lines = run_cli("masks", log_dpx, "--out", tmp_path / "masks")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and "log transfer (Logarithmic)" in lines[0]
    assert not (tmp_path / "run").exists() and not (tmp_path / "masks").exists()


def test_movie_frames_are_converted_with_the_bt709_matrix_they_are_tagged_with(tmp_path):
    """Pure sRGB red becomes Y' = 16 + 219 * 0.2126 = 63 (BT.709, limited range), not BT.601's 81."""
    from engine.edit.movie import MovieWriter

    writer = MovieWriter(tmp_path / "red.mp4", 24.0, (16, 16))
    for _ in range(3):
        writer.write(np.tile(np.uint8([255, 0, 0]), (16, 16, 1)))
    writer.close()
    with av.open(str(tmp_path / "red.mp4")) as container:
        luma = next(container.decode(video=0)).to_ndarray(format="yuv420p")[:16]
    assert abs(float(luma.mean()) - 63.0) <= 1.0
