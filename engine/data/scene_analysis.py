"""Scene analysis: before fitting, decide which components the clip calls for, and record why.

A tripod shot does not need a deformable background mapping, a clip without an object needs no foreground
or alpha networks, a single frame has no flow. Each decision carries a one-line reason and the measured
numbers behind it, so an artist (and a bug report) can see why a run computed what it did. The decisions
are written to ``RUN_DIR/scene.json`` (``terms.run_folder.SCENE_FILE``, by ``engine.fit.run_folder.RunFolder``), shown
as a ``stage`` progress event, and copied into every export's manifest.

Background motion is measured on the flow the fit computes anyway (no extra cost): per adjacent frame pair,
over the reliable flow vectors (those that survive the forward-backward round trip) of the background
(outside every mask, by a margin), the median flow magnitude decides *static*, and the residual of a
robust similarity fit decides *pan/zoom*. Anything else, or too little reliable flow to tell, is
*deformable*: the full model is the safe default.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from ..config import FitConfig
from ..errors import InputError
from ..loss_terms import ALL_TERMS, TERMS, SceneFacts
from ..terms.run_folder import (
    BG_MOTION_DEFORMABLE,
    BG_MOTION_PAN_ZOOM,
    BG_MOTION_STATIC,
    SCENE_LAYERS_AUTO,
    SCENE_LAYERS_GIVEN,
    SCENE_LAYERS_NONE,
)
from ..terms.versions import SCHEMA_VERSION
from .flow import FlowField
from .long_flow import long_flow_gaps

#: A background whose median flow magnitude (working px per frame) stays under this in (almost) every frame
#: pair is *static*: a tripod. DIS noise on a real tripod shot is far below it, and the slowest real camera
#: pan far above it (docs/engine.md lists the clips measured).
STATIC_MOTION_PX = 0.25
#: A background whose flow a per-pair similarity (rotation, uniform scale, translation) explains to within
#: this (working px, at RESIDUAL_PERCENTILE of the vectors) is a *pan/zoom*: a low-capacity mapping suffices.
#: Parallax, water and foliage leave larger residuals, a tripod shot a far smaller one (docs/engine.md lists
#: the clips measured).
PANZOOM_RESIDUAL_PX = 0.35
#: Percentile of the per-vector similarity residual that represents a pair: high enough that a distinct
#: depth plane covering a fifth of the background counts, low enough that flow outliers at edges do not.
RESIDUAL_PERCENTILE = 80.0
#: Percentile over frame pairs that represents the clip: one jolt in an otherwise static shot is tolerated
#: (the per-frame delta of the static mapping absorbs it), a camera that moves in a tenth of the pairs is not.
PAIR_PERCENTILE = 90.0
#: About this many flow vectors (on a regular grid) per pair: enough for a stable median and RANSAC.
TARGET_VECTORS = 4000
#: A pair with fewer reliable background vectors than this is not measured (textureless, or all masked).
MIN_VECTORS = 50
#: RANSAC inlier threshold (px) of the similarity fit.
RANSAC_PX = 1.0
#: Margin (px) around the masks that is not background for the measurement (coarse masks bleed).
MASK_MARGIN_PX = 6


@dataclass
class MotionMeasure:
    """Background motion measured from the flow (working pixels)."""

    static_px: float | None
    """PAIR_PERCENTILE over pairs of the median background flow magnitude (None: nothing measurable)."""
    similarity_residual_px: float | None
    """PAIR_PERCENTILE over pairs of the RESIDUAL_PERCENTILE similarity residual (None: nothing measurable)."""
    pairs_measured: int
    pairs: int
    vectors: int
    """Reliable background flow vectors used, over all pairs."""


@dataclass
class SceneAnalysis:
    """What a fit computes, decided from the clip; ``reasons`` holds one line per decision."""

    components: str = "auto"
    num_layers: int = 1
    layers_source: str = SCENE_LAYERS_NONE
    background_motion: str = BG_MOTION_DEFORMABLE
    flow: bool = True
    scribbles: int = 0
    alpha_network: bool = False
    active_terms: list[str] = field(default_factory=lambda: list(ALL_TERMS))
    reasons: dict[str, str] = field(default_factory=dict)
    measured: dict[str, float | int | None] = field(default_factory=dict)
    overrides: list[str] = field(default_factory=list)

    @property
    def term_set(self) -> frozenset[str] | None:
        """The terms the objective evaluates; None = every term (components=all: including terms that
        evaluate to zero)."""
        return None if self.components == "all" else frozenset(self.active_terms)

    def to_dict(self) -> dict[str, Any]:
        return {"schema": SCHEMA_VERSION, **dataclasses.asdict(self)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> SceneAnalysis:
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in names})

    def summary(self) -> str:
        """One line for the progress stream and the log."""
        off = [t for t in ALL_TERMS if t not in self.active_terms]
        return (
            f"{self.num_layers} layer(s) ({self.layers_source}), background {self.background_motion}, "
            f"flow {'on' if self.flow else 'off'}, terms off: {', '.join(off) or 'none'}"
        )


def _background_region(masks: np.ndarray, t: int) -> np.ndarray | None:
    """Pixels of frame ``t`` farther than MASK_MARGIN_PX from every mask; None when there are no masks."""
    if masks.shape[0] == 0:
        return None
    fg = masks[:, t].any(0).astype(np.uint8)
    if not fg.any():
        return None
    k = 2 * MASK_MARGIN_PX + 1
    return cv2.dilate(fg, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))) == 0


def measure_background_motion(flow: FlowField, masks: np.ndarray) -> MotionMeasure:
    """Median flow magnitude and similarity residual of the background, per pair, summarised over pairs."""
    pairs = flow.pairs
    statics, residuals, vectors = [], [], 0
    for t in range(pairs):
        ok = flow.forward_ok[t]
        h, w = ok.shape
        region = _background_region(masks, t)
        area = float(region.sum()) if region is not None else float(h * w)
        stride = max(1, int(np.sqrt(max(area, 1.0) / TARGET_VECTORS)))
        ys, xs = np.mgrid[stride // 2 : h : stride, stride // 2 : w : stride]
        sel = ok[ys, xs]
        if region is not None:
            sel &= region[ys, xs]
        n = int(sel.sum())
        if n < MIN_VECTORS:
            continue
        vec = flow.forward[t][ys[sel], xs[sel]].astype(np.float64)
        statics.append(float(np.median(np.linalg.norm(vec, axis=1))))
        src = np.stack((xs[sel], ys[sel]), -1).astype(np.float64)
        dst = src + vec
        m, _ = cv2.estimateAffinePartial2D(
            src.astype(np.float32), dst.astype(np.float32), method=cv2.RANSAC, ransacReprojThreshold=RANSAC_PX
        )
        if m is None:  # RANSAC found no consensus: the motion is not a similarity
            residuals.append(float("inf"))
        else:
            pred = src @ m[:, :2].T + m[:, 2]
            residuals.append(float(np.percentile(np.linalg.norm(dst - pred, axis=1), RESIDUAL_PERCENTILE)))
        vectors += n
    if not statics:
        return MotionMeasure(None, None, 0, pairs, 0)
    return MotionMeasure(
        float(np.percentile(statics, PAIR_PERCENTILE)),
        float(np.percentile(residuals, PAIR_PERCENTILE)),
        len(statics),
        pairs,
        vectors,
    )


def classify_background(measure: MotionMeasure | None, frames: int) -> tuple[str, str]:
    """(background motion class, reason) from the measurement."""
    if frames < 2:
        return BG_MOTION_STATIC, "a single frame: the background cannot move"
    if measure is None or measure.static_px is None:
        return BG_MOTION_DEFORMABLE, (
            f"too little reliable background flow to measure (< {MIN_VECTORS} vectors in every pair): "
            "the full deformable mapping is the safe choice"
        )
    if measure.static_px < STATIC_MOTION_PX:
        return BG_MOTION_STATIC, (
            f"static camera: median background motion {measure.static_px:.3f} px/frame "
            f"< {STATIC_MOTION_PX} px ({measure.pairs_measured}/{measure.pairs} pairs measured): "
            "near-identity mapping, no residual network, no warp grid"
        )
    res = measure.similarity_residual_px
    if res is not None and res < PANZOOM_RESIDUAL_PX:
        return BG_MOTION_PAN_ZOOM, (
            f"pan/zoom: a similarity per frame explains the background flow to {res:.3f} px "
            f"< {PANZOOM_RESIDUAL_PX} px (motion {measure.static_px:.2f} px/frame): "
            "similarity + small residual network, no warp grid"
        )
    return BG_MOTION_DEFORMABLE, (
        f"deformable: a similarity leaves {res:.3f} px of background flow unexplained "
        f"(>= {PANZOOM_RESIDUAL_PX} px: parallax or non-rigid motion): full mapping with warp grid"
    )


def analyse_scene(
    frames: int,
    flow: FlowField | None,
    masks: np.ndarray,
    cfg: FitConfig,
    layers_source: str | None = None,
    scribbles: int = 0,
    masks_note: str | None = None,
    foreground_layers: int | None = None,
) -> SceneAnalysis:
    """Decide what the fit computes for a clip of ``frames`` frames with ``flow`` and bool ``masks``
    [F, T, H, W] (F foreground layers); ``layers_source`` says where the masks came from (contract
    SCENE_LAYERS_*; default: given when there are masks), ``masks_note`` adds the auto-masks' message;
    ``foreground_layers`` when it differs from F (scribbles split one mask into several layers)."""
    if cfg.components not in ("auto", "all"):
        raise InputError(None, f"--set components={cfg.components}: unknown", "use components=auto or components=all")
    fg = int(masks.shape[0]) if foreground_layers is None else int(foreground_layers)
    source = layers_source or (SCENE_LAYERS_GIVEN if fg else SCENE_LAYERS_NONE)
    reasons: dict[str, str] = {"layers": _layers_reason(fg, source, masks_note)}

    has_flow = frames >= 2 and flow is not None and flow.pairs > 0
    long_gaps = long_flow_gaps(cfg.long_flow_max_gap, frames)
    reasons["flow"] = "flow between adjacent frames" if has_flow else "a single frame: no flow is computed"
    measure = measure_background_motion(flow, masks) if has_flow and flow is not None else None
    motion, reasons["background_motion"] = classify_background(measure, frames)
    if cfg.model == "paper":
        reasons["background_motion"] += " (paper model: its mappings are MLPs either way; only loss terms change)"
    reasons["scribbles"] = f"{scribbles} scribble file(s)" if scribbles else "no scribbles given"

    active = _active_terms(SceneFacts(cfg, fg, has_flow, bool(long_gaps), scribbles, motion), reasons)
    scene = SceneAnalysis(
        components="auto",
        num_layers=1 + fg,
        layers_source=source,
        background_motion=motion,
        flow=has_flow,
        scribbles=scribbles,
        alpha_network=fg > 0,
        active_terms=active,
        reasons=reasons,
        measured=_measured(frames, fg, measure),
    )
    return force_all(scene) if cfg.components == "all" else scene


def _layers_reason(fg: int, source: str, masks_note: str | None) -> str:
    """Why the fit has the layers it has: the masks given or found, or none (a background-only atlas)."""
    note = f" ({masks_note})" if masks_note else ""
    if fg:
        how = "found from motion (--auto-masks)" if source == SCENE_LAYERS_AUTO else "given (--mask)"
        return f"background + {fg} foreground layer(s): masks {how}{note}"
    why = "no moving object was found" if source == SCENE_LAYERS_AUTO else "no masks were given"
    return f"background only: {why}{note}; no foreground or alpha networks, alpha = 1"


def _active_terms(facts: SceneFacts, reasons: dict[str, str]) -> list[str]:
    """The loss terms the fit computes, in ``ALL_TERMS`` order; each term left off gets its reason in ``reasons``
    (in that order too: the reasons are written to the run folder as they come)."""
    off = {term.name: why for term in TERMS if (why := term.why_off(facts)) is not None}
    reasons.update(off)
    return [name for name in ALL_TERMS if name not in off]


def _measured(frames: int, fg: int, measure: MotionMeasure | None) -> dict[str, float | int | None]:
    """The numbers the analysis decided by, as the run folder records them."""
    measured: dict[str, float | int | None] = {"frames": frames, "foreground_layers": fg}
    if measure is not None:
        measured.update(
            {
                "background_median_motion_px": measure.static_px,
                "similarity_residual_px": measure.similarity_residual_px,
                "pairs_measured": measure.pairs_measured,
                "pairs": measure.pairs,
                "background_vectors": measure.vectors,
            }
        )
    return measured


def force_all(scene: SceneAnalysis) -> SceneAnalysis:
    """components=all: every component on, recording what the analysis would have left off."""
    overrides = []
    if scene.background_motion != BG_MOTION_DEFORMABLE:
        overrides.append(f"background_motion: deformable instead of {scene.background_motion}")
    if not scene.alpha_network:
        overrides.append("alpha_network: on (one layer: its output is 1 everywhere)")
    off = [t for t in ALL_TERMS if t not in scene.active_terms]
    if off:
        overrides.append(f"terms evaluated although the analysis found nothing for them: {', '.join(off)}")
    reasons = {**scene.reasons, "components": "components=all: every component forced on"}
    return dataclasses.replace(
        scene,
        components="all",
        background_motion=BG_MOTION_DEFORMABLE,
        alpha_network=True,
        active_terms=list(ALL_TERMS),
        reasons=reasons,
        overrides=overrides,
    )


__all__ = [
    "PANZOOM_RESIDUAL_PX",
    "STATIC_MOTION_PX",
    "MotionMeasure",
    "SceneAnalysis",
    "analyse_scene",
    "classify_background",
    "force_all",
    "measure_background_motion",
]
