"""Configs: presets, overrides with suggestions, versioned JSON round trip, and every field's declared range
(checked for ``--set`` and for a run's config.json alike, one line, nothing written)."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
from dataclasses import fields

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from engine import cli
from engine import contract as C
from engine.config import (
    PRESETS,
    RESUMABLE_FIELDS,
    VALID,
    FitConfig,
    apply_overrides,
    check_config,
    config_help,
    field_kind,
    parse_set_args,
    preset_config,
    resume_changes,
)
from engine.errors import InputError
from engine.fit.run_folder import RunFolder
from engine.terms.versions import SCHEMA_VERSION


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


# --- every field's valid range ------------------------------------------------------------------------------


def out_of_range(name: str) -> str:
    """A ``--set`` value just outside field ``name``'s declared range (or not one of its choices)."""
    kind = field_kind(name)
    valid = VALID[name]
    if kind == "bool":
        return "maybe"
    if kind == "str":
        return "no-such-choice" if valid.choices else ""
    if valid.low is None:
        return "nan"
    if valid.above:
        return repr(valid.low) if kind == "float" else str(int(valid.low))
    below = valid.low - (1 if kind == "int" else 1e-3)
    return str(int(below)) if kind == "int" else repr(below)


FIELDS = [f.name for f in fields(FitConfig)]


def test_every_field_declares_its_range_and_help_shows_it():
    assert set(VALID) == set(FIELDS)
    text = config_help()
    for name in FIELDS:
        line = next(ln for ln in text.splitlines() if ln.strip().startswith(name + " "))
        assert VALID[name].describe(field_kind(name)) in line, line
    for preset in PRESETS.values():  # every preset is within the ranges
        assert check_config(preset) is preset


@pytest.mark.parametrize("name", FIELDS)
def test_an_out_of_range_value_is_one_line_and_writes_nothing(tmp_path, name):
    """``fit --set NAME=<just outside its range>`` through the real CLI: exit 2, one stderr line naming the
    field, and no run folder."""
    value = out_of_range(name)
    run = tmp_path / "run"
    err = io.StringIO()
    argv = ["fit", str(tmp_path / "clip"), "--out", str(run), "--preset", "draft", "--set", f"{name}={value}"]
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = cli.main(argv)
    lines = err.getvalue().splitlines()
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1, err.getvalue()
    assert lines[0].startswith(f"error: --set {name}=") and name in lines[0], lines[0]
    assert not run.exists()


@pytest.mark.parametrize("name", FIELDS)
def test_an_out_of_range_value_in_config_json_is_one_line_naming_the_file(tmp_path, name):
    """The same ranges when a run's config.json is loaded (edited by hand): one line naming config.json."""
    run = RunFolder(tmp_path)
    run.write_config(preset_config("draft"))
    data = json.loads(run.config.read_text())
    raw = out_of_range(name)
    data["config"][name] = (
        {"maybe": "maybe", "": ""}.get(raw, raw) if field_kind(name) in ("bool", "str") else float(raw)
    )
    run.config.write_text(json.dumps(data))
    with pytest.raises(InputError) as err:
        run.read_config()
    text = str(err.value)
    assert text.startswith(f"{run.config}: config {name!r} must be") and "\n" not in text, text


@pytest.mark.parametrize(
    ("value", "needle"),
    [("12", "must be true or false"), (3.5, "must be an int"), (True, "must be an int"), ([1], "must be an int")],
)
def test_config_json_types_are_checked(tmp_path, value, needle):
    run = RunFolder(tmp_path)
    run.write_config(preset_config("draft"))
    data = json.loads(run.config.read_text())
    data["config"]["init_motion" if needle.endswith("false") else "steps"] = value
    run.config.write_text(json.dumps(data))
    with pytest.raises(InputError, match=needle):
        run.read_config()


def test_a_field_missing_from_config_json_takes_its_default(tmp_path):
    """A config.json of an earlier engine holds no later field: it reads with the default (a checkpoint that was
    fitted with another value is refused when the run loads: test_resume_checks)."""
    run = RunFolder(tmp_path)
    run.write_config(apply_overrides(preset_config("draft"), {"lr": "5e-4"}))
    data = json.loads(run.config.read_text())
    del data["config"]["lr"]
    run.config.write_text(json.dumps(data))
    assert run.read_config().lr == FitConfig().lr


@settings(max_examples=200, deadline=None)
@given(name=st.sampled_from(FIELDS), value=st.one_of(st.integers(), st.floats(), st.booleans(), st.text()))
def test_property_any_value_is_accepted_in_range_or_refused_in_one_line(name, value):
    """Any value of any type for any field: taken (and then within the field's declared range) or a one-line
    ``InputError``, never another exception."""
    try:
        cfg = apply_overrides(FitConfig(), {name: value}, source="run/config.json")
    except InputError as exc:
        assert "\n" not in str(exc) and name in str(exc)
        return
    assert VALID[name].accepts(getattr(cfg, name)) and check_config(cfg) is cfg


def test_resume_may_change_the_schedule_only():
    saved = preset_config("draft")
    allowed, refused = resume_changes(saved, apply_overrides(saved, {"lr": "1e-4", "steps": "900", "seed": "3"}))
    assert allowed == ["steps", "lr"] and refused == ["seed"]
    assert set(RESUMABLE_FIELDS) <= set(FIELDS) and "model" not in RESUMABLE_FIELDS


#: The fields FitConfig had when checkpoints began to record their config. A field added since must be in
#: LATER_FIELDS (with the value that computes what the engine did before it), or every run folder made before it
#: stops loading ("checkpoint was saved with another config").
FIELDS_WHEN_CHECKPOINTS_RECORDED_CONFIG = frozenset(
    [
        "preset",
        "model",
        "steps",
        "batch",
        "object_sample_share",
        "seed",
        "long_edge",
        "flow_preset",
        "flow_threshold_px",
        "lr",
        "lr_grid",
        "lr_final_ratio",
        "w_rgb",
        "w_gradient",
        "w_sparsity",
        "w_atlas_sparsity",
        "atlas_sparsity_samples",
        "w_flow",
        "w_alpha_flow",
        "w_rigidity",
        "rigidity_delta",
        "w_global_rigidity_fg",
        "w_global_rigidity_bg",
        "global_rigidity_delta",
        "global_rigidity_steps",
        "w_mask",
        "bootstrap_steps",
        "w_scribble",
        "scribble_samples",
        "w_mask_prior",
        "mask_prior_margin_px",
        "w_anchor",
        "uv_mapping_scale",
        "pretrain_iters",
        "mapping_hidden",
        "mapping_layers",
        "atlas_levels",
        "atlas_features",
        "atlas_density",
        "alpha_levels",
        "alpha_features",
        "alpha_density",
        "decoder_hidden",
        "warp_levels",
        "warp_foreground",
        "warp_cell_px",
        "lr_warp",
        "init_motion",
        "atlas_margin_fg",
        "components",
        "atlas_box_full_mask",
        "eval_every",
        "eval_pixels",
        "checkpoint_seconds",
    ]
)


def test_every_field_added_since_checkpoints_recorded_their_config_says_how_older_runs_load():
    from engine.config import LATER_FIELDS

    names = {f.name for f in fields(FitConfig)}
    added = names - FIELDS_WHEN_CHECKPOINTS_RECORDED_CONFIG
    assert added <= set(LATER_FIELDS), f"add {sorted(added - set(LATER_FIELDS))} to config.LATER_FIELDS"
    assert set(LATER_FIELDS) <= names
    for name, value in LATER_FIELDS.items():  # the old behaviour is a value the field accepts
        assert getattr(apply_overrides(FitConfig(), {name: str(value).lower()}), name) == value


def test_the_mappings_rate_reaches_its_final_ratio_at_lr_mapping_steps_and_stays_there():
    import torch

    from engine.fit.optimisation import make_scheduler

    groups = [{"params": [torch.zeros(1, requires_grad=True)], "lr": 1.0, "name": n} for n in ("grids", "mappings")]
    cfg = apply_overrides(preset_config("draft"), {"steps": "100", "lr_final_ratio": "0.1"})
    for mapping_steps, at_50, at_100 in ((0, 0.1**0.5, 0.1), (50, 0.1, 0.1), (400, 0.1**0.5, 0.1)):
        sched = make_scheduler(torch.optim.SGD(groups), dataclasses.replace(cfg, lr_mapping_steps=mapping_steps))
        grids, mappings = sched.lr_lambdas
        assert grids(50) == pytest.approx(0.1**0.5) and grids(100) == pytest.approx(0.1)
        assert mappings(50) == pytest.approx(at_50) and mappings(100) == pytest.approx(at_100)
        assert mappings(75) == pytest.approx(at_100 if mapping_steps == 50 else 0.1**0.75)


def test_balanced_settles_its_mappings_rate_by_step_1600_and_draft_decays_it_over_every_step():
    """The preset measured on every clip (docs/accuracy-vs-time.md, the balanced table): the mappings' rate at its
    final ratio from step 1600 of 6000; draft's 800 steps decay every rate to the end, as before."""
    import torch

    from engine.fit.optimisation import make_scheduler

    groups = [{"params": [torch.zeros(1, requires_grad=True)], "lr": 1.0, "name": n} for n in ("grids", "mappings")]
    balanced, draft = preset_config("balanced"), preset_config("draft")
    assert (balanced.lr_mapping_steps, balanced.steps, draft.lr_mapping_steps) == (1600, 6000, 0)
    grids, mappings = make_scheduler(torch.optim.SGD(groups), balanced).lr_lambdas
    ratio = balanced.lr_final_ratio
    assert mappings(1600) == pytest.approx(ratio) and mappings(4000) == pytest.approx(ratio)
    assert grids(1600) == pytest.approx(ratio ** (1600 / 6000)) and grids(6000) == pytest.approx(ratio)


def test_a_clip_longer_than_the_batch_is_for_draws_more_pixels_a_step_and_a_shorter_one_the_batch():
    """``batch_frames``: each frame keeps the samples a step gives it in a clip that long; the fast presets take it,
    and ``mapping_time_frames``, from the contract (the add-on's estimate scales their steps by it), the paper preset
    keeps its fixed batch."""
    cfg = dataclasses.replace(FitConfig(), batch=4000, batch_frames=70)
    assert [cfg.step_batch(n) for n in (1, 50, 70, 71, 140, 300)] == [4000, 4000, 4000, 4058, 8000, 17143]
    assert dataclasses.replace(cfg, batch_frames=0).step_batch(300) == 4000
    assert {n: PRESETS[n].batch_frames for n in PRESETS} == C.PRESET_CLIP_FRAMES
    assert {n: PRESETS[n].mapping_time_frames for n in PRESETS} == C.PRESET_CLIP_FRAMES
    assert C.PRESET_CLIP_FRAMES["paper"] == 0 and min(C.PRESET_CLIP_FRAMES[n] for n in ("draft", "final")) > 0
