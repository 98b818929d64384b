"""Loss weights are range-checked (finite, >= 0, at most ``MAX_LOSS_WEIGHT``) before anything is written, and a fit
that diverges because of a weight says so: the fix it prints is the weight, not the learning rates (a resume keeps
the weights, so lower rates alone diverge again, forever)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from engine import contract as C
from engine.config import MAX_LOSS_WEIGHT, VALID, FitConfig, apply_overrides, preset_config
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.errors import InputError
from engine.fit.divergence import NonFinite, diverged_message, suspect_weights
from engine.fit.run_folder import RunFolder
from tests.engine_cli import run_cli
from tests.untouched import digest_outside

WEIGHTS = [f.name for f in dataclasses.fields(FitConfig) if f.name.startswith("w_")]
BOUND = f"a finite number in 0..{int(MAX_LOSS_WEIGHT)}"


def test_every_loss_weight_is_bounded_by_the_named_constant():
    assert len(WEIGHTS) == 14
    for name in WEIGHTS:
        valid = VALID[name]
        assert (valid.low, valid.high, valid.above) == (0, MAX_LOSS_WEIGHT, False), name
    assert all(getattr(preset_config(p), w) <= MAX_LOSS_WEIGHT for p in ("draft", "balanced", "final") for w in WEIGHTS)


@pytest.mark.parametrize("value", ["1e308", "1000000.5", "-1", "inf", "nan"])
def test_an_absurd_weight_is_refused_in_one_line_naming_its_bound(value):
    with pytest.raises(InputError) as info:
        apply_overrides(preset_config("draft"), {"w_flow": value})
    assert str(info.value) == (
        f"--set w_flow={value}: w_flow must be {BOUND} — `python -m engine fit --help-config` lists every field's range"
    )


def test_weights_at_the_bound_and_zero_are_taken():
    cfg = apply_overrides(preset_config("draft"), {"w_flow": str(MAX_LOSS_WEIGHT), "w_rgb": "0"})
    assert (cfg.w_flow, cfg.w_rgb) == (MAX_LOSS_WEIGHT, 0.0)


def test_fit_with_w_flow_1e308_exits_2_before_writing_anything(tmp_path):
    frames, masks = write_scene(make_scene(SceneSpec(width=32, height=24, frames=2)), tmp_path / "clip")
    run = tmp_path / "run"
    before = digest_outside(tmp_path)
    code, err = run_cli("fit", frames, "--mask", masks, "--out", run, "--no-bar", "--set", "w_flow=1e308")
    assert (code, err) == (
        C.EXIT_BAD_INPUT,
        [f"error: --set w_flow=1e308: w_flow must be {BOUND} — `python -m engine fit --help-config` lists every "
         "field's range"],
    )  # fmt: skip
    assert not run.exists() and digest_outside(tmp_path) == before


def test_a_config_json_with_an_absurd_weight_is_refused_naming_the_file(tmp_path):
    run = RunFolder(tmp_path / "run")
    run.path.mkdir()
    data = json.loads(preset_config("draft").to_json())
    data["config"]["w_flow"] = 1e308
    run.config.write_text(json.dumps(data), encoding="utf-8")
    before = digest_outside(tmp_path)
    with pytest.raises(InputError) as info:
        run.read_config()
    assert str(info.value) == (
        f"{run.config}: config 'w_flow' must be {BOUND}, not 1e+308 — restore it, or fit into a new run folder"
    )
    assert digest_outside(tmp_path) == before


def _message(cfg: FitConfig, error: NonFinite, tmp_path: Path) -> str:
    return diverged_message(error, cfg, RunFolder(tmp_path / "run"), checkpoint_step=40)


def test_a_divergence_with_a_weight_far_above_its_presets_names_the_weight_not_the_rates(tmp_path):
    cfg = apply_overrides(preset_config("draft"), {"w_flow": "1e6"})
    message = _message(cfg, NonFinite(41, "loss", []), tmp_path)
    assert message == (
        f"{tmp_path / 'run'}: the fit diverged at step 41: the loss became NaN/Inf — likely cause: the loss weight "
        "w_flow=1e+06, far above the draft preset's (5); a resume keeps the weights, so fit again with --refit "
        "--set w_flow=5 (edit layers and exports are kept)"
    )
    assert "lr" not in message and "\n" not in message


def test_the_weight_of_the_term_that_went_non_finite_is_named_first(tmp_path):
    cfg = apply_overrides(preset_config("draft"), {"w_flow": "1e6", "w_rigidity": "1e6"})
    assert suspect_weights(NonFinite(3, "loss", ["rigidity"]), cfg) == ["w_rigidity", "w_flow"]
    assert suspect_weights(NonFinite(3, "loss", []), cfg) == ["w_rigidity", "w_flow"]  # the further off first
    assert suspect_weights(NonFinite(3, "gradients", ["grids"]), preset_config("draft")) == []


def test_weights_near_their_presets_leave_the_learning_rate_advice_as_it_was(tmp_path):
    cfg = apply_overrides(preset_config("draft"), {"lr": "1e8", "w_flow": "25", "w_mask_prior": "20"})
    message = _message(cfg, NonFinite(41, "loss", ["flow"]), tmp_path)
    assert "likely cause: a learning rate too high (lr=1e+08) or extreme values in the plate" in message
    assert message.endswith(f"--out {tmp_path / 'run'} --set lr=0.001")
