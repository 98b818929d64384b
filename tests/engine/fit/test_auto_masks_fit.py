"""``fit --auto-masks`` in one pass over the clip: opened once, decoded once, its flow computed once when the motion
analysis runs at the fit's working size (and cached either way), the masks handed to the fit in memory; the
masks written for the artist are exactly what the ``masks`` verb writes, and exactly what the fit used."""

from __future__ import annotations

import numpy as np
import pytest

import engine.fit.prepare
import engine.io.clip
from engine import contract as C
from engine.config import apply_overrides, preset_config
from engine.data.auto_masks import mask_iou, write_auto_masks
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.fit.prepare import prepare_clip
from engine.io.clip import open_clip, read_masks
from engine.io.images import read_image

SMALL = SceneSpec(width=96, height=64, frames=6, fg_size=(28, 20), fg_start=(20.0, 20.0))


def _count(monkeypatch, module, name: str, calls: dict[str, int]) -> None:
    real = getattr(module, name)

    def counted(*args, **kwargs):  # type: ignore[no-untyped-def]
        calls[name] = calls.get(name, 0) + 1
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, counted)


@pytest.mark.parametrize(
    ("long_edge", "flows"),
    [("512", 1), ("48", 2)],  # working size 96x64 = the analysis size; 48x32: the analysis keeps 96x64
)
def test_one_pass_over_the_clip(tmp_path, monkeypatch, long_edge, flows):
    frames_dir, masks_dir = write_scene(make_scene(SMALL), tmp_path / "clip")
    cfg = apply_overrides(preset_config("draft"), {"long_edge": long_edge})
    calls: dict[str, int] = {}
    _count(monkeypatch, engine.fit.prepare, "open_clip", calls)
    _count(monkeypatch, engine.fit.prepare, "compute_flow", calls)
    _count(monkeypatch, engine.fit.prepare, "read_masks", calls)
    _count(monkeypatch, engine.io.clip, "iter_frames", calls)  # every decoding pass over the frames goes through it
    run = tmp_path / "run"
    prepared = prepare_clip(frames_dir, [], cfg, run, None, auto_masks=True)
    assert calls == {"open_clip": 1, "iter_frames": 1, "compute_flow": flows}  # no mask file is read back
    assert len(list((run / C.FLOW_CACHE_DIR).glob("*.npz"))) == flows

    folder = (run / C.AUTO_MASKS_DIR).resolve()
    assert prepared.mask_dirs == [str(folder)] and prepared.layers_source == C.SCENE_LAYERS_AUTO
    assert prepared.masks_note is not None and prepared.masks_note.startswith("foreground in 6/6 frames")
    monkeypatch.undo()
    info = open_clip(frames_dir)
    # the fit's masks are the written files read back at the working size; the files are the `masks` verb's
    assert np.array_equal(prepared.masks[0], read_masks(folder, info, prepared.size))
    verb = write_auto_masks(frames_dir, tmp_path / "verb")
    for name in verb.files:
        ours = folder / name.rsplit("/", 1)[-1]
        assert np.array_equal(read_image(ours)[0], read_image(name)[0]), ours.name
    iou = mask_iou(prepared.masks[0], read_masks(masks_dir, info, prepared.size))
    assert iou.min() > 0.8, iou
