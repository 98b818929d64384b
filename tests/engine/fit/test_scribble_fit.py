"""Scribbles (paper Sec. 4.4) end to end: one object made of two rigid parts that cross, one mask for
the whole object, red and green strokes on two frames -> each part in its own foreground layer.

The scene is the two-object crossing scene with the union of both silhouettes as the only mask: one
foreground layer would need a single rigid atlas for two parts moving in opposite directions (measured
with one layer: below). The strokes are the parts' eroded silhouettes on
frames 0 and 11. Measured: ownership (fraction of a part's visible pixels whose largest weight is its
layer) A 0.95 / B 0.97, IoU of the summed alphas vs the object mask 0.96 (400 steps, ~80 s alone).
With ONE foreground layer and the same mask (measured once, not a test: a second fit): PSNR 23.8 dB
against 30.3, and a part's texture point drifts by a median 11.8 (A) / 8.3 (B) px in the atlas.
NOT solved: part A's own atlas is rigid only piecewise (see test_part_atlas_rigidity_is_reported).
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import torch

from engine import contract as C
from engine.config import apply_overrides, preset_config
from engine.errors import InputError
from engine.fit.evaluation import render_frame
from engine.fit.fit_inputs import FitInputs
from engine.fit.fitted_run import load_run
from engine.terms.run_folder import RUN_CLIP
from tests.engine.fit_helpers import TINY_OVERRIDES, object_drift_per_frame, quiet_fit
from tests.two_object_scene import make_two_object_scene, write_two_object_scene

pytestmark = pytest.mark.slow

SCRIBBLED_FRAMES = (0, 11)


def write_strokes(scene, folder, frames=SCRIBBLED_FRAMES) -> None:
    folder.mkdir(parents=True)
    for t in frames:
        img = np.zeros((*scene.frames.shape[1:3], 3), np.uint8)
        for k in range(2):
            part = cv2.erode(scene.masks[k, t].astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
            img[part] = C.SCRIBBLE_COLOURS[k][::-1]  # BGR for OpenCV
        cv2.imwrite(str(folder / C.SCRIBBLE_FILE_FORMAT.format(t)), img)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("scribbles")
    scene = make_two_object_scene()
    frames_dir, mask_dirs = write_two_object_scene(scene, tmp / "clip", union=True)
    write_strokes(scene, tmp / "clip" / "scribbles")
    cfg = apply_overrides(preset_config("draft"), {**TINY_OVERRIDES, "atlas_margin_fg": "0.3"})
    run = tmp / "run"
    metrics = quiet_fit(run, cfg, FitInputs(frames_dir, mask_dirs, scribbles=tmp / "clip" / "scribbles"))
    return scene, run, metrics, tmp


def test_each_scribbled_part_lands_in_its_own_layer(fitted):
    scene, run, metrics, _ = fitted
    model, prepared, _ = load_run(run)  # the run remembers its scribbles: same model shape on reload
    assert model.num_layers == 3 and prepared.mask_layers == ((1, 2),)
    own = np.zeros(2)
    count = np.zeros(2)
    for t in range(scene.spec.frames):
        owner = render_frame(model, t, prepared.size, torch.device("cpu"))[1].argmax(-1)
        for k in range(2):
            own[k] += (owner[scene.masks[k, t]] == k + 1).sum()
            count[k] += scene.masks[k, t].sum()
    frac = own / count
    print(f"scribbles: ownership A {frac[0]:.3f}  B {frac[1]:.3f}; summed-alpha IoU {metrics['alpha_iou']}")
    assert frac.min() >= 0.85
    assert metrics["alpha_iou"][0] >= 0.85  # the mask is compared with the SUM of the parts' alphas
    clip = json.loads((run / RUN_CLIP).read_text())
    assert clip["scribbles"].endswith("scribbles")


def test_each_part_gets_a_rigid_atlas(fitted):
    """How rigid each part's own atlas is: median atlas distance (px) a part's texture point travels
    between frame 0 and frame t in its own layer. Measured at most 0.3 px (A) and 0.4 px (B). Before the
    gauge anchor and the whole-mask atlas box, part A's mapping jumped by ~29 px between frames 2 and 5
    (its atlas held A twice)."""
    scene, run, _, _ = fitted
    model, _, _ = load_run(run)
    drift = []
    for k in range(2):
        per_t = object_drift_per_frame(model, scene, k, seed=k)
        print(f"part {'AB'[k]}: own-layer atlas drift vs frame 0, median px per frame {np.round(per_t, 1).tolist()}")
        drift.append(per_t)
    assert max(drift[0]) < 1.0 and max(drift[1]) < 1.0


def test_scribbles_need_one_mask_and_two_colours(fitted, tmp_path):
    scene, _, _, tmp = fitted
    frames_dir = tmp / "clip" / "frames"
    cfg = apply_overrides(preset_config("draft"), {"steps": "1"})
    with pytest.raises(InputError, match="exactly one --mask"):
        quiet_fit(tmp_path / "a", cfg, FitInputs(frames_dir, scribbles=tmp / "clip" / "scribbles"))
    red_only = tmp_path / "red"
    red_only.mkdir()
    img = np.zeros((*scene.frames.shape[1:3], 3), np.uint8)
    img[10:20, 10:20] = (0, 0, 255)
    cv2.imwrite(str(red_only / "00000.png"), img)
    with pytest.raises(InputError, match="green"):
        quiet_fit(tmp_path / "b", cfg, FitInputs(frames_dir, [tmp / "clip" / "masks"], scribbles=red_only))
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()  # bad input writes nothing
