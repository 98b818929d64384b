"""A run reloads into exactly the model it was fitted with, whatever today's code would build from scratch.

The atlas boxes and starting motions are derived from masks and flow; a later engine (or another OpenCV) may
derive them differently, and an earlier fit must still export and resume: the checkpoint carries them.
"""

from __future__ import annotations

import json

import torch

from engine import contract as C
from engine.config import FitConfig
from engine.fit.checkpoint import load_checkpoint, save_checkpoint
from engine.fit.trainer import load_run
from tests.engine.fit_helpers import fit_scene


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
    cfg_path = run / C.RUN_CONFIG
    data = json.loads(cfg_path.read_text())
    data["config"]["atlas_box_full_mask"] = False
    data["config"]["atlas_margin_fg"] = 0.4
    cfg_path.write_text(json.dumps(data))
    again, _, _ = load_run(run)
    with torch.no_grad():
        out = [again.uv(i, xy, t) for i in range(2)] + [again.color(1, torch.zeros(1, 2))]
    for a, b in zip(ref, out, strict=True):
        assert torch.equal(a, b)


def test_a_run_from_before_saved_motions_still_loads(tmp_path):
    """Checkpoints without ``motions`` and configs without ``atlas_box_full_mask`` (earlier engine versions)
    rebuild with the rule they were made with: the eroded-mask box."""
    _, run, _ = fit_scene(tmp_path, steps="30", eval_every="30", atlas_box_full_mask="false")
    path = run / C.RUN_CHECKPOINT
    state = load_checkpoint(path, torch.device("cpu"))
    del state["motions"]
    save_checkpoint(path, state)
    cfg_path = run / C.RUN_CONFIG
    data = json.loads(cfg_path.read_text())
    del data["config"]["atlas_box_full_mask"]
    cfg_path.write_text(json.dumps(data))
    assert FitConfig.from_json(cfg_path.read_text()).atlas_box_full_mask is False
    model, _, _ = load_run(run)  # shapes match, or load_state_dict raises
    assert model.num_layers == 2
