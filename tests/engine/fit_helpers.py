"""Shared helpers for end-to-end fit tests on synthetic scenes with known motion."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np
import torch

from engine.config import FitConfig, apply_overrides, preset_config
from engine.data.synthetic import SceneSpec, SyntheticScene, make_scene, write_scene
from engine.fit.fit_inputs import FitInputs
from engine.fit.fitted_run import load_run
from engine.fit.run_plan import PLAN_START, FitPlan
from engine.fit.trainer import fit


def quiet_fit(run: Path, cfg: FitConfig, inputs: FitInputs, stream: Any = None) -> dict[str, Any]:
    """A new fit of ``inputs`` into ``run`` on the CPU: no bar, its progress lines into ``stream`` (default:
    nowhere); the metrics."""
    plan = FitPlan(PLAN_START, cfg, inputs)
    return fit(run, plan, device_name="cpu", progress_bar=False, stream=stream or io.StringIO())


TINY_OVERRIDES = {
    "steps": "400",
    "batch": "2000",
    "eval_every": "100",
    "bootstrap_steps": "150",
    "global_rigidity_steps": "100",
}


def fit_scene(tmp: Path, spec: SceneSpec | None = None, **overrides: str) -> tuple[SyntheticScene, Path, dict]:
    scene = make_scene(spec)
    frames_dir, masks_dir = write_scene(scene, tmp / "clip")
    cfg = apply_overrides(preset_config("draft"), {**TINY_OVERRIDES, **overrides})
    run = tmp / "run"
    metrics = quiet_fit(run, cfg, FitInputs(frames_dir, [masks_dir]))
    return scene, run, metrics


def load_model(run: Path):
    model, prepared, _ = load_run(run)
    return model, prepared


def atlas_consistency_px(model, layer: int, pts_frames: list[np.ndarray], ts: list[int]) -> np.ndarray:
    """Atlas distance (pixels) between the UVs one texture point gets in different frames, vs. frame ts[0]."""
    with torch.no_grad():
        uvs = []
        for p, t in zip(pts_frames, ts, strict=True):
            xy = torch.tensor(p, dtype=torch.float32) + 0.5  # scene pixel centres are integers
            uvs.append(model.uv(layer, xy, torch.full((len(p),), t, dtype=torch.long)).numpy())
    ref = uvs[0]
    return np.concatenate([np.linalg.norm(u - ref, axis=-1) for u in uvs[1:]]) / model.uv_per_px(layer)


def object_drift_per_frame(model, scene, k: int, samples: int = 200, seed: int = 0) -> list[float]:
    """Median atlas drift (pixels) of object ``k``'s texture points in its own layer ``k + 1``: frame 0 vs
    each later frame (scenes with per-object offsets: make_two_object_scene and its scribble variant)."""
    rng = np.random.default_rng(seed)
    ys, xs = np.nonzero(scene.masks[k, 0])
    sel = rng.choice(len(xs), samples)
    p0 = np.stack([xs[sel], ys[sel]], -1).astype(float)
    tex = p0 - scene.offsets[k, 0]
    return [
        float(np.median(atlas_consistency_px(model, k + 1, [p0, tex + scene.offsets[k, t]], [0, t])))
        for t in range(1, scene.spec.frames)
    ]
