"""Configs: presets, overrides with suggestions, versioned JSON round trip."""

from __future__ import annotations

import json

import pytest

from engine.config import (
    PRESETS,
    FitConfig,
    apply_overrides,
    config_help,
    loss_weights,
    parse_set_args,
    preset_config,
    weight_ever_on,
)
from engine.contract import SCHEMA_VERSION
from engine.errors import InputError


def test_presets_are_named_configs_with_their_own_budgets():
    assert set(PRESETS) == {"draft", "balanced", "final", "paper"}
    steps = [PRESETS[n].steps for n in ("draft", "balanced", "final")]
    assert steps == sorted(steps) and len(set(steps)) == 3
    assert PRESETS["paper"].model == "paper" and PRESETS["paper"].lr == 1e-4
    assert all(PRESETS[n].model == "fast" for n in ("draft", "balanced", "final"))
    assert all(PRESETS[n].preset == n for n in PRESETS)


def test_paper_preset_keeps_the_reference_weights():
    p = PRESETS["paper"]
    assert (p.w_rgb, p.w_gradient, p.w_sparsity, p.w_flow, p.w_alpha_flow) == (5000, 1000, 1000, 5, 49)
    assert (p.w_global_rigidity_fg, p.w_global_rigidity_bg, p.global_rigidity_delta) == (5, 50, 100)
    assert (p.bootstrap_steps, p.global_rigidity_steps, p.w_mask, p.w_mask_prior) == (10000, 5000, 2000, 0)


def test_preset_config_is_a_copy():
    a = preset_config("draft")
    a.steps = 1
    assert PRESETS["draft"].steps != 1


def test_overrides_parse_types():
    cfg = apply_overrides(FitConfig(), parse_set_args(["steps=1e3", "w_rgb=2.5", "init_motion=false", "model=paper"]))
    assert (cfg.steps, cfg.w_rgb, cfg.init_motion, cfg.model) == (1000, 2.5, False, "paper")


@pytest.mark.parametrize("bad", ["stpes=10", "w_rbg=1"])
def test_unknown_key_suggests_nearest(bad):
    with pytest.raises(InputError) as err:
        apply_overrides(FitConfig(), parse_set_args([bad]))
    msg = str(err.value)
    assert "did you mean" in msg and "\n" not in msg


def test_bad_values_and_malformed_items():
    with pytest.raises(InputError, match="not a valid int"):
        apply_overrides(FitConfig(), {"steps": "1.5"})
    with pytest.raises(InputError, match="key=value"):
        parse_set_args(["steps"])


def test_unknown_preset_suggests_nearest():
    with pytest.raises(InputError, match="did you mean 'balanced'"):
        preset_config("balance")


def test_json_round_trip_and_schema_check():
    cfg = apply_overrides(preset_config("final"), {"steps": "123"})
    back = FitConfig.from_json(cfg.to_json())
    assert back == cfg
    data = json.loads(cfg.to_json())
    assert data["schema"] == SCHEMA_VERSION
    data["schema"] = SCHEMA_VERSION + 1
    with pytest.raises(InputError, match="schema"):
        FitConfig.from_json(json.dumps(data), "run/config.json")


def test_config_help_documents_every_field():
    text = config_help()
    for name in FitConfig.__dataclass_fields__:
        line = next(ln for ln in text.splitlines() if ln.strip().startswith(name + " "))
        assert line.split("): ", 1)[1].strip(), f"{name} has no docstring"


def test_loss_weights_follow_the_schedule():
    cfg = apply_overrides(preset_config("draft"), {"bootstrap_steps": "300", "global_rigidity_steps": "150"})
    early, middle, late = loss_weights(cfg, 0), loss_weights(cfg, 150), loss_weights(cfg, 300)
    assert early["global_rigidity_bg"] == cfg.w_global_rigidity_bg and middle["global_rigidity_bg"] == 0.0
    assert early["mask"] == middle["mask"] == cfg.w_mask and late["mask"] == 0.0
    assert early["mask_prior"] == 0.0 and late["mask_prior"] == cfg.w_mask_prior
    assert all(early[t] == late[t] for t in ("rgb", "gradient", "rigidity", "flow", "anchor"))


@pytest.mark.parametrize("steps", [1, 5, 10])
@pytest.mark.parametrize("bootstrap", [0, 4, 10])
@pytest.mark.parametrize("rigid", [0, 3, 12])
def test_weight_ever_on_is_any_step_of_the_fit(steps, bootstrap, rigid):
    cfg = apply_overrides(
        preset_config("draft"),
        {"steps": str(steps), "bootstrap_steps": str(bootstrap), "global_rigidity_steps": str(rigid), "w_flow": "0"},
    )
    for term in loss_weights(cfg, 0):
        assert weight_ever_on(cfg, term) == any(loss_weights(cfg, s)[term] != 0.0 for s in range(steps)), term
