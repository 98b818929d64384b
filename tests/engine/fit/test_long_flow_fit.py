"""A fit with long-range correspondences: prepared with the flow (one progress count over both), cached in the run
folder and reused, switched on in the scene analysis, and its term falls as the mappings learn the motion."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from engine import contract as C
from engine.config import apply_overrides, preset_config
from engine.data.long_flow import long_flow_pairs
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.fit.prepare import prepare_clip
from engine.fit.progress import Reporter
from engine.fit.run_folder import RunFolder
from engine.fit.trainer import fit

SPEC = SceneSpec(width=64, height=48, frames=6, bg_velocity=(2.0, 0.5), fg_start=(16.0, 12.0), fg_size=(20, 14))
SETS = {
    "steps": "160",
    "batch": "1000",
    "eval_every": "20",
    "eval_pixels": "2000",
    "bootstrap_steps": "60",
    "global_rigidity_steps": "40",
    "long_flow_max_gap": "4",
    "long_flow_samples": "512",
}


def _events(text: str) -> list[dict]:
    return [m for m in map(C.parse_progress_line, text.splitlines()) if m]


def test_fit_with_long_range_correspondences(tmp_path: Path) -> None:
    frames_dir, masks_dir = write_scene(make_scene(SPEC), tmp_path / "clip")
    cfg = apply_overrides(preset_config("draft"), SETS)
    run = tmp_path / "run"
    out = io.StringIO()
    fit(frames_dir, [masks_dir], run, cfg, device_name="cpu", progress_bar=False, stream=out)
    events = _events(out.getvalue())

    # the flow stage counts the adjacent and the long-range pairs as one, and only forward
    pairs = SPEC.frames - 1 + long_flow_pairs((2, 4), SPEC.frames)
    assert pairs == 5 + 4 + 2
    flow = [(e["done"], e["total"]) for e in events if e["event"] == C.EVENT_JOB and e["stage"] == "flow"]
    assert flow == [(i, pairs) for i in range(1, pairs + 1)]
    fractions = [e["job_fraction"] for e in events if "job_fraction" in e]
    assert fractions == sorted(fractions)

    scene = RunFolder(run).read_scene()
    assert "long_flow" in scene.active_terms and "flow" in scene.active_terms

    losses = [e["losses"]["long_flow"] for e in events if e["event"] == C.EVENT_PROGRESS]
    assert len(losses) == 9  # step 1, then every 20
    first, last = losses[0], float(np.mean(losses[-3:]))
    assert last < 0.6 * first, losses

    # the correspondences are cached next to the adjacent flow, and a second preparation reads them
    cache = RunFolder(run).flow_cache
    (long_file,) = cache.glob("long-*.npz")
    stamp = long_file.stat().st_mtime_ns
    again = io.StringIO()
    prepared = prepare_clip(frames_dir, [masks_dir], cfg, run, None, Reporter(None, again))
    assert long_file.stat().st_mtime_ns == stamp
    assert prepared.long_flow is not None and prepared.long_flow.count > 1000
    flow = [(e["done"], e["total"]) for e in _events(again.getvalue()) if e["event"] == C.EVENT_JOB]
    assert flow == [(5, pairs), (pairs, pairs)]  # one message per cache hit


def test_off_prepares_nothing_extra(tmp_path: Path) -> None:
    frames_dir, masks_dir = write_scene(make_scene(SPEC), tmp_path / "clip")
    cfg = apply_overrides(preset_config("draft"), {"long_flow_max_gap": "1"})
    prepared = prepare_clip(frames_dir, [masks_dir], cfg, tmp_path / "run", None)
    assert prepared.long_flow is None
    assert not list(RunFolder(tmp_path / "run").flow_cache.glob("long-*.npz"))
    assert "long_flow" not in prepared.analyse(cfg).active_terms
    assert prepared.analyse(cfg).reasons["long_flow"] == "off: long_flow_max_gap < 2 in this config"
