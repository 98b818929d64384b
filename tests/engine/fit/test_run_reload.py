"""A run reloads into exactly the model it was fitted with, whatever today's code would build from scratch.

The atlas boxes and starting motions are derived from masks and flow; a later engine (or another OpenCV) may
derive them differently, and an earlier fit must still export and resume: the checkpoint carries them.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from engine import contract as C
from engine.config import apply_overrides, preset_config
from engine.data.synthetic import make_scene, write_scene
from engine.errors import InputError
from engine.fit.checkpoint import load_checkpoint, save_checkpoint
from engine.fit.fit_inputs import FitInputs
from engine.fit.fitted_run import load_run
from engine.fit.prepare import to_fitting_values
from engine.io.clip import open_clip, read_frames
from engine.terms.run_folder import RUN_CONFIG
from tests.engine.fit_helpers import TINY_OVERRIDES, fit_scene, quiet_fit


def test_checkpoint_motions_rebuild_the_fitted_model_even_when_the_box_rule_changes(tmp_path):
    _, run, _ = fit_scene(tmp_path, steps="30", eval_every="30")
    model, _, _ = load_run(run)
    state = load_checkpoint(run / C.RUN_CHECKPOINT, torch.device("cpu"))
    assert len(state["motions"]) == model.num_layers == 2
    xy = torch.tensor([[10.5, 20.5], [100.5, 50.5]])
    t = torch.tensor([0, 5])
    with torch.no_grad():
        ref = [model.uv(i, xy, t) for i in range(2)] + [model.color(1, torch.zeros(1, 2))]

    # today's code would draw the foreground box from the eroded masks: without the saved motions the
    # grids would get other shapes (a load error) or other scales (paint in the wrong place)
    cfg_path = run / RUN_CONFIG
    data = json.loads(cfg_path.read_text())
    data["config"]["atlas_box_full_mask"] = False
    data["config"]["atlas_margin_fg"] = 0.4
    cfg_path.write_text(json.dumps(data))
    again, _, _ = load_run(run)
    with torch.no_grad():
        out = [again.uv(i, xy, t) for i in range(2)] + [again.color(1, torch.zeros(1, 2))]
    for a, b in zip(ref, out, strict=True):
        assert torch.equal(a, b)


def test_a_checkpoint_without_saved_motions_is_refused_in_one_line(tmp_path):
    """Checkpoints from before the saved motions (an unreleased format) are not rebuilt from today's masks and
    flow: loading one is a one-line error naming the checkpoint and the fix."""
    _, run, _ = fit_scene(tmp_path, steps="30", eval_every="30")
    path = run / C.RUN_CHECKPOINT
    state = load_checkpoint(path, torch.device("cpu"))
    del state["motions"]
    save_checkpoint(path, state)
    with pytest.raises(InputError, match="checkpoint has no 'motions' — fit into a new run folder") as err:
        load_run(run)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_a_run_reloads_its_plate_in_the_colour_space_it_was_fitted_in(tmp_path):
    """``fit --colorspace ACEScg`` on PNG frames (whose default is sRGB): the reloaded clip is read as ACEScg, the
    frames the fit saw, not as today's default for the file type would read it."""
    scene = make_scene()
    frames_dir, masks_dir = write_scene(scene, tmp_path / "clip")
    cfg = apply_overrides(preset_config("draft"), {**TINY_OVERRIDES, "steps": "4", "eval_every": "4"})
    run = tmp_path / "run"
    quiet_fit(run, cfg, FitInputs(frames_dir, [masks_dir], colorspace="ACEScg"))
    _, prepared, _ = load_run(run)
    assert prepared.info.colorspace == "ACEScg"
    fresh = open_clip(frames_dir)
    assert fresh.colorspace != "ACEScg"
    seen, _ = to_fitting_values(read_frames(prepared.info, prepared.frames.shape[2:0:-1]), "ACEScg",
                                colour_config=prepared.info.colour_config)  # fmt: skip
    assert np.array_equal(prepared.frames, seen)
