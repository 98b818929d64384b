"""The edit equations, texture conventions and frame projection on hand-made passes (no fit needed)."""

from __future__ import annotations

import av
import numpy as np
import pytest

from engine.edit.equations import composite_edits, edit_to_premultiplied, load_edit, sample_texture
from engine.edit.project_frame import over, project_frame
from engine.edit.render import RenderSettings, render_frames, render_manifest
from engine.export.manifest import LayerPasses, Manifest
from engine.io.colour import linear_to_srgb, srgb_to_linear
from engine.io.images import read_exr, write_png, write_rgba_exr
from tests.engine.fake_export import make_fake_export


def _tex(h=3, w=4, c=1):
    return np.arange(h * w * c, dtype=np.float32).reshape(h, w, c)


def test_nearest_follows_map_uv_conventions():
    tex = _tex()  # row 0 is the TOP of the image file; v = 0 is the bottom row
    centre = lambda i, j: np.array([(i + 0.5) / 4, (j + 0.5) / 3])  # noqa: E731 - texel (i, j) from bottom-left
    assert sample_texture(tex, centre(0, 0), "nearest")[0] == tex[2, 0, 0]
    assert sample_texture(tex, centre(3, 2), "nearest")[0] == tex[0, 3, 0]
    assert sample_texture(tex, np.array([1.0, 1.0]), "nearest")[0] == tex[0, 3, 0]  # the edge belongs inside
    assert sample_texture(tex, np.array([0.0, 0.0]), "nearest")[0] == tex[2, 0, 0]
    for outside in ([-1e-4, 0.5], [0.5, 1.0001], [1.5, 0.5]):
        assert sample_texture(tex + 1, np.array(outside), "nearest")[0] == 0.0  # Clip: zero outside


def test_bilinear_is_exact_at_texel_centres_and_interpolates_between():
    tex = _tex(c=2)
    for i in range(4):
        for j in range(3):
            uv = np.array([(i + 0.5) / 4, (j + 0.5) / 3])
            np.testing.assert_allclose(sample_texture(tex, uv), tex[2 - j, i], atol=1e-5)
    mid = np.array([1.0 / 4, 0.5 / 3])  # halfway between texels (0, 0) and (1, 0)
    np.testing.assert_allclose(sample_texture(tex, mid), (tex[2, 0] + tex[2, 1]) / 2, atol=1e-5)
    edge = np.array([0.0, 0.5 / 3])  # half a texel left of texel 0's centre: half of it, half of nothing
    np.testing.assert_allclose(sample_texture(tex, edge), tex[2, 0] / 2, atol=1e-5)


def test_empty_edits_return_the_plate_bit_for_bit():
    rng = np.random.default_rng(0)
    plate = rng.normal(0.5, 2.0, (5, 6, 3)).astype(np.float32)  # HDR values and negatives stay untouched
    passes = [LayerPasses(rng.random((5, 6, 2), np.float32), np.full((5, 6), 0.5, np.float32), np.full((5, 6), 0.5))]
    out = composite_edits(plate, passes * 2, [np.zeros((4, 4, 4), np.float32), None])
    assert np.array_equal(out, plate)


def test_layers_blend_by_alpha_over_the_original_plate():
    plate = np.full((1, 1, 3), 0.2, np.float32)
    uv = np.full((1, 1, 2), 0.5, np.float32)
    red = np.zeros((2, 2, 4), np.float32)
    red[..., 0] = red[..., 3] = 1.0
    half_blue = np.zeros((2, 2, 4), np.float32)
    half_blue[..., 2] = half_blue[..., 3] = 0.5  # premultiplied: 50% blue
    z_bg, z_fg = np.full((1, 1), 0.3, np.float32), np.full((1, 1), 0.7, np.float32)
    out = composite_edits(plate, [LayerPasses(uv, z_bg, z_bg), LayerPasses(uv, z_fg, z_fg)], [red, half_blue])
    # (1 - a) * (1 * red + 0 * plate) + a * (0.5 * blue + 0.5 * plate), a = 0.7
    expected = 0.3 * np.array([1.0, 0.0, 0.0]) + 0.7 * (np.array([0.0, 0.0, 1.0]) * 0.5 + 0.5 * 0.2)
    np.testing.assert_allclose(out[0, 0], expected, atol=1e-6)


def test_png_edits_load_like_blender():
    """8-bit sRGB straight alpha -> linear premultiplied; float EXR kept as is (premultiplied)."""
    px = np.array([[[0.5, 1.0, 0.0, 0.25]]], np.float32)
    got = edit_to_premultiplied(px, is_float=False)
    np.testing.assert_allclose(got[0, 0, :3], srgb_to_linear(px[0, 0, :3]) * 0.25, atol=1e-7)
    assert got[0, 0, 3] == 0.25
    assert np.array_equal(edit_to_premultiplied(px, is_float=True), px)


def test_srgb_round_trip():
    x = np.linspace(-0.5, 4.0, 1001, dtype=np.float32)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(x)), x, rtol=3e-5, atol=2e-6)  # OCIO: float32 curve
    assert srgb_to_linear(np.float32(0.04045)) == pytest.approx(0.04045 / 12.92, rel=3e-5)


def _identity_layer(w, h, alpha=1.0):
    """u, v = the pixel's own position (an atlas the frame's size; no motion)."""
    return (lambda t, xs, ys: (xs / w, 1.0 - ys / h, np.full(xs.shape, alpha)), (w, h))


def _plate(t=3, h=24, w=32, seed=1):
    return np.random.default_rng(seed).uniform(0.1, 0.9, (t, h, w, 3)).astype(np.float32)


def test_project_frame_with_an_opaque_layer_is_exact(tmp_path):
    plate = _plate()
    manifest = make_fake_export(tmp_path, plate, [_identity_layer(32, 24)])
    paint = np.zeros((24, 32, 4), np.float32)
    paint[5:12, 8:20] = (0.9, 0.2, 0.1, 1.0)
    paint[15:18, 3:9] = (0.1, 0.9, 0.3, 0.5)
    write_png(tmp_path / "paint.png", paint, 8)
    project_frame(manifest, 1, tmp_path / "paint.png")
    m = Manifest(manifest)
    edit = load_edit(m.edit_path(m.layers[0]))
    expected = edit_to_premultiplied(np.rint(paint * 255) / 255, is_float=False)
    assert np.abs(edit - expected).max() < 2.0 / 255  # 8-bit edit layer round trip
    frames = dict(render_frames(m, [edit]))
    lin = srgb_to_linear(np.rint(plate * 255) / 255)
    a = expected[..., 3:4]
    for t in range(3):  # nothing moves, so every frame gets the same paint
        np.testing.assert_allclose(frames[t], lin[t] * (1 - a) + expected[..., :3], atol=3.0 / 255)


def test_project_frame_cli_prints_its_stages_then_the_paths(tmp_path, capsys):
    """The CLI verb says each stage as a progress line (the add-on's bar), then the files it wrote, last."""
    from engine import contract as C
    from engine.cli import main

    manifest = make_fake_export(tmp_path, _plate(), [_identity_layer(32, 24)])
    paint = np.zeros((24, 32, 4), np.float32)
    paint[5:12, 8:20] = (0.9, 0.2, 0.1, 1.0)
    write_png(tmp_path / "paint.png", paint, 8)
    assert main([C.VERB_PROJECT_FRAME, str(manifest), "--frame", "1", "--edit", str(tmp_path / "paint.png")]) == 0
    lines = capsys.readouterr().out.splitlines()
    msgs = [m for m in map(C.parse_progress_line, lines) if m is not None]
    assert [m["stage"] for m in msgs if m["event"] == C.EVENT_STAGE] == ["read", "project", "write"]
    assert [(m["step"], m["total"]) for m in msgs if m["event"] == C.EVENT_PROGRESS] == [(0, 3), (1, 3), (2, 3)]
    m = Manifest(manifest)
    assert lines[-1] == str(m.edit_path(m.layers[0]))


def test_project_frame_lands_in_the_float_edit_layer_when_there_is_one(tmp_path):
    """An artist who switched a layer to a float EXR edit layer: projected paint goes there (where the renders
    read it), in linear premultiplied float, and the PNG beside it is left as it was."""
    plate = _plate()
    manifest = make_fake_export(tmp_path, plate, [_identity_layer(32, 24)])
    m = Manifest(manifest)
    png = m.edit_path(m.layers[0])
    png_bytes = png.read_bytes()
    exr = png.with_suffix(".exr")
    write_rgba_exr(exr, np.zeros((24, 32, 4), np.float32))
    paint = np.zeros((24, 32, 4), np.float32)
    paint[5:12, 8:20] = (0.9, 0.2, 0.1, 1.0)
    write_png(tmp_path / "paint.png", paint, 8)
    written = project_frame(manifest, 1, tmp_path / "paint.png")
    assert written == {"Background": exr}
    assert png.read_bytes() == png_bytes
    edit = load_edit(exr)
    expected = edit_to_premultiplied(np.rint(paint * 255) / 255, is_float=False)
    assert np.abs(edit[6:11, 9:19] - expected[6:11, 9:19]).max() < 1e-6  # stroke core: exact, no 8-bit step


def test_projection_fills_gaps_when_the_atlas_is_finer_than_the_frame(tmp_path):
    """An atlas 3x the frame's resolution: splatted samples land 3 texels apart; linear interpolation
    closes the stroke without holes and without bleeding beyond it."""
    plate = _plate(t=1)
    layer = (lambda t, xs, ys: (xs / 32, 1.0 - ys / 24, np.ones(xs.shape)), (96, 72))
    manifest = make_fake_export(tmp_path, plate, [layer])
    paint = np.zeros((24, 32, 4), np.float32)
    paint[6:14, 10:22] = (1.0, 1.0, 1.0, 1.0)
    write_png(tmp_path / "paint.png", paint, 8)
    project_frame(manifest, 0, tmp_path / "paint.png")
    m = Manifest(manifest)
    a = load_edit(m.edit_path(m.layers[0]))[..., 3]
    # the stroke spans pixel centres 10.5..21.5 x 6.5..13.5 -> texels 31..64 x 19..40 (centres at 3x - 0.5)
    assert a[20:40, 32:64].min() == 1.0
    assert a[:14, :].max() == 0.0 and a[46:, :].max() == 0.0 and a[:, :25].max() == 0.0 and a[:, 71:].max() == 0.0


def test_paint_goes_to_the_layer_that_owns_the_pixel(tmp_path):
    """Two layers, foreground opaque on the left half: paint on the left lands only in the foreground."""
    plate = _plate(t=1)
    w, h = 32, 24
    fg_alpha = lambda xs: (xs < 16).astype(np.float64)  # noqa: E731
    bg = (lambda t, xs, ys: (xs / w, 1.0 - ys / h, 1.0 - fg_alpha(xs)), (w, h))
    fg = (lambda t, xs, ys: (xs / w, 1.0 - ys / h, fg_alpha(xs)), (w, h))
    manifest = make_fake_export(tmp_path, plate, [bg, fg])
    paint = np.zeros((h, w, 4), np.float32)
    paint[4:20, 4:12] = (1.0, 0.0, 0.0, 1.0)  # on the foreground
    paint[4:20, 20:28] = (0.0, 0.0, 1.0, 1.0)  # on the background
    write_png(tmp_path / "paint.png", paint, 8)
    project_frame(manifest, 0, tmp_path / "paint.png")
    m = Manifest(manifest)
    bg_edit, fg_edit = (load_edit(m.edit_path(layer)) for layer in m.layers)
    assert fg_edit[4:20, 4:12, 0].min() > 0.99 and fg_edit[:, 16:, 3].max() == 0.0
    assert bg_edit[4:20, 20:28, 2].min() > 0.99 and bg_edit[:, :16, 3].max() == 0.0


def test_over_composites_premultiplied():
    top = np.array([0.5, 0.0, 0.0, 0.5], np.float32)
    bottom = np.array([0.0, 1.0, 0.0, 1.0], np.float32)
    np.testing.assert_allclose(over(top, bottom), [0.5, 0.5, 0.0, 1.0])


def test_render_writes_png_frames_and_a_movie(tmp_path):
    yy, xx = np.mgrid[0:23, 0:31] / 31.0
    smooth = np.stack([0.2 + 0.6 * xx, 0.3 + 0.5 * yy, 0.5 + 0.2 * xx * yy], -1).astype(np.float32)
    plate = np.stack([smooth] * 4)  # odd sizes: the movie pads to even sides; smooth, as chroma is subsampled
    manifest = make_fake_export(tmp_path, plate, [_identity_layer(31, 23)])
    out = render_manifest(
        manifest, tmp_path / "png", settings=RenderSettings("png"), movie=tmp_path / "edit.mp4", progress_bar=False
    )
    assert out == tmp_path / "edit.mp4"
    pngs = sorted((tmp_path / "png").glob("edit.*.png"))
    assert [p.name for p in pngs] == [f"edit.{t:05d}.png" for t in range(4)]
    with av.open(str(out)) as container:
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    assert len(frames) == 4 and frames[0].shape == (24, 32, 3)
    assert np.abs(frames[2][:23, :31].astype(float) / 255 - plate[2]).mean() < 0.03  # lossy codec
    exr_out = render_manifest(manifest, tmp_path / "exr", progress_bar=False)
    got = read_exr(exr_out / "edit.00001.exr")
    rgb = np.stack([got[c] for c in "RGB"], -1)
    assert np.abs(rgb - srgb_to_linear(np.rint(plate[1] * 255) / 255)).max() < 1e-6  # the plate, as decoded


@pytest.mark.parametrize(
    ("mutate", "needle"),
    [
        (lambda d: d.update({"neural_atlas_manifest": 99}), "manifest version 99 is not supported"),
        (lambda d: d.pop("passes"), "manifest has no 'passes'"),
        (lambda d: d["layers"][0].pop("uv_pass"), "manifest layer 0 has no 'uv_pass'"),
        (lambda d: d["layers"][0].update({"role": "sky"}), "unknown role 'sky'"),
        (lambda d: d["passes"].update({"frames": []}), "lists no frames"),
    ],
)
def test_a_manifest_off_the_contract_is_a_one_line_error(tmp_path, capsys, mutate, needle):
    import json

    from engine import cli
    from engine import contract as C

    manifest = make_fake_export(tmp_path, _plate(t=1), [_identity_layer(32, 24)])
    data = json.loads(manifest.read_text())
    mutate(data)
    manifest.write_text(json.dumps(data))
    assert cli.main(["render", str(manifest), "--out", str(tmp_path / "out")]) == C.EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0] and str(manifest) in err[0], err
    assert not (tmp_path / "out").exists()
