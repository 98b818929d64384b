"""`render`'s EXR frames keep the plate's depth: a half-float plate gives half-float frames, unless ``--depth`` says
otherwise; read back with OpenImageIO, which reports each channel's pixel type as the file stores it."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest

from engine import contract as C
from engine.export.manifest import Manifest
from engine.io.images import read_exr, write_png
from engine.terms.cli import VERB_RENDER
from tests.engine_cli import run_cli
from tests.export_td.shots import fake_export, renumber


def _pixel_types(path) -> set[str]:
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    inp.close()
    return {str(spec.channelformat(i)) for i in range(spec.nchannels)}


def _paint(manifest) -> None:
    m = Manifest(manifest)
    for k, layer in enumerate(m.layers):
        w, h = layer["atlas_size"]
        write_png(m.edit_path(layer), np.random.default_rng(k).random((h, w, 4)).astype(np.float32), 8)


@pytest.fixture
def half_plate(tmp_path):
    """A scene-linear half-float EXR plate plate.1001.exr .. and its (fake) export, painted."""
    manifest = renumber(fake_export(tmp_path), 1001, 4, half_exr=True)
    _paint(manifest)
    return manifest


def test_a_half_plate_renders_half_frames_and_depth_32_asks_for_float(half_plate, tmp_path):
    half, full = tmp_path / "half", tmp_path / "full"
    assert run_cli(VERB_RENDER, half_plate, "--out", half, "--no-bar") == (0, [])
    assert run_cli(VERB_RENDER, half_plate, "--out", full, "--depth", "32", "--no-bar") == (0, [])
    for f in (1001, 1002, 1003):
        assert _pixel_types(half / f"edit.{f}.exr") == {"half"}
        assert _pixel_types(full / f"edit.{f}.exr") == {"float"}
        a, b = read_exr(half / f"edit.{f}.exr"), read_exr(full / f"edit.{f}.exr")
        for c in "RGBA":  # the same render, rounded to half once
            assert np.array_equal(a[c], b[c].astype(np.float16).astype(np.float32))
        assert np.abs(a["G"] - read_exr(Manifest(half_plate).plate_frame_file(f - 1001))["G"]).max() > 0.05


def test_an_empty_edit_on_a_half_plate_gives_the_plate_back_bit_for_bit(tmp_path):
    manifest = renumber(fake_export(tmp_path), 1001, 4, half_exr=True)
    out = tmp_path / "out"
    assert run_cli(VERB_RENDER, manifest, "--out", out, "--no-bar") == (0, [])
    m = Manifest(manifest)
    for k, f in enumerate(m.frames):
        got, plate = read_exr(out / f"edit.{f}.exr"), read_exr(m.plate_frame_file(k))
        assert _pixel_types(out / f"edit.{f}.exr") == {"half"}
        assert all(np.array_equal(got[c], plate[c]) for c in "RGB") and (got["A"] == 1).all()


def test_an_8bit_plate_renders_float_unless_depth_16(tmp_path):
    manifest = fake_export(tmp_path)
    _paint(manifest)
    default, half = tmp_path / "default", tmp_path / "half"
    assert run_cli(VERB_RENDER, manifest, "--out", default, "--no-bar") == (0, [])
    assert run_cli(VERB_RENDER, manifest, "--out", half, "--depth", "16", "--no-bar") == (0, [])
    assert _pixel_types(default / "edit.00000.exr") == {"float"}
    assert _pixel_types(half / "edit.00000.exr") == {"half"}


def test_depth_with_another_format_is_one_line(half_plate, tmp_path):
    for fmt in ("png", "plate"):
        code, err = run_cli(VERB_RENDER, half_plate, "--out", tmp_path / fmt, "--format", fmt, "--depth", "16")
        assert code == C.EXIT_BAD_INPUT and len(err) == 1, err
        assert f"--depth is for --format exr, not {fmt}" in err[0]
        assert not (tmp_path / fmt).exists()
