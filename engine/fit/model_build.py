"""A fit's model: built for a new fit from its prepared clip (the layers starting at the motion the flow shows),
or rebuilt from a run folder alone (the starting motions its checkpoint saved), so a checkpoint loads into the
shapes it was saved from. What the loop, ``estimate`` and export build their models with."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..config import FitConfig
from ..data.scene_analysis import SceneAnalysis
from ..data.scribbles import propagate_labels
from ..errors import InputError
from ..model.atlas_model import AtlasModel, FastModel, motion_regions
from ..model.motion_init import LayerMotion, estimate_layer_motion
from ..model.paper_model import PaperModel
from ..terms.run_folder import BG_MOTION_DEFORMABLE, BG_MOTION_STATIC, RUN_FILE_OTHER_VERSION_FIX
from .prepare import PreparedClip
from .run_folder import FOREIGN_CHECKPOINT_FIX, ClipRecord

#: Characters of a torch error kept in the one-line message of a checkpoint that does not fit the model.
ERROR_DETAIL_CHARS = 160


def build_model(cfg: FitConfig, clip: PreparedClip, scene: SceneAnalysis | None = None) -> AtlasModel:
    """A new model for ``clip``: the components ``scene`` calls for (engine.data.scene_analysis; None = every
    component), the fast model's layers starting at the motion the flow shows inside their masks."""
    t = clip.frames.shape[0]
    if cfg.model == "paper":
        return assemble_model(cfg, clip.size, t, 1 + clip.num_foreground, scene, None)
    if cfg.model != "fast":
        raise InputError(None, f"unknown model {cfg.model!r}", "use --set model=fast or model=paper")
    flow = clip.flow if t > 1 else None
    background = BG_MOTION_DEFORMABLE if scene is None else scene.background_motion
    motions = []
    if clip.masks.shape[0]:
        bg_region, fg_regions = motion_regions(clip.masks)
    else:
        bg_region, fg_regions = None, []
    # a static camera's background is the identity: the flow's noise must not tilt it
    fit_bg = cfg.init_motion and background != BG_MOTION_STATIC
    motions.append(estimate_layer_motion(flow, bg_region, clip.size, fit_bg))
    if clip.scribbles is not None:
        # each part moves like its scribbles (carried to every frame by the flow); its atlas spans the object
        carried = propagate_labels(clip.scribbles, flow, clip.masks[0])
        layers = [(carried == k, fg_regions[0]) for k in range(clip.num_foreground)]
    else:
        # motion from the eroded mask (flow at object boundaries is unreliable), atlas box from the whole mask
        # (an eroded box cut the rim off small objects)
        layers = [
            (region, full if cfg.atlas_box_full_mask else None)
            for region, full in zip(fg_regions, clip.masks, strict=True)
        ]
    for region, extent in layers:  # (where the layer's motion is fitted, where its atlas box is drawn from)
        motions.append(
            estimate_layer_motion(
                flow,
                region,
                clip.size,
                cfg.init_motion,
                margin=cfg.atlas_margin_fg,
                extent_masks=extent,
                background=motions[0],
            )
        )
    return assemble_model(cfg, clip.size, t, len(motions), scene, motions)


def assemble_model(
    cfg: FitConfig,
    size: tuple[int, int],
    frames: int,
    layers: int,
    scene: SceneAnalysis | None,
    motions: list[LayerMotion] | None,
) -> AtlasModel:
    """The model of ``layers`` layers over ``frames`` frames of ``size`` (W, H) with ``scene``'s components; the
    fast model's layers start at ``motions``. What ``build_model`` makes for a new fit and ``rebuild_model``
    for a saved one."""
    if cfg.model == "paper":
        model: AtlasModel = PaperModel(cfg, size, frames, num_layers=layers)
    elif cfg.model == "fast":
        if motions is None or len(motions) != layers:
            raise InputError(
                None,
                f"the fast model needs a starting motion for each of its {layers} layers",
                RUN_FILE_OTHER_VERSION_FIX,
            )
        background = BG_MOTION_DEFORMABLE if scene is None else scene.background_motion
        alpha_network = True if scene is None else (scene.alpha_network or len(motions) > 1)
        model = FastModel(cfg, size, frames, motions, background=background, alpha_network=alpha_network)
    else:
        raise InputError(None, f"unknown model {cfg.model!r}", "use --set model=fast or model=paper")
    model.active_terms = None if scene is None else scene.term_set
    return model


def rebuild_model(
    cfg: FitConfig, clip: ClipRecord, scene: SceneAnalysis, saved_motions: list[dict[str, Any]] | None
) -> AtlasModel:
    """The model a checkpoint was saved from, built from the run folder alone (no frames, masks or flow): the
    fast model's layers start at the motions the fit saved, so a run reloads into the same shapes and scales
    whatever the engine version or the flow backend would compute today."""
    motions = None if saved_motions is None else [motion_from_state(m) for m in saved_motions]
    return assemble_model(cfg, clip.working_size, clip.num_frames, clip.layers, scene, motions)


def _one_line(exc: BaseException) -> str:
    """A torch error (often several lines) as a short clause for a one-line message."""
    text = " ".join(part.strip() for part in str(exc).splitlines() if part.strip()) or type(exc).__name__
    return text if len(text) <= ERROR_DETAIL_CHARS else text[: ERROR_DETAIL_CHARS - 3] + "..."


@contextlib.contextmanager
def checkpoint_fits(path: Path | None) -> Iterator[None]:
    """A checkpoint loaded into a model it was not saved from (another run's, a damaged one: missing weights,
    wrong shapes, a broken optimiser or sampler state) is one line naming ``path``, not torch's traceback."""
    try:
        yield
    except InputError as exc:
        if exc.path is not None:
            raise
        raise InputError(path, exc.problem, exc.fix) from None
    except (RuntimeError, ValueError, TypeError, KeyError, IndexError, AttributeError) as exc:
        problem = f"checkpoint does not fit this run's model ({_one_line(exc)})"
        raise InputError(path, problem, FOREIGN_CHECKPOINT_FIX) from None


def model_motions(model: AtlasModel) -> list[dict[str, Any]] | None:
    """The fast model's per-layer starting motion and atlas box, for the checkpoint (None: other models)."""
    motions = getattr(model, "layer_motions", None)
    if motions is None:
        return None
    return [
        {
            "to_ref": torch.from_numpy(np.asarray(m.to_ref, np.float64)),
            "center": torch.from_numpy(np.asarray(m.center, np.float64)),
            "half_extent": float(m.half_extent),
            "aspect": [float(a) for a in m.aspect],
        }
        for m in motions
    ]


def motion_from_state(rec: dict[str, Any]) -> LayerMotion:
    """A layer's starting motion as ``model_motions`` saved it (a malformed one raises: ``checkpoint_fits``)."""
    return LayerMotion(
        to_ref=rec["to_ref"].cpu().numpy().astype(np.float64),
        center=rec["center"].cpu().numpy().astype(np.float64),
        half_extent=float(rec["half_extent"]),
        aspect=(float(rec["aspect"][0]), float(rec["aspect"][1])),
    )
