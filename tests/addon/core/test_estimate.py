"""The fit-time estimate (``core.estimate``): the documented one, the preset menu, and the engine's own."""

from __future__ import annotations

import json

import pytest
from neural_atlas.addon.core import estimate

from engine import contract as C


def test_estimate_grows_with_frames_and_preset():
    draft = estimate.estimate_seconds("draft", 50, 854, 480)
    assert draft == pytest.approx(800 * 0.132 + 70.0, rel=0.02)  # the documented training time + flow, eval
    assert estimate.estimate_seconds("balanced", 50, 854, 480) > draft
    assert estimate.estimate_seconds("draft", 100, 854, 480) > draft
    balanced = estimate.estimate_seconds("balanced", 50, 854, 480)
    assert estimate.estimate_seconds("no such preset", 50, 854, 480) == balanced
    assert C.working_size(854, 480, 768) == (768, 432)


def test_the_documented_estimate_follows_the_overrides_steps_and_working_size():
    """``steps=`` and ``long_edge=`` typed in Engine Settings change what the fit does, so they change the estimate too:
    the last one given wins, as in the engine; a value the engine would refuse leaves the preset's."""
    items = ["lr=1e-3", "steps=400", "steps=1600"]
    assert estimate.overridden_int(items, "steps") == 1600
    assert estimate.overridden_int(["steps=abc"], "steps") is None and estimate.overridden_int([], "steps") is None
    assert (
        estimate.overridden_int(["steps=0"], "steps") is None and estimate.overridden_int(["step=9"], "steps") is None
    )
    base = estimate.estimate_seconds("draft", 50, 854, 480)
    doubled = estimate.estimate_seconds("draft", 50, 854, 480, steps=1600)
    assert doubled - base == pytest.approx(800 * estimate.SECONDS_PER_STEP["draft"])
    assert estimate.estimate_seconds("draft", 50, 854, 480, 384) < base  # a quarter of the working pixels


def test_a_long_clips_steps_cost_more_as_its_batch_grows_and_the_paper_presets_do_not():
    """A preset's batch grows with a clip longer than ``contract.PRESET_CLIP_FRAMES`` says (the engine's
    ``FitConfig.step_batch``), and a step's time with its batch: the training part of the estimate scales so."""
    assert estimate.batch_scale("draft", 70) == 1.0 and estimate.batch_scale("draft", 35) == 1.0
    assert estimate.batch_scale("draft", 280) == pytest.approx(4.0) and estimate.batch_scale("paper", 280) == 1.0
    short, long = (estimate.estimate_seconds("draft", n, 854, 480) for n in (70, 280))
    overhead = estimate.OVERHEAD_SECONDS_PER_FRAME_MPX * 0.768 * 0.432
    assert long - 280 * overhead == pytest.approx(4 * (short - 70 * overhead))


def test_working_size_rounds_half_up_like_the_engine():
    """One definition (``contract.working_size``): a half rounds up, where Python's ``round`` rounds to even."""
    assert C.working_size(10, 5, 5) == (5, 3) and round(5 * 0.5) == 2
    assert C.working_size(480, 854, 768) == (432, 768)
    assert C.working_size(320, 240, 768) == (320, 240)  # never enlarged
    with pytest.raises(ValueError, match="positive"):
        C.working_size(0, 240)


def test_preset_menu_is_the_engines_presets():
    """The menu and the fallback estimate read the contract's budgets, the engine builds its presets with them."""
    from engine.config import PRESETS as presets

    assert list(estimate.SECONDS_PER_STEP) == list(presets) == list(C.PRESET_STEPS)
    assert [name for name, _, _ in estimate.preset_items()] == list(presets)
    assert {name: int(text.split(" steps")[0]) for name, _, text in estimate.preset_items()} == {
        name: cfg.steps for name, cfg in presets.items()
    }


def test_engine_estimate_parsed_and_preferred():
    row = {"preset": "draft", "total_seconds": 61.0, "expected_psnr": 25.7}
    text = "noise\n" + json.dumps({C.ESTIMATE_TAG: 1, "presets": [row]}) + "\n"
    rows = estimate.parse_engine_estimate(text, C.ESTIMATE_TAG)
    assert rows == {"draft": {"seconds": 61.0, "psnr": 25.7}}
    assert estimate.estimate_text("draft", rows, 999) == "about 1m01s here (engine estimate), ~25.7 dB"
    assert estimate.estimate_text("final", rows, 204) == "about 3m24s on a 2-core CPU (documented)"
    assert estimate.parse_engine_estimate("not json\n", C.ESTIMATE_TAG) == {}


def test_a_preset_the_engine_cannot_fit_is_shown_with_its_reason():
    """``engine estimate`` gives every preset a row; the paper's on a clip without exactly one mask says why
    (``unavailable``) instead of timings. The reader keeps the reason and the panel's line shows it."""
    why = "the paper model fits exactly 1 foreground layer and this clip has 0 (no --mask)"
    rows = [
        {"preset": "draft", "total_seconds": 61.0, "expected_psnr": 25.7, "unavailable": None},
        {"preset": "paper", "total_seconds": None, "expected_psnr": None, "unavailable": why},
    ]
    parsed = estimate.parse_engine_estimate(json.dumps({C.ESTIMATE_TAG: 1, "presets": rows}), C.ESTIMATE_TAG)
    assert parsed == {
        "draft": {"seconds": 61.0, "psnr": 25.7},
        "paper": {"seconds": None, "psnr": None, "unavailable": why},
    }
    assert estimate.estimate_text("paper", parsed, 999) == f"paper cannot fit this clip: {why}"
    assert estimate.estimate_text("draft", parsed, 999) == "about 1m01s here (engine estimate), ~25.7 dB"
    assert estimate.estimate_text("paper", json.loads(json.dumps(parsed)), 999).endswith(why)  # as the scene keeps it
