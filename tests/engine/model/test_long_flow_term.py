"""The objective's long-range flow term: absent and free when off, one field call per layer when on, the value
the definition gives, and the same draws for the same (seed, step)."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest
import torch

from engine.config import preset_config
from engine.data.flow import DISFlow, compute_flow
from engine.data.long_flow import compute_long_flow
from engine.data.synthetic import SceneSpec, make_scene
from engine.data.video import VideoTensors, build_video_tensors
from engine.model import losses as L
from engine.model.atlas_model import FastModel
from engine.model.motion_init import LayerMotion
from engine.model.objective import _long_flow_points, compute_losses

CPU = torch.device("cpu")
SPEC = SceneSpec(width=64, height=48, frames=5, bg_velocity=(1.5, 0.5), fg_start=(20.0, 12.0), fg_size=(16, 12))
T = SPEC.frames


def _motion(shift: float, half: float) -> LayerMotion:
    to_ref = np.stack([np.array([[1.0, 0.0, shift * t], [0.0, 1.0, 0.0]]) for t in range(T)])
    return LayerMotion(to_ref=to_ref, center=np.array([32.0, 24.0]), half_extent=half, aspect=(1.0, 0.75))


@functools.cache
def _videos() -> tuple[VideoTensors, VideoTensors]:
    scene = make_scene(SPEC)
    adj = compute_flow(scene.frames, DISFlow("ultrafast"))
    lf = compute_long_flow(scene.frames, adj, (2, 4), DISFlow("ultrafast"))
    masks = scene.masks[None]
    off = build_video_tensors(scene.frames, masks, adj, 2.0, CPU)
    on = build_video_tensors(scene.frames, masks, adj, 2.0, CPU, long_flow=lf)
    return off, on


class Counted:
    """The model with every ``uv``/``alpha`` call's point count recorded."""

    def __init__(self, model: FastModel) -> None:
        self.model = model
        self.calls: list[tuple[str, int]] = []
        self._uv, self._alpha = model.uv, model.alpha
        model.uv = self.uv  # type: ignore[method-assign]
        model.alpha = self.alpha  # type: ignore[method-assign]

    def uv(self, layer: int, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        self.calls.append((f"uv{layer}", xy.shape[0]))
        return self._uv(layer, xy, t)

    def alpha(self, xy: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        self.calls.append(("alpha", xy.shape[0]))
        return self._alpha(xy, t)


def _model() -> FastModel:
    torch.manual_seed(0)
    return FastModel(preset_config("draft"), (SPEC.width, SPEC.height), T, [_motion(1.5, 40.0), _motion(-1.0, 20.0)])


def _batch() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(1)
    n = 400
    return (
        torch.randint(0, SPEC.width, (n,), generator=g),
        torch.randint(0, SPEC.height, (n,), generator=g),
        torch.randint(0, T, (n,), generator=g),
    )


def test_off_is_absent_and_costs_no_evaluation() -> None:
    off, on = _videos()
    cfg = preset_config("draft")
    assert cfg.long_flow_max_gap == 0
    results = []
    for video in (off, on):  # the clip's correspondences are there, the config does not ask for them
        model = _model()
        counted = Counted(model)
        total, terms = compute_losses(model, video, cfg, 3, *_batch())
        results.append((total, terms, counted.calls))
    (t0, terms0, calls0), (t1, terms1, calls1) = results
    assert "long_flow" not in terms0 and "long_flow" not in terms1
    assert t0.item() == t1.item()  # bit for bit
    assert all(terms0[k].item() == terms1[k].item() for k in terms0)
    assert calls0 == calls1


def test_on_adds_points_to_the_one_call_per_layer_and_gives_the_defined_value() -> None:
    off, on = _videos()
    cfg = dataclasses.replace(preset_config("draft"), long_flow_max_gap=4, long_flow_samples=300, w_long_flow=5.0)
    model = _model()
    counted = Counted(model)
    base, terms_off = compute_losses(model, off, cfg, 3, *_batch())
    calls_off = list(counted.calls)
    counted.calls.clear()
    total, terms = compute_losses(model, on, cfg, 3, *_batch())
    calls_on = counted.calls
    # the same calls, the uv ones 2 x 300 points longer (source and target), alpha 300 longer (the source)
    assert [c[0] for c in calls_on] == [c[0] for c in calls_off]
    extra = [b[1] - a[1] for a, b in zip(calls_off, calls_on, strict=True)]
    assert extra == [600 if name.startswith("uv") else 300 for name, _ in calls_on]
    # the other terms do not change; the total gains the weighted term
    for k, v in terms_off.items():
        assert terms[k].item() == pytest.approx(v.item(), rel=1e-5, abs=1e-7), k
    assert total.item() == pytest.approx(base.item() + 5.0 * terms["long_flow"].item(), rel=1e-5)
    assert terms["long_flow"].dtype == torch.float32
    # the definition: per layer, alpha at the source times the atlas distance in pixels, summed over layers
    p, tp, q, tq = _long_flow_points(on, cfg, 3, CPU)
    assert p.shape == q.shape == (300, 2)
    with torch.no_grad():
        alpha = model.alpha(p, tp)
        want = sum(
            L.flow_loss(model.uv(i, p, tp), model.uv(i, q, tq), alpha[:, i], None, model.uv_per_px(i))
            for i in range(model.num_layers)
        )
    assert terms["long_flow"].item() == pytest.approx(float(want), rel=1e-5)
    assert terms["long_flow"].item() > 0.01  # the starting motions are not the scene's: the term sees it


def test_draws_depend_on_seed_and_step_only() -> None:
    _, on = _videos()
    cfg = dataclasses.replace(preset_config("draft"), long_flow_max_gap=4, object_sample_share=0.25)
    a = _long_flow_points(on, cfg, 7, CPU)
    b = _long_flow_points(on, cfg, 7, CPU)
    c = _long_flow_points(on, cfg, 8, CPU)
    assert all(torch.equal(x, y) for x, y in zip(a, b, strict=True))
    assert not torch.equal(a[0], c[0])
    # targets are gap frames away from their sources, inside the frame
    gap = (a[3] - a[1]).abs()
    assert set(gap.tolist()) <= {2, 4}
    assert (a[2] >= 0.5).all() and (a[2][:, 0] <= SPEC.width - 0.5).all() and (a[2][:, 1] <= SPEC.height - 0.5).all()
