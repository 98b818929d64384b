"""End-to-end: a tiny fit on a synthetic scene with known motion reaches stated numbers.

Typical results (2-core CPU, about 35 s, default fast config): PSNR 32.8 dB, alpha IoU 0.91, atlas consistency
of background points 0.10 px median / 1.5 px p95, of foreground points 0.25 / 0.89 px. The bounds below leave
room for CPU/BLAS differences.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.engine.fit_helpers import atlas_consistency_px, fit_scene, load_model

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fit")
    scene, run, metrics = fit_scene(tmp)
    model, _ = load_model(run)
    return scene, run, metrics, model


def test_reconstruction_psnr(fitted):
    _, run, metrics, _ = fitted
    assert metrics["psnr"] >= 30.0
    on_disk = json.loads((run / "metrics.json").read_text())
    for key in ("psnr", "steps", "train_seconds", "preset", "device"):
        assert key in on_disk
    assert on_disk["steps"] == 400 and on_disk["device"] == "cpu" and on_disk["preset"] == "draft"


def test_foreground_alpha_follows_the_masks(fitted):
    assert fitted[2]["alpha_iou"][0] >= 0.8


def _bg_points(scene, rng, n=300):
    h, w = scene.frames.shape[1:3]
    pts0 = np.stack([rng.uniform(5, w - 5, n), rng.uniform(5, h - 5, n)], -1)
    return pts0, pts0 + scene.bg_offset[0]


def _visible(scene, p, t):
    h, w = scene.frames.shape[1:3]
    ok = (p[:, 0] > 1) & (p[:, 0] < w - 2) & (p[:, 1] > 1) & (p[:, 1] < h - 2)
    xi = np.clip(p[:, 0].round().astype(int), 0, w - 1)
    yi = np.clip(p[:, 1].round().astype(int), 0, h - 1)
    return ok & ~scene.masks[t][yi, xi]


def test_background_point_keeps_its_atlas_position(fitted):
    scene, _, _, model = fitted
    rng = np.random.default_rng(0)
    pts0, tex = _bg_points(scene, rng)
    errs = []
    for t in range(1, scene.frames.shape[0]):
        p = scene.bg_point_in_frame(tex, t)
        ok = _visible(scene, pts0, 0) & _visible(scene, p, t)
        errs.append(atlas_consistency_px(model, 0, [pts0[ok], p[ok]], [0, t]))
    e = np.concatenate(errs)
    assert np.median(e) < 0.4 and np.percentile(e, 95) < 2.5


def test_foreground_point_keeps_its_atlas_position(fitted):
    scene, _, _, model = fitted
    rng = np.random.default_rng(1)
    ys, xs = np.nonzero(scene.masks[0])
    sel = rng.choice(len(xs), 200)
    pts0 = np.stack([xs[sel], ys[sel]], -1).astype(float)
    tex = pts0 - scene.fg_offset[0]
    errs = [
        atlas_consistency_px(model, 1, [pts0, scene.fg_point_in_frame(tex, t)], [0, t])
        for t in range(1, scene.frames.shape[0])
    ]
    e = np.concatenate(errs)
    assert np.median(e) < 0.6 and np.percentile(e, 95) < 2.0
