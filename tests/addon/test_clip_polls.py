"""Fit Atlas, Find Masks and Estimate Time are greyed out without a clip (bpy 4.5 and 5.0): their poll fails with the
line saying to choose the clip in the Fit Atlas panel (a script calling them gets the same line), and passes once the
panel has a clip; Fit Atlas also passes with a fit to resume (Resume needs no clip: it continues from its
checkpoint). While a job of the scene runs, each is greyed as before."""

from __future__ import annotations

import re

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from neural_atlas.addon.core import needs, running  # noqa: E402

LINES = {"fit": needs.NO_FIT_CLIP, "find_masks": needs.NO_MASKS_CLIP, "estimate": needs.NO_ESTIMATE_CLIP}


def _refused(name: str, line: str) -> None:
    op = getattr(bpy.ops.neural_atlas, name)
    assert not op.poll(), name
    with pytest.raises(RuntimeError, match=re.escape(line[:200])):
        op("EXEC_DEFAULT")


def test_clip_operators_are_greyed_without_a_clip(blender, tmp_path):
    props = blender.context.scene.neural_atlas
    for name, line in LINES.items():
        _refused(name, line)
        assert "Fit Atlas panel" in line and len(line) < 200
    X.write_png(tmp_path / "plate.0001.png", np.zeros((4, 4, 4), np.uint8))
    props.clip = bpy.data.movieclips.load(str(tmp_path / "plate.0001.png"))
    assert all(getattr(bpy.ops.neural_atlas, name).poll() for name in LINES)
    props.clip = None
    props.can_resume = True  # a fit to continue: Resume needs no clip
    assert bpy.ops.neural_atlas.fit.poll()
    assert not bpy.ops.neural_atlas.find_masks.poll() and not bpy.ops.neural_atlas.estimate.poll()


def test_clip_operators_stay_greyed_while_a_job_runs(blender, tmp_path):
    props = blender.context.scene.neural_atlas
    X.write_png(tmp_path / "plate.0001.png", np.zeros((4, 4, 4), np.uint8))
    props.clip = bpy.data.movieclips.load(str(tmp_path / "plate.0001.png"))
    running.add(blender.context.scene.name, object())
    try:
        assert not any(getattr(bpy.ops.neural_atlas, name).poll() for name in LINES)
    finally:
        running.remove(blender.context.scene.name)
    assert all(getattr(bpy.ops.neural_atlas, name).poll() for name in LINES)
