"""The loss terms' one declaration each (engine.loss_terms) against what reads it: the objective computes exactly the
declared terms and asks only about declared ones, every weight and phase a term names is a config field, every
weight field weighs a term, and the schedule and the scene's rules say what the declarations say."""

from __future__ import annotations

import ast
import itertools
from dataclasses import fields

import pytest

from engine.config import PHASE_FIELDS, FitConfig, apply_overrides, field_kind, preset_config
from engine.loss_terms import ALL_TERMS, TERMS, SceneFacts, loss_weights
from engine.terms.run_folder import BG_MOTION_DEFORMABLE, BG_MOTION_PAN_ZOOM, BG_MOTION_STATIC
from tests.paths import ROOT

OBJECTIVE = ROOT / "engine" / "model" / "objective.py"


def _objective_names() -> tuple[set[str], set[str]]:
    """The term names objective.py stores into its ``terms`` dict, and every name it asks about (``on("...")``,
    ``wts["..."]``, ``terms["..."]``), read from its source: a term computed, weighed or switched under a name no
    declaration has fails here, not silently at weight 0."""
    stored: set[str] = set()
    asked: set[str] = set()
    for node in ast.walk(ast.parse(OBJECTIVE.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Constant):
            owner = node.value.attr if isinstance(node.value, ast.Attribute) else getattr(node.value, "id", None)
            if owner in ("terms", "wts"):
                asked.add(node.slice.value)
                if owner == "terms" and isinstance(node.ctx, ast.Store):
                    stored.add(node.slice.value)
        elif isinstance(node, ast.Call) and getattr(node.func, "id", None) == "on" and node.args:
            arg = node.args[0]
            asked.add(arg.value if isinstance(arg, ast.Constant) else repr(ast.unparse(arg)))
    return stored, asked


def test_every_term_is_declared_once():
    assert len(set(ALL_TERMS)) == len(ALL_TERMS), [n for n in ALL_TERMS if ALL_TERMS.count(n) > 1]


def test_the_objective_computes_exactly_the_declared_terms():
    stored, asked = _objective_names()
    assert stored == set(ALL_TERMS), (stored - set(ALL_TERMS), set(ALL_TERMS) - stored)
    assert asked <= set(ALL_TERMS), asked - set(ALL_TERMS)


def test_every_weight_and_phase_a_term_names_is_a_config_field():
    names = {f.name for f in fields(FitConfig)}
    for term in TERMS:
        assert term.weight in names and field_kind(term.weight) == "float", term
        assert term.until is None or term.since is None, term
        assert {term.until, term.since} - {None} <= set(PHASE_FIELDS), term


def test_every_weight_field_weighs_a_term():
    weights = {f.name for f in fields(FitConfig) if f.name.startswith("w_")}
    assert weights == {term.weight for term in TERMS}


def test_loss_weights_follow_the_schedule():
    cfg = apply_overrides(preset_config("draft"), {"bootstrap_steps": "300", "global_rigidity_steps": "150"})
    early, middle, late = loss_weights(cfg, 0), loss_weights(cfg, 150), loss_weights(cfg, 300)
    assert list(early) == list(ALL_TERMS)
    assert early["global_rigidity_bg"] == cfg.w_global_rigidity_bg and middle["global_rigidity_bg"] == 0.0
    assert early["mask"] == middle["mask"] == cfg.w_mask and late["mask"] == 0.0
    assert early["mask_prior"] == 0.0 and late["mask_prior"] == cfg.w_mask_prior
    assert early["mask_hold"] == 0.0 and late["mask_hold"] == cfg.w_mask
    assert early["scribble"] == cfg.w_scribble and late["scribble"] == 0.0
    assert all(early[t] == late[t] for t in ("rgb", "gradient", "rigidity", "flow", "anchor"))


@pytest.mark.parametrize("steps", [1, 5, 10])
@pytest.mark.parametrize("bootstrap", [0, 4, 10])
@pytest.mark.parametrize("rigid", [0, 3, 12])
def test_ever_on_is_any_step_of_the_fit(steps, bootstrap, rigid):
    cfg = apply_overrides(
        preset_config("draft"),
        {"steps": str(steps), "bootstrap_steps": str(bootstrap), "global_rigidity_steps": str(rigid), "w_flow": "0"},
    )
    for term in TERMS:
        assert term.ever_on(cfg) == any(loss_weights(cfg, s)[term.name] != 0.0 for s in range(steps)), term.name


def test_every_rule_leaves_its_term_off_with_a_reason_and_some_scene_turns_it_on():
    """Over every combination of what a scene can have, each term is on somewhere and off somewhere (a rule that can
    never pass, or never fail, is a mistake), and every term left off says why in one line."""
    draft = preset_config("draft")
    zero = {f.name: "0" for f in fields(FitConfig) if f.name.startswith("w_")}
    cfgs = [
        apply_overrides(draft, {"long_flow_max_gap": "4", "bootstrap_steps": str(draft.steps // 2)}),
        preset_config("paper"),
        apply_overrides(draft, zero),
    ]
    on: set[str] = set()
    off: set[str] = set()
    motions = (BG_MOTION_STATIC, BG_MOTION_PAN_ZOOM, BG_MOTION_DEFORMABLE)
    for cfg, fg, flow, gaps, scribbles, motion in itertools.product(
        cfgs, range(3), (False, True), (False, True), (0, 2), motions
    ):
        for term in TERMS:
            reason = term.why_off(SceneFacts(cfg, fg, flow, gaps, scribbles, motion))
            if reason is None:
                on.add(term.name)
            else:
                off.add(term.name)
                assert reason.startswith("off: ") and "\n" not in reason, (term.name, reason)
    assert on == off == set(ALL_TERMS), (set(ALL_TERMS) - on, set(ALL_TERMS) - off)
