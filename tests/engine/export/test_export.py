"""Export, render and project-frame on a synthetic scene with exact ground-truth motion.

Typical results (2-core CPU, the default 192x108x12 scene, the 400-step tiny fit of fit_helpers):
dots painted on the foreground atlas land 0.14 px (median) / 0.29 px (p95) from where the sprite's true
motion puts them, on the background atlas 0.04 / 0.41 px; project-frame then render reproduces a frame
edit exactly inside the strokes (0.016 mean abs error over whole strokes, rims included, through the
owning layer's alpha; 0.073 against the raw frame edit, because this short fit's alpha is about 0.9, not 1,
inside the sprite); an empty edit renders the plate to < 1e-6. Bounds leave room for CPU/BLAS differences.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
import torch

from engine import cli
from engine import contract as C
from engine.edit.equations import load_edit, sample_texture
from engine.edit.project_frame import project_frame
from engine.edit.render import render_frames, render_manifest
from engine.errors import DiskFullError
from engine.export.atlas_frame import BOX_ALPHA
from engine.export.exporter import export_run
from engine.export.manifest import Manifest
from engine.io.colour import srgb_to_linear
from engine.io.images import read_exr, read_image, write_png
from engine.terms.colour import COLOUR_BUILTIN_CONFIG, EXR_COLORSPACE_ATTRIBUTE
from engine.terms.export_names import PASS_PRECISION_COMPACT
from engine.terms.manifest import validate_manifest
from tests.engine.export.tiny_run import fail_exr_writes_after
from tests.engine.fit_helpers import fit_scene, load_model
from tests.folders import tree_digest
from tests.paths import ROOT

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("export")
    # components=all: this scene is an exact pan, which the scene analysis fits with the pan/zoom background
    # (no warp grid); the fidelity bounds below were calibrated on the full model at seed 0. They are seed-
    # fragile either way (measured, test_atlas_textures_are_the_fitted_atlases, seeds 0/1/2: all passes
    # 0 only (seed 1: no alpha > 0.7 core, seed 2: 11.8 dB); auto passes 1 and 2, fails 0 at 16.8 dB);
    # every other test here passes with auto at seed 0. The analysis' own export is in test_scene.py.
    scene, run, _ = fit_scene(tmp, components="all")
    manifest_path = export_run(run, atlas_size=256, progress_bar=False)
    return scene, run, manifest_path


def _dot_edit(size: tuple[int, int], uv: np.ndarray, radius_tex: float, rgb=(1.0, 0.0, 1.0)) -> np.ndarray:
    """An sRGB straight-alpha RGBA image with a soft dot centred at texture ``uv`` (bottom-left origin)."""
    w, h = size
    cx, cy = uv[0] * w - 0.5, (1.0 - uv[1]) * h - 0.5
    yy, xx = np.mgrid[0:h, 0:w]
    a = np.clip(1.5 - np.hypot(xx - cx, yy - cy) / radius_tex, 0.0, 1.0)
    img = np.zeros((h, w, 4), np.float32)
    img[..., :3] = rgb
    img[..., 3] = a
    return img


def _centroid(diff: np.ndarray, near: np.ndarray, window: float) -> np.ndarray | None:
    """Weighted centroid (scene coordinates: pixel [y, x] is the point (x, y)) of ``diff`` around ``near``."""
    h, w = diff.shape
    yy, xx = np.mgrid[0:h, 0:w]
    sel = np.hypot(xx - near[0], yy - near[1]) <= window
    wgt = diff * sel
    if wgt.sum() < 1e-3:
        return None
    return np.array([(wgt * xx).sum(), (wgt * yy).sum()]) / wgt.sum()


def test_pass_files_follow_the_contract(exported):
    scene, _, manifest_path = exported
    m = Manifest(manifest_path)
    h, w = scene.frames.shape[1:3]
    assert m.resolution == (w, h) and m.frames == list(range(scene.spec.frames))
    expected = set()
    for layer in m.layers:
        expected |= {C.channel_name(layer["uv_pass"], c) for c in ("U", "V", "A")}
        expected.add(C.channel_name(layer["alpha_pass"], "V"))
    assert expected == {
        "Atlas.UVBackground.U", "Atlas.UVBackground.V", "Atlas.UVBackground.A", "Atlas.AlphaBackground.V",
        "Atlas.UVForeground.U", "Atlas.UVForeground.V", "Atlas.UVForeground.A", "Atlas.AlphaForeground.V",
    }  # fmt: skip
    # no STMap copy unless asked (export --stmap: tests/engine/export/test_nuke.py)
    assert not any("stmap_pass" in layer for layer in m.layers)
    for f in m.frames:
        path = m.pass_path(f)
        assert path.name == f"atlas.{f:05d}.exr"
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            chans = exr.channels()
            assert set(chans) == expected
            for ch in chans.values():
                assert ch.pixels.dtype == np.float32 and ch.pixels.shape == (h, w)
        passes = m.read_passes(f)
        total = sum(p.alpha for p in passes)
        # the layers' weights sum to one; a compact export rounds each down to half float's precision (< 2^-11)
        assert m.data["passes"]["precision"] == PASS_PRECISION_COMPACT
        assert (total <= 1.0 + 1e-6).all() and (total >= 1.0 - len(passes) * 2.0**-11).all()
        for p in passes:
            assert p.uv.min() >= 0.0 and p.uv.max() <= 1.0
            assert np.all(p.z <= p.alpha + 1e-7) and np.all(p.z >= 0.0)
        # the layers' alphas follow the sprite: foreground owns the mask, background the rest
        fg = passes[1].alpha > 0.5
        iou = (fg & scene.masks[f]).sum() / (fg | scene.masks[f]).sum()
        assert iou > 0.8, f"frame {f}: foreground alpha IoU {iou:.3f}"
        # wherever a layer is visible its atlas box covers the pixel (Z = alpha, not cut to 0)
        for p in passes:
            visible = p.alpha > BOX_ALPHA
            assert np.array_equal(p.z[visible], p.alpha[visible])


REC709 = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)


def _header(path, name):
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    try:
        return inp.spec().getattribute(name)
    finally:
        inp.close()


def test_manifest_and_files(exported):
    _, run, manifest_path = exported
    data = json.loads(Path(manifest_path).read_text())
    assert validate_manifest(data) is data
    assert Path(manifest_path).parent == run / "exports" / "v001"
    m = Manifest(manifest_path)
    assert [layer["name"] for layer in m.layers] == ["Background", "Foreground"]
    assert data["fit"]["steps"] == 400 and data["fit"]["psnr"] > 25
    assert (data["clip"]["colorspace"], data["clip"]["colour_config"]) == (C.COLOUR_SRGB, COLOUR_BUILTIN_CONFIG)
    assert data["clip"]["resolution"] == [192, 108]
    # the passes are data: OCIO readers take them raw
    assert _header(m.pass_path(m.frames[0]), EXR_COLORSPACE_ATTRIBUTE) == "Raw"
    for layer in m.layers:
        n = layer["name"]
        assert layer["channels"] == [f"Atlas.UV{n}.U", f"Atlas.UV{n}.V", f"Atlas.UV{n}.A", f"Atlas.Alpha{n}.V"]
        w, h = layer["atlas_size"]
        assert max(w, h) == 256
        exr = read_exr(m.resolve(layer["atlas_exr"]))
        assert set(exr) == {"R", "G", "B", "A"} and exr["A"].shape == (h, w)
        png, is_float = read_image(m.resolve(layer["atlas_png"]))
        assert png.shape == (h, w, 4) and not is_float
        edit = m.edit_path(layer)
        assert edit.parent == run / "edits"
        e, _ = read_image(edit)
        assert e.shape == (h, w, 4) and e.max() == 0.0
        # tagged: the atlas EXR scene-linear Rec.709 (its chromaticities), the PNGs sRGB (their sRGB chunk)
        assert _header(m.resolve(layer["atlas_exr"]), "chromaticities") == pytest.approx(REC709, abs=1e-6)
        assert _header(m.resolve(layer["atlas_exr"]), EXR_COLORSPACE_ATTRIBUTE) == C.COLOUR_SCENE_LINEAR
        assert b"sRGB" in Path(m.resolve(layer["atlas_png"])).read_bytes()[:200]
        # EXR is linear premultiplied, PNG sRGB straight: the same atlas
        np.testing.assert_allclose(exr["A"], png[..., 3], atol=2e-5)
        np.testing.assert_allclose(exr["R"], srgb_to_linear(png[..., 0]) * png[..., 3], atol=2e-4)


def test_atlas_textures_are_the_fitted_atlases(exported):
    """The exported textures are the networks' atlases (fidelity), and each holds its own layer: sampled at
    a pixel's UV, the sprite atlas gives the sprite's true texture and the background atlas the true
    background (decomposition; bounds from the tiny 400-step fit: about 21.6 and 25.0 dB measured)."""
    scene, run, manifest_path = exported
    m = Manifest(manifest_path)
    model, _ = load_model(run)
    atlases = [read_image(m.resolve(layer["atlas_png"]))[0] for layer in m.layers]
    for f in (0, 6, 11):
        passes = m.read_passes(f)
        mk = scene.masks[f]
        ys, xs = np.nonzero(mk)
        with torch.no_grad():
            xy = torch.tensor(np.stack([xs + 0.5, ys + 0.5], -1), dtype=torch.float32)
            tt = torch.full((len(xs),), f, dtype=torch.long)
            net = model.color(1, model.uv(1, xy, tt)).numpy()
        sampled = sample_texture(atlases[1], passes[1].uv)[mk]
        assert np.abs(sampled[:, :3] - net).mean() < 0.01  # texel discretisation + 16-bit rounding only
        core = passes[1].alpha[mk] > 0.7
        truth = scene.fg_color(np.stack([xs, ys], -1) - scene.fg_offset[f])
        assert _psnr(sampled[core, :3], truth[core]) > 19.0
        assert np.median(sampled[:, 3]) > 0.6  # the sprite's texels are covered (median alpha over frames)
        ys, xs = np.nonzero(~mk)
        sampled = sample_texture(atlases[0], passes[0].uv)[~mk]
        assert _psnr(sampled[:, :3], scene.bg_color(np.stack([xs, ys], -1) + scene.bg_offset[f])) > 22.0
        assert np.median(sampled[:, 3]) > 0.9  # max over frames: every visible background texel


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(-10.0 * np.log10(np.mean((a - b) ** 2)))


def _dot_errors(scene, manifest_path, layer_index: int, tex_point, radius_px: float = 2.0):
    m = Manifest(manifest_path)
    layer = m.layers[layer_index]
    w, h = layer["atlas_size"]
    truth = scene.fg_point_in_frame if layer_index == 1 else scene.bg_point_in_frame
    p0 = truth(tex_point, 0)
    uv0 = m.read_passes(0)[layer_index].uv[round(p0[1]), round(p0[0])]
    # the UV at the nearest pixel centre; correct it to the sub-pixel point by the local UV gradient
    passes0 = m.read_passes(0)[layer_index].uv
    xi, yi = round(p0[0]), round(p0[1])
    du = (passes0[yi, xi + 1] - passes0[yi, xi - 1]) / 2.0
    dv = (passes0[yi + 1, xi] - passes0[yi - 1, xi]) / 2.0
    uv0 = uv0 + du * (p0[0] - xi) + dv * (p0[1] - yi)
    # a dot a few frame pixels wide, so its rendered centroid is a sub-pixel measurement
    texels_per_px = float(np.hypot(du[0] * w, du[1] * h))
    edit = _dot_edit((w, h), uv0, radius_px * texels_per_px)
    path = m.edit_path(layer).parent / f"dot_{layer['name']}.png"
    write_png(path, edit, 16)
    errs = []
    plate_cache = {}
    for f, frame in render_frames(m, [load_edit(path) if i == layer_index else None for i in range(len(m.layers))]):
        from engine.edit.render import plate_frames

        if f not in plate_cache:
            plate_cache.update(dict(plate_frames(m, [f])))
        diff = np.abs(frame - plate_cache[f]).sum(-1)
        expected = truth(tex_point, f)
        hh, ww = diff.shape
        if not (4 <= expected[0] < ww - 4 and 4 <= expected[1] < hh - 4):
            continue
        if (
            layer_index == 0
            and scene.masks[f][
                max(0, int(expected[1]) - 4) : int(expected[1]) + 5, max(0, int(expected[0]) - 4) : int(expected[0]) + 5
            ].any()
        ):
            continue  # the background point is behind (or next to) the sprite in this frame
        got = _centroid(diff, expected, window=6.0)
        assert got is not None, f"frame {f}: the dot vanished"
        errs.append(np.hypot(*(got - expected)))
    path.unlink()
    return np.array(errs)


def test_atlas_paint_follows_the_foreground(exported):
    scene, _, manifest_path = exported
    sw, sh = scene.spec.fg_size
    errs = np.concatenate([_dot_errors(scene, manifest_path, 1, np.array(p)) for p in
                           [(sw * 0.5, sh * 0.5), (sw * 0.3, sh * 0.4), (sw * 0.65, sh * 0.6)]])  # fmt: skip
    med, p95 = float(np.median(errs)), float(np.percentile(errs, 95))
    print(f"foreground dot: median {med:.3f} px, p95 {p95:.3f} px over {len(errs)} frame samples")
    assert len(errs) >= 30
    assert med < 1.0 and p95 < 2.0


def test_atlas_paint_follows_the_background(exported):
    scene, _, manifest_path = exported
    points = [np.array(p) + scene.bg_offset[0] for p in [(20, 20), (150, 80), (170, 25)]]
    errs = np.concatenate([_dot_errors(scene, manifest_path, 0, p) for p in points])
    med, p95 = float(np.median(errs)), float(np.percentile(errs, 95))
    print(f"background dot: median {med:.3f} px, p95 {p95:.3f} px over {len(errs)} frame samples")
    assert len(errs) >= 20
    assert med < 1.0 and p95 < 2.0


def test_empty_edits_render_the_plate_exactly(exported, tmp_path):
    scene, _, manifest_path = exported
    out = render_manifest(manifest_path, tmp_path / "render", progress_bar=False)
    for f in (0, 5, 11):
        got = read_exr(out / f"edit.{f:05d}.exr")
        rgb = np.stack([got["R"], got["G"], got["B"]], -1)
        plate = srgb_to_linear(np.rint(scene.frames[f] * 255) / 255)
        assert np.abs(rgb - plate).max() < 1e-6
        assert np.all(got["A"] == 1.0)


def test_project_frame_reproduces_the_edit_and_carries_it(exported, tmp_path):
    scene, run, manifest_path = exported
    m = Manifest(manifest_path)
    h, w = scene.frames.shape[1:3]
    edits_before = tree_digest(run / "edits")
    # paint a disc on the sprite and one on the background, on frame 3
    f0 = 3
    fg_centre = scene.fg_point_in_frame(np.array(scene.spec.fg_size) / 2.0, f0)
    bg_centre = np.array([25.0, 80.0])
    yy, xx = np.mgrid[0:h, 0:w]
    paint = np.zeros((h, w, 4), np.float32)
    for centre, colour in ((fg_centre, (0.0, 1.0, 0.0)), (bg_centre, (1.0, 1.0, 0.0))):
        disc = np.hypot(xx - centre[0], yy - centre[1]) <= 5.0
        paint[disc, :3] = colour
        paint[disc, 3] = 1.0
    paint_path = tmp_path / "paint.png"
    write_png(paint_path, paint, 8)
    written = project_frame(manifest_path, f0, paint_path)
    assert set(written) == {"Background", "Foreground"}
    assert list((run / "edits" / "history").iterdir()), "the previous edit layers were not kept"
    frames = dict(render_frames(m, [load_edit(m.edit_path(layer)) for layer in m.layers]))
    plate = srgb_to_linear(np.rint(scene.frames[f0] * 255) / 255)
    a = paint[..., 3:4]
    inside = paint[..., 3] > 0
    raw = np.abs(frames[f0] - (plate * (1 - a) + srgb_to_linear(paint[..., :3]) * a))[inside]
    # paint goes to the layer that owns the pixel, so on its own frame it shows through that layer's alpha
    passes = m.read_passes(f0)
    owner = np.maximum(passes[0].z, passes[1].z)[..., None]
    expected = plate * (1 - a * owner) + srgb_to_linear(paint[..., :3]) * a * owner
    err = np.abs(frames[f0] - expected)[inside]
    print(
        f"project-frame on frame {f0}: vs the frame edit mean abs {raw.mean():.4f} (owner alpha median "
        f"{np.median(owner[inside]):.3f}); vs the edit through the owner's alpha mean abs {err.mean():.4f}, "
        f"p95 {np.percentile(err, 95):.4f}"
    )
    # inside the strokes the splat is exact up to 8-bit rounding; at their rims it is interpolated
    import cv2

    core = cv2.erode(inside.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    err_core = np.abs(frames[f0] - expected)[core]
    print(f"   in the strokes' cores: mean abs {err_core.mean():.4f}, max {err_core.max():.4f}")
    assert err_core.mean() < 0.01 and err.mean() < 0.03 and np.percentile(err, 95) < 0.15
    assert raw.mean() < 0.15
    outside = np.abs(frames[f0] - plate)[~inside].max(-1)
    assert np.percentile(outside, 99) < 0.02  # nothing bleeds outside the paint
    # the sprite disc moves with the sprite in every frame
    errs = []
    for f in range(scene.spec.frames):
        green = np.clip(frames[f][..., 1] - frames[f][..., 0], 0, None) * (frames[f][..., 1] > 0.6)
        expected_c = scene.fg_point_in_frame(np.array(scene.spec.fg_size) / 2.0, f)
        got = _centroid(green, expected_c, window=8.0)
        assert got is not None
        errs.append(np.hypot(*(got - expected_c)))
    print(f"projected foreground disc: median {np.median(errs):.3f} px, max {np.max(errs):.3f} px")
    assert np.median(errs) < 1.0 and np.max(errs) < 2.0
    # restore the artist's (empty) edit layers for the other tests; history kept the originals
    for layer in m.layers:
        hist = sorted((run / "edits" / "history").glob(f"{layer['name']}.*"))[0]
        m.edit_path(layer).write_bytes(hist.read_bytes())
    assert tree_digest(run / "edits") == {**edits_before, **{k: v for k, v in tree_digest(run / "edits").items()
                                                             if k.startswith("history")}}  # fmt: skip


def test_reexport_never_touches_paint_or_earlier_exports(exported, tmp_path):
    _, run, manifest_path = exported
    m = Manifest(manifest_path)
    fg = m.layer("Foreground")
    w, h = fg["atlas_size"]
    paint = np.zeros((h, w, 4), np.float32)
    paint[h // 3 : h // 2, w // 3 : w // 2] = (1.0, 0.5, 0.0, 1.0)
    original = m.edit_path(fg).read_bytes()
    write_png(m.edit_path(fg), paint, 8)
    try:
        edits_hash = tree_digest(run / "edits")
        v1_hash = tree_digest(Path(manifest_path).parent)
        second = export_run(run, atlas_size=128, frames=(2, 4), progress_bar=False)
        assert second.parent.name == "v002"
        assert tree_digest(run / "edits") == edits_hash
        assert tree_digest(Path(manifest_path).parent) == v1_hash
        m2 = Manifest(second)
        assert m2.frames == [2, 3, 4]
        # the painted layer keeps its atlas frame, so the paint stays where it was painted
        assert m2.layer("Foreground")["atlas_box"] == fg["atlas_box"]
        u1 = m.read_passes(3)[1].uv
        u2 = m2.read_passes(3)[1].uv
        assert np.abs(u1 - u2).max() < 1e-5
    finally:
        m.edit_path(fg).write_bytes(original)


def test_killed_export_leaves_nothing_behind(exported, monkeypatch):
    _, run, _ = exported
    before = sorted(p.name for p in (run / "exports").iterdir())
    edits = tree_digest(run / "edits")
    fail_exr_writes_after(monkeypatch, 3)
    with pytest.raises(DiskFullError):  # the writer's ENOSPC, as the one-line error export_run raises for it
        export_run(run, atlas_size=64, progress_bar=False)
    assert sorted(p.name for p in (run / "exports").iterdir()) == before
    assert tree_digest(run / "edits") == edits


def test_cli_export_prints_the_manifest_last(exported, capsys):
    _, run, _ = exported
    assert cli.main(["export", str(run), "--atlas-size", "64", "--frames", "0:1", "--no-bar"]) == C.EXIT_OK
    out = capsys.readouterr().out.strip().splitlines()
    assert out[-1].endswith("manifest.json") and Path(out[-1]).exists()
    events = [C.parse_progress_line(line) for line in out]
    assert any(e and e["event"] == C.EVENT_EXPORTED and e["manifest"] == out[-1] for e in events)


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["export", "{tmp}"], "not a fitted run folder"),
        (["render", "{tmp}/manifest.json", "--out", "{tmp}/r"], "no manifest here"),
        (["render", "{manifest}", "--out", "{tmp}/r", "--edit", "Nope=x.png"], "no layer called 'Nope'"),
        (["render", "{manifest}", "--out", "{tmp}/r", "--edit", "Foreground"], "is not LAYER=IMAGE"),
        (["project-frame", "{manifest}", "--frame", "99", "--edit", "{tmp}/x.png"], "has no passes"),
        (["export", "{run}", "--frames", "5:40"], "outside the fitted frames"),
    ],
)
def test_bad_input_is_one_line(exported, tmp_path, capsys, argv, needle):
    _, run, manifest_path = exported
    args = [a.format(tmp=tmp_path, manifest=manifest_path, run=run) for a in argv]
    assert cli.main(args) == C.EXIT_BAD_INPUT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0], err


def test_disk_full_during_export_is_one_line_and_loses_nothing(exported, monkeypatch, capsys):
    _, run, _ = exported
    before = tree_digest(run / "exports")
    edits = tree_digest(run / "edits")
    fail_exr_writes_after(monkeypatch, 2)
    assert cli.main(["export", str(run), "--atlas-size", "64", "--no-bar"]) == C.EXIT_BAD_INPUT
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and err[0].startswith("error: disk full: free ") and "intact" in err[0], err
    assert tree_digest(run / "exports") == before
    assert tree_digest(run / "edits") == edits


def test_sigkill_during_export_leaves_no_partial_result(exported):
    import os
    import signal
    import subprocess
    import sys
    import time

    _, run, _ = exported
    exports = run / "exports"
    finished = {p.name for p in exports.iterdir() if not p.name.startswith(".")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "engine", "export", str(run), "--atlas-size", "64", "--no-bar"],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline and not list(exports.glob(".*.partial/passes/atlas.*.exr")):
            time.sleep(0.02)
        assert list(exports.glob(".*.partial/passes/atlas.*.exr")), "the export never started writing passes"
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    assert {p.name for p in exports.iterdir() if not p.name.startswith(".")} == finished  # no half export
    again = export_run(run, atlas_size=64, progress_bar=False)
    assert again.exists() and again.parent.name not in finished
    assert not list(exports.glob(".*.partial"))  # the dead export's leftovers were cleared


def test_refit_into_an_exported_run_never_touches_paint_or_exports(exported, capsys):
    _, run, _ = exported
    rec = json.loads((run / "clip.json").read_text())
    protected = {**tree_digest(run / "edits"), **{f"x/{k}": v for k, v in tree_digest(run / "exports").items()}}
    argv = ["fit", rec["source"], "--mask", rec["masks"][0], "--out", str(run), "--no-bar"]
    assert cli.main(argv) == C.EXIT_BAD_INPUT  # a fit is never overwritten
    assert "already holds a fit" in capsys.readouterr().err
    assert cli.main(["fit", "--resume", "--out", str(run), "--no-bar"]) == C.EXIT_OK  # finished: nothing to do
    after = {**tree_digest(run / "edits"), **{f"x/{k}": v for k, v in tree_digest(run / "exports").items()}}
    assert after == protected
