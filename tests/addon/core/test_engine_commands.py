"""The engine command lines (``core.engine_commands``): each verb's argv exactly as the engine's CLI takes it."""

from __future__ import annotations

import pytest
from neural_atlas.addon.core import engine_commands as EC
from neural_atlas.addon.core.errors import UserError

from engine import contract as C
from engine.terms.run_folder import FIT_AUTO_PARTS_FLAG

CLIP = EC.ClipInputs("/clip/plate", ("/run.masks/layer1", "/hand/masks"), 0, 2)


def test_fit_argv_plate_masks_frames_out_preset_sets_no_bar():
    argv = EC.fit_argv("py", CLIP, "/run", "draft", EC.set_args(512, "steps=60 'eval_every=20'"))
    assert argv == [
        *("py", "-m", C.CLI_MODULE, C.VERB_FIT, "/clip/plate"),
        *("--mask", "/run.masks/layer1", "--mask", "/hand/masks", "--frames", "0:2"),
        *("--out", "/run", "--preset", "draft"),
        *("--set", "long_edge=512", "--set", "steps=60", "--set", "eval_every=20"),
        EC.NO_BAR_FLAG,
    ]


def test_scribbles_go_to_the_fit_but_not_to_the_estimate():
    scribbled = EC.ClipInputs(CLIP.plate, CLIP.masks[:1], 0, 2, "/run.scribbles")
    fit = EC.fit_argv("py", scribbled, "/run", "draft", [])
    assert fit[fit.index(C.SCRIBBLE_ARG) + 1] == "/run.scribbles" and fit.index(C.SCRIBBLE_ARG) > fit.index("--frames")
    estimate = EC.estimate_argv("py", scribbled, EC.set_args(768))
    assert estimate == [
        *("py", "-m", "engine", C.VERB_ESTIMATE, "/clip/plate", "--mask", "/run.masks/layer1"),
        *("--frames", "0:2", "--set", "long_edge=768", "--json"),
    ]


def test_find_parts_on_leaves_the_split_to_the_engine_and_off_tells_it_not_to():
    """Find Parts on (the default): no flag, the engine splits the parts that move apart wherever that applies;
    off: ``--no-auto-parts`` to the fit; the estimate gets neither."""
    flags = {FIT_AUTO_PARTS_FLAG, C.FIT_NO_AUTO_PARTS_FLAG}
    on = EC.ClipInputs(CLIP.plate, CLIP.masks[:1], 0, 2)
    assert not flags & set(EC.fit_argv("py", on, "/run", "draft", []))
    off = EC.ClipInputs(CLIP.plate, CLIP.masks[:1], 0, 2, auto_parts=False)
    fit = EC.fit_argv("py", off, "/run", "draft", [])
    assert fit.count(C.FIT_NO_AUTO_PARTS_FLAG) == 1 and FIT_AUTO_PARTS_FLAG not in fit and C.SCRIBBLE_ARG not in fit
    assert not flags & set(EC.estimate_argv("py", off, EC.set_args(768)))


def test_resume_export_masks_and_version():
    assert EC.resume_argv("py", "/run") == ["py", "-m", "engine", C.VERB_FIT, "--resume", "--out", "/run", "--no-bar"]
    assert EC.export_argv("py", "/run") == ["py", "-m", "engine", C.VERB_EXPORT, "/run"]
    no_follow = ["py", "-m", "engine", C.VERB_EXPORT, "/run", C.EXPORT_NO_FOLLOW_FLOW_FLAG]  # Follow Motion off
    assert EC.export_argv("py", "/run", follow_flow=False) == no_follow
    assert EC.masks_argv("py", "/clip/plate", "/run/auto_masks", 0, 5) == [
        *("py", "-m", "engine", C.VERB_MASKS, "/clip/plate", "--out", "/run/auto_masks", "--frames", "0:5")
    ]
    assert EC.version_argv("py") == ["py", "-m", "engine", "--version"]


@pytest.mark.parametrize("typed", ["steps=60 'eval_every=20", 'lr="0.001', "steps=60 \\"])
def test_an_unbalanced_quote_in_overrides_is_one_line_naming_the_field(typed):
    """``shlex.split`` raised ValueError on what the artist typed, a traceback out of the Fit operator; now a
    UserError the driver shows as the panel's one line: the field, what was typed, how to fix it."""
    with pytest.raises(UserError) as exc:
        EC.set_args(512, typed)
    message = str(exc.value)
    assert "\n" not in message and message.startswith(f"{EC.OVERRIDES_FIELD}: ")
    assert repr(typed) in message and "close the quote" in message and "KEY=VALUE" in message


def test_quoted_overrides_still_split_like_a_shell():
    assert EC.split_overrides("steps=60  'note=a b' ") == ["steps=60", "note=a b"]
    assert EC.set_args(768, "") == ["--set", "long_edge=768"]
