"""Every loss term of the objective, declared once: its name, weight field and schedule, and what it needs of the
scene, with the reason the fit gives where the scene lacks it. The objective weighs its terms with ``loss_weights``;
the scene analysis keeps those whose ``why_off`` finds nothing. A new term is its function in engine.model.losses,
its place in the objective's groups, its weight field in ``FitConfig`` and one ``LossTerm`` in ``TERMS``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from .config import PHASE_FIELDS, FitConfig
from .terms.run_folder import BG_MOTION_STATIC


@dataclass(frozen=True)
class SceneFacts:
    """What the scene analysis found that a term may need: foreground layers, flow between frames, long-range
    correspondences (asked for, and a clip long enough for a gap of 2), scribble files, the background's motion
    class (``terms.run_folder.BG_MOTION_*``), with the fit's config."""

    cfg: FitConfig
    foreground: int
    flow: bool
    long_gaps: bool
    scribbles: int
    motion: str


@dataclass(frozen=True)
class Need:
    """Something a term needs of the scene (``holds``), and why the term is off where the scene lacks it."""

    holds: Callable[[SceneFacts], bool]
    reason: str


#: Terms on alpha or on a foreground atlas.
FOREGROUND = Need(lambda s: s.foreground > 0, "no foreground layer")
#: Terms on the flow between frames.
FLOW = Need(lambda s: s.flow, "no flow (single frame)")


@dataclass(frozen=True)
class LossTerm:
    """One loss term: ``name`` (the objective's and scene.json's), ``weight`` (its ``FitConfig`` field), its
    schedule (on while ``step < until``, or from ``step >= since``, both ``PHASE_FIELDS``; always when neither)
    and what it ``needs`` of the scene, in order: the first need the scene lacks gives the reason it is off."""

    name: str
    weight: str
    until: str | None = None
    since: str | None = None
    needs: tuple[Need, ...] = ()

    def weight_at(self, cfg: FitConfig, step: int) -> float:
        """The term's weight at ``step``: its field's value within its phase, else 0."""
        if (self.until and step >= getattr(cfg, self.until)) or (self.since and step < getattr(cfg, self.since)):
            return 0.0
        weight: float = getattr(cfg, self.weight)
        return weight

    def ever_on(self, cfg: FitConfig) -> bool:
        """Whether the term has a non-zero weight at some step of the fit: at the start or where a phase ends (the
        weights change only there)."""
        phases = {0} | {s for s in (getattr(cfg, name) for name in PHASE_FIELDS) if 0 < s < cfg.steps}
        return any(self.weight_at(cfg, step) != 0.0 for step in phases)

    def why_off(self, scene: SceneFacts) -> str | None:
        """Why the fit leaves the term off (the first need the scene lacks, else a weight 0 for the whole fit), or
        None when it is evaluated."""
        lacking = next((need.reason for need in self.needs if not need.holds(scene)), None)
        if lacking is None and not self.ever_on(scene.cfg):
            lacking = "its weight (or schedule) is 0 in this config"
        return None if lacking is None else f"off: {lacking}"


#: Every term, in the order scene.json lists them. The mask bootstrap (``mask``, refined by ``scribble``) ends at
#: ``bootstrap_steps``, where the mask prior takes over (and, for small and thin objects' mask layers, ``mask_hold``:
#: the mask term again); global rigidity ends at ``global_rigidity_steps``.
TERMS: tuple[LossTerm, ...] = (
    LossTerm("rgb", "w_rgb"),
    LossTerm("gradient", "w_gradient"),
    LossTerm("rigidity", "w_rigidity"),
    LossTerm("global_rigidity_bg", "w_global_rigidity_bg", until="global_rigidity_steps", needs=(
        Need(lambda s: s.motion != BG_MOTION_STATIC, "a near-identity mapping is globally rigid by construction"),
    )),
    LossTerm("global_rigidity_fg", "w_global_rigidity_fg", until="global_rigidity_steps", needs=(FOREGROUND,)),
    LossTerm("flow", "w_flow", needs=(FLOW,)),
    LossTerm("long_flow", "w_long_flow", needs=(
        FLOW,
        Need(lambda s: s.cfg.long_flow_max_gap >= 2, "long_flow_max_gap < 2 in this config"),
        Need(lambda s: s.long_gaps, "the clip has too few frames for a gap of 2"),
    )),
    LossTerm("alpha_flow", "w_alpha_flow", needs=(FOREGROUND, FLOW)),
    # several foreground layers (paper Sec. 4.3): the alpha-weighted sparsity would blacken what one object hides
    LossTerm("sparsity", "w_sparsity", needs=(
        FOREGROUND,
        Need(lambda s: s.foreground < 2, "several foreground layers use the atlas l1 instead (paper Sec. 4.3)"),
    )),
    LossTerm("mask", "w_mask", until="bootstrap_steps", needs=(FOREGROUND,)),
    LossTerm("mask_prior", "w_mask_prior", since="bootstrap_steps", needs=(FOREGROUND,)),
    LossTerm("mask_hold", "w_mask", since="bootstrap_steps", needs=(FOREGROUND,)),
    LossTerm("atlas_sparsity", "w_atlas_sparsity", needs=(
        FOREGROUND,
        Need(lambda s: s.foreground >= 2, "one foreground layer uses the alpha-weighted sparsity"),
    )),
    LossTerm("scribble", "w_scribble", until="bootstrap_steps", needs=(
        FOREGROUND,
        Need(lambda s: s.scribbles > 0, "no scribbles given"),
    )),
    LossTerm("anchor", "w_anchor", needs=(
        FOREGROUND,
        Need(lambda s: s.cfg.model != "paper", "the paper model's atlas is unbounded, there is no box to keep the "
             "object in"),
    )),
)  # fmt: skip
#: The terms' names, in ``TERMS`` order.
ALL_TERMS: tuple[str, ...] = tuple(term.name for term in TERMS)


def loss_weights(cfg: FitConfig, step: int) -> dict[str, float]:
    """Every term's weight at ``step`` (``LossTerm.weight_at``)."""
    return {term.name: term.weight_at(cfg, step) for term in TERMS}


__all__ = ["ALL_TERMS", "FLOW", "FOREGROUND", "TERMS", "LossTerm", "Need", "SceneFacts", "loss_weights"]
