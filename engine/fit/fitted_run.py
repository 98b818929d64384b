"""A fitted run loaded back from its run folder: the model with its weights (what export works from), and for
looking at a fit against its plate, the clip prepared again."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..config import FitConfig
from ..data.scene_analysis import SceneAnalysis
from ..model.atlas_model import AtlasModel
from .device import select_device
from .fit_inputs import FitInputs
from .model_build import checkpoint_fits, rebuild_model
from .prepare import PreparedClip, prepare_clip
from .run_folder import ClipRecord, RunFolder


@dataclass
class FittedRun:
    """A fit as its run folder holds it, loaded without its clip: what ``export`` works from."""

    folder: RunFolder
    cfg: FitConfig
    clip: ClipRecord
    scene: SceneAnalysis
    model: AtlasModel
    metrics: dict[str, Any] | None  # None: the fit has not finished


def load_fitted(run_dir: str | Path, device_name: str = "cpu") -> FittedRun:
    """The model of a finished (or checkpointed) fit with its weights, from the run folder alone: the plate,
    masks, scribbles and flow are not read."""
    run = RunFolder(run_dir)
    cfg = run.read_config()
    record = run.read_clip()
    scene = run.read_scene(record)
    device = select_device(device_name)
    state = run.load_checkpoint(device)
    run.check_checkpoint_belongs(state, cfg, record)
    with checkpoint_fits(run.checkpoint):
        model = rebuild_model(cfg, record, scene, state["motions"]).to(device)
        model.load_state_dict(state["model"])
    return FittedRun(run, cfg, record, scene, model.eval(), run.read_metrics())


def load_run(run_dir: str | Path, device_name: str = "cpu") -> tuple[AtlasModel, PreparedClip, FitConfig]:
    """A finished (or checkpointed) fit's model with its weights, its clip prepared again (frames, masks, flow
    from the cache) and its config: for looking at a fit against its plate (the demo's contact sheet)."""
    fitted = load_fitted(run_dir, device_name)
    record = fitted.clip
    missing = record.missing_input(fitted.folder.path)
    if missing is not None:
        raise missing
    # the plate as it was fitted: its recorded colour space, rate and movie numbering, not today's defaults
    prepared = prepare_clip(FitInputs.of_record(record), fitted.cfg, fitted.folder.path)
    return fitted.model, prepared, fitted.cfg
