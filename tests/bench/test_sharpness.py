"""Atlas sharpness on a hand-made export whose UVs land on texel centres exactly: a texture sliding 2 px left per
frame, seen through one layer. The atlas that IS the texture re-renders the plate to the PSNR cap; the same atlas
blurred gives exactly the PSNR of the blurred texture against the sharp one, inside the mask."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from bench.__main__ import main as bench_main
from bench.sharpness import (
    MIN_MASK_PIXELS,
    PSNR_CAP_DB,
    UNPREMULT_MIN_COVERAGE,
    atlas_sharpness,
    masked_psnr,
    rerender,
)
from engine import contract as C
from engine.export.manifest import LayerPasses
from engine.io.colour import linear_to_srgb, srgb_to_linear
from engine.io.images import write_exr, write_png
from engine.terms.export_names import ATLAS_EXR_EXT, ATLASES_DIR
from tests.engine.fake_export import make_fake_export

W, H, T = 40, 32, 4
VX = 2  # texels per frame: integer, so every UV is a texel centre
AW, AH = W + (T - 1) * VX, H
EMPTY_MASK_FRAME = 2


def _texture() -> np.ndarray:
    """8-bit code values (k / 255), so the plate's PNG holds them exactly."""
    rng = np.random.default_rng(1)
    smooth = cv2.GaussianBlur(rng.random((AH, AW, 3)).astype(np.float32), (0, 0), 1.0)
    smooth = (smooth - smooth.min()) / (smooth.max() - smooth.min())
    return np.rint(smooth * 255.0).astype(np.float32) / 255.0


def _mask(t: int) -> np.ndarray:
    m = np.zeros((H, W), np.float32)
    if t != EMPTY_MASK_FRAME:
        m[6:26, 8 + t : 30 + t] = 1.0
    return m


def _export(folder: Path, atlas_linear: np.ndarray) -> tuple[Path, Path, Path]:
    tex = _texture()
    plate = np.stack([tex[:, t * VX : t * VX + W] for t in range(T)])

    def layer(t, xs, ys):
        return (xs + t * VX) / AW, 1.0 - ys / AH, np.ones_like(xs, dtype=np.float32)

    manifest = make_fake_export(folder, plate, [(layer, (AW, AH))])
    chans = {c: atlas_linear[..., i] for i, c in enumerate("RGB")}
    write_exr(manifest.parent / ATLASES_DIR / f"Background{ATLAS_EXR_EXT}", {**chans, "A": np.ones((AH, AW))})
    masks = folder / "masks"
    for t in range(T):
        write_png(masks / f"{t:05d}.png", _mask(t)[..., None], 8, srgb=False)
    return manifest, folder / "clip", masks


def test_a_perfect_atlas_scores_the_cap(tmp_path):
    manifest, plate, masks = _export(tmp_path, srgb_to_linear(_texture()))
    report = atlas_sharpness(manifest, plate, [masks])
    assert report["per_frame"][str(EMPTY_MASK_FRAME)] is None
    assert report["frames_scored"] == T - 1
    assert report["psnr_mean"] == pytest.approx(PSNR_CAP_DB, abs=1e-9)
    assert report["psnr_pooled"] == pytest.approx(PSNR_CAP_DB, abs=1e-9)


def test_a_blurred_atlas_scores_the_blurred_textures_psnr(tmp_path):
    blurred = cv2.GaussianBlur(srgb_to_linear(_texture()), (0, 0), 1.5)
    manifest, plate, masks = _export(tmp_path, blurred)
    report = atlas_sharpness(manifest, plate, [masks])
    sharp, soft = _texture(), np.clip(linear_to_srgb(blurred), 0.0, 1.0)
    for t in range(T):
        m = _mask(t) > 0.5
        if not m.any():
            continue
        diff = soft[:, t * VX : t * VX + W][m] - sharp[:, t * VX : t * VX + W][m]
        expected = 10.0 * np.log10(1.0 / np.mean(diff.astype(np.float64) ** 2))
        assert report["per_frame"][str(t)] == pytest.approx(expected, abs=1e-3)
    assert 15.0 < report["psnr_mean"] < 40.0


def test_the_same_image_scores_the_cap_and_an_empty_mask_none():
    a = np.random.default_rng(2).random((8, 8, 3))
    assert MIN_MASK_PIXELS == 1
    assert masked_psnr(a, a, np.ones((8, 8), bool)) == PSNR_CAP_DB
    assert masked_psnr(a, a + 0.1, np.zeros((8, 8), bool)) is None
    assert masked_psnr(a, a + 0.1, np.ones((8, 8), bool)) == pytest.approx(20.0)


def test_rerender_unpremultiplies_and_gives_black_where_the_atlas_has_no_coverage():
    """A texel at half coverage gives back its straight colour; one with coverage at or below
    UNPREMULT_MIN_COVERAGE gives black, not a division by zero."""
    atlas = np.zeros((1, 2, 4), np.float32)
    atlas[0, 0] = [0.3 * 0.5, 0.6 * 0.5, 0.9 * 0.5, 0.5]
    atlas[0, 1] = [1.0, 1.0, 1.0, UNPREMULT_MIN_COVERAGE / 2]
    uv = np.array([[[0.25, 0.5], [0.75, 0.5]]], np.float32)  # the two texel centres
    passes = LayerPasses(uv=uv, z=np.ones((1, 2), np.float32), alpha=np.ones((1, 2), np.float32))
    out = rerender([passes], [atlas])
    np.testing.assert_allclose(out[0, 0], [0.3, 0.6, 0.9], rtol=1e-6)
    np.testing.assert_array_equal(out[0, 1], [0.0, 0.0, 0.0])


def test_cli_prints_the_mean_and_a_plate_of_another_size_is_one_line(tmp_path):
    manifest, plate, masks = _export(tmp_path, srgb_to_linear(_texture()))
    out = tmp_path / "sharp.json"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = bench_main(["sharpness", str(manifest), "--plate", str(plate), "--masks", str(masks), "--json", str(out)])
    assert rc == C.EXIT_OK
    assert buf.getvalue().splitlines()[0] == "sharpness: masked PSNR mean 100.00 dB, pooled 100.00 dB, 3 frames"
    assert json.loads(out.read_text())["frames_scored"] == T - 1
    other = tmp_path / "other"
    for t in range(T):
        write_png(other / f"{t:05d}.png", np.zeros((H, W + 2, 3), np.float32), 8)
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = bench_main(["sharpness", str(manifest), "--plate", str(other), "--masks", str(masks)])
    assert rc == C.EXIT_BAD_INPUT
    assert err.getvalue().strip().splitlines() == [
        f"error: {other}: plate is {W + 2}x{H}, the export's passes are {W}x{H} — pass the plate the export was "
        "made from"
    ]


def test_the_networks_ceiling_over_every_pixel_is_the_fits_own_psnr(tmp_path):
    """``sharpness --run``: the fit's networks rendered at the working size against the plate. With a mask over every
    pixel it is the PSNR the fit itself reports (evaluate_full, a separate path) to 1e-4 dB; inside the object's
    mask it is a number of its own, pooled from the per-frame values."""
    from bench.network_sharpness import network_sharpness
    from engine.data.synthetic import SceneSpec, make_scene, write_scene
    from tests.engine_cli import run_cli
    from tests.stability.bad_inputs import TINY_FIT

    spec = SceneSpec(width=32, height=24, frames=3, fg_size=(12, 10), fg_start=(8.0, 6.0))
    frames, masks = write_scene(make_scene(spec), tmp_path / "clip")
    run = tmp_path / "run"
    assert run_cli("fit", frames, "--mask", masks, "--out", run, *TINY_FIT)[0] == C.EXIT_OK
    full = tmp_path / "full"
    full.mkdir()
    for p in sorted(Path(masks).iterdir()):
        cv2.imwrite(str(full / p.name), np.full((spec.height, spec.width), 255, np.uint8))
    fitted_psnr = json.loads((run / C.RUN_METRICS).read_text())["psnr"]
    assert abs(network_sharpness(run, frames, [full])["psnr_pooled"] - fitted_psnr) < 1e-4
    inside = network_sharpness(run, frames, [masks])
    values = [v for v in inside["per_frame"].values() if v is not None]
    assert len(values) == spec.frames and min(values) <= inside["psnr_pooled"] <= max(values)
    assert run_cli("export", run, "--no-bar")[0] == C.EXIT_OK
    manifest = run / C.EXPORTS_DIR / "v001" / "manifest.json"
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        argv = ["sharpness", manifest, "--plate", frames, "--masks", masks, "--run", run]
        code = bench_main([str(a) for a in argv])
    assert code == C.EXIT_OK
    assert out.getvalue().splitlines()[-1] == f"sharpness: the fit's networks, pooled {inside['psnr_pooled']:.2f} dB"
