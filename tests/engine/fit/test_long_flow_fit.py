"""A fit with long-range correspondences: prepared with the flow (one progress count over both), cached in the run
folder and reused, switched on in the scene analysis, and its term falls as the mappings learn the motion."""

from __future__ import annotations

import dataclasses
import io
import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from engine import contract as C
from engine.config import LATER_FIELDS, FitConfig, apply_overrides, config_help, preset_config
from engine.data.long_flow import long_flow_pairs
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.data.video import build_video_tensors
from engine.errors import InputError
from engine.fit.fit_inputs import FitInputs
from engine.fit.prepare import prepare_clip
from engine.fit.progress import Reporter
from engine.fit.run_folder import RunFolder
from engine.fit.trainer import Trainer
from engine.terms.versions import SCHEMA_VERSION
from tests.engine.fit_helpers import quiet_fit

SPEC = SceneSpec(width=64, height=48, frames=6, bg_velocity=(2.0, 0.5), fg_start=(16.0, 12.0), fg_size=(20, 14))
CPU = torch.device("cpu")
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


@pytest.mark.slow
def test_fit_with_long_range_correspondences(tmp_path: Path) -> None:
    frames_dir, masks_dir = write_scene(make_scene(SPEC), tmp_path / "clip")
    cfg = apply_overrides(preset_config("draft"), SETS)
    run = tmp_path / "run"
    out = io.StringIO()
    quiet_fit(run, cfg, FitInputs(frames_dir, [masks_dir]), out)
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
    prepared = prepare_clip(FitInputs(frames_dir, [masks_dir]), cfg, run, Reporter(None, again))
    assert long_file.stat().st_mtime_ns == stamp
    assert prepared.long_flow is not None and prepared.long_flow.count > 1000
    flow = [(e["done"], e["total"]) for e in _events(again.getvalue()) if e["event"] == C.EVENT_JOB]
    assert flow == [(5, pairs), (pairs, pairs)]  # one message per cache hit


def test_off_prepares_nothing_extra(tmp_path: Path) -> None:
    frames_dir, masks_dir = write_scene(make_scene(SPEC), tmp_path / "clip")
    cfg = apply_overrides(preset_config("draft"), {"long_flow_max_gap": "1"})
    prepared = prepare_clip(FitInputs(frames_dir, [masks_dir]), cfg, tmp_path / "run")
    assert prepared.long_flow is None
    assert not list(RunFolder(tmp_path / "run").flow_cache.glob("long-*.npz"))
    assert "long_flow" not in prepared.analyse(cfg).active_terms
    assert prepared.analyse(cfg).reasons["long_flow"] == "off: long_flow_max_gap < 2 in this config"


def test_runs_from_before_the_long_range_fields_still_load(tmp_path: Path) -> None:
    """A config.json and a checkpoint written before the fields existed: the defaults reproduce that fit (off),
    so the checkpoint belongs to the run; one fitted with long-range correspondences does not belong to a config
    without them."""
    cfg = preset_config("draft")
    old = {k: v for k, v in dataclasses.asdict(cfg).items() if k not in LATER_FIELDS}
    text = json.dumps({"schema": SCHEMA_VERSION, "config": old})
    loaded = FitConfig.from_json(text, tmp_path / "config.json")
    assert loaded == dataclasses.replace(cfg, **LATER_FIELDS) and loaded.long_flow_max_gap == 0
    assert all(getattr(loaded, k) == v for k, v in LATER_FIELDS.items())
    assert loaded.mask_snap_px == 0 < cfg.mask_snap_px  # fitted before the snap: its masks as drawn
    record = SimpleNamespace(fingerprint="abc")
    folder = RunFolder(tmp_path)
    folder.check_checkpoint_belongs({"fingerprint": "abc", "config": old}, loaded, record)  # type: ignore[arg-type]
    on = dict(old, long_flow_max_gap=4)
    with pytest.raises(InputError, match="long_flow_max_gap 4, not 0"):
        folder.check_checkpoint_belongs({"fingerprint": "abc", "config": on}, loaded, record)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="long_flow_max_gap"):
        apply_overrides(cfg, {"long_flow_max_gap": "-1"})
    assert "long_flow_max_gap (int, default 0, an int >= 0)" in config_help()


def test_shared_tensors_must_hold_the_configs_correspondences(tmp_path: Path) -> None:
    """The bench and ``estimate`` share one clip's tensors between configs: a config asking for other long-range
    correspondences than the clip was prepared with is refused, not fitted without them."""
    frames_dir, masks_dir = write_scene(make_scene(SPEC), tmp_path / "clip")
    cfg = apply_overrides(preset_config("draft"), {"long_flow_max_gap": "4"})
    prepared = prepare_clip(FitInputs(frames_dir, [masks_dir]), cfg, tmp_path / "run")
    video = build_video_tensors(prepared.frames, prepared.masks, prepared.flow, 2.0, CPU, long_flow=prepared.long_flow)
    Trainer(cfg, prepared, prepared.analyse(cfg), CPU, video=video)  # the same settings: fine
    off = preset_config("draft")
    Trainer(off, prepared, prepared.analyse(off), CPU, video=video)  # off: the tensors are not used
    other = apply_overrides(cfg, {"long_flow_max_gap": "2"})
    with pytest.raises(InputError, match="long-range correspondences"):
        Trainer(other, prepared, prepared.analyse(other), CPU, video=video)
