"""``scribble_carry``: the scribble term's samples also on the frames nobody scribbled, the strokes carried there along
the consistent flow (the labels that seed each part's motion). Off, the samples are the drawn strokes alone."""

from __future__ import annotations

import numpy as np
import torch

from engine.config import apply_overrides, preset_config
from engine.data.scribbles import propagate_labels
from engine.fit.fit_inputs import FitInputs
from engine.fit.prepare import prepare_clip
from tests.engine.fit.test_scribble_fit import write_strokes
from tests.two_object_scene import make_two_object_scene, write_two_object_scene


def test_carried_strokes_reach_every_frame_inside_the_object_and_keep_the_drawn_ones(tmp_path):
    scene = make_two_object_scene()
    frames_dir, mask_dirs = write_two_object_scene(scene, tmp_path / "clip", union=True)
    write_strokes(scene, tmp_path / "clip" / "scribbles")
    cfg = preset_config("draft")
    prepared = prepare_clip(
        FitInputs(frames_dir, mask_dirs, scribbles=tmp_path / "clip" / "scribbles"), cfg, tmp_path / "run"
    )
    cpu = torch.device("cpu")
    drawn = prepared.tensors(cfg, cpu)
    carried = prepared.tensors(apply_overrides(cfg, {"scribble_carry": "true"}), cpu)
    t_count = prepared.frames.shape[0]
    assert sorted(set(drawn.scribble_xyt[:, 2].tolist())) == [0, t_count - 1]
    assert set(carried.scribble_xyt[:, 2].tolist()) == set(range(t_count))  # every frame has strokes

    # the drawn strokes are among the carried samples, with their labels
    def samples(video) -> set[tuple[int, int, int, int]]:
        xyt, label = video.scribble_xyt.tolist(), video.scribble_label.tolist()
        return {(x, y, t, lab) for (x, y, t), lab in zip(xyt, label, strict=True)}

    ours = samples(carried)
    assert samples(drawn) <= ours
    # exactly propagate_labels' labels, each inside the object's mask
    labels = propagate_labels(prepared.scribbles, prepared.flow, prepared.masks[0])
    assert len(ours) == int((labels >= 0).sum())
    x, y, t = carried.scribble_xyt.numpy().T
    assert prepared.masks[0][t, y, x].all()
    assert np.array_equal(np.sort(carried.scribble_label.numpy()), np.sort(labels[labels >= 0].astype(np.int64)))
