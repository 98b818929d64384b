"""The shots file: what it accepts (TOML and JSON alike, paths relative to it, defaults) and the one-line error of
each mistake, naming the file, the shot, the key and the fix."""

from __future__ import annotations

import argparse
import json
import os
import string
from pathlib import Path
from typing import get_args

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from engine import contract as C
from engine.cli_options import frame_range
from engine.errors import InputError
from engine.farm.shots import DEFAULT_EXPORT_CHUNK, Shot, load_shots
from engine.farm.shots_model import PassPrecision
from engine.terms.cli import DEFAULT_PRESET
from engine.terms.export_names import PASS_PRECISIONS
from engine.terms.farm import FARM_PLAN, SHOT_DEFAULT_KEYS, SHOT_REQUIRED_KEYS
from tests.engine_cli import run_cli
from tests.farm.farm_helpers import write_clip, write_shots


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    """A folder holding a tiny clip (clip/frames, clip/masks) that every shots file here refers to."""
    folder = tmp_path_factory.mktemp("seq")
    write_clip(folder / "clip")
    return folder


def _error(path: Path) -> str:
    with pytest.raises(InputError) as info:
        load_shots(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}: ")
    return message


def test_toml_and_json_give_the_same_shots_with_paths_relative_to_the_file(seq):
    (seq / "shots.toml").write_text(
        f"""{C.SHOTS_TAG} = {C.SHOTS_VERSION}
[defaults]
preset = "draft"
set = ["steps=40"]
export_chunk = 3

[[shots]]
name = "sh010"
plate = "clip/frames"
masks = ["clip/masks"]
frames = "1-3"
fps = "24000/1001"

[[shots]]
name = "sh020"
plate = "./clip/frames"
preset = "final"
run = "elsewhere/sh020"
render = "renders/sh020"
render_format = "png"
preview = false
""",
        encoding="utf-8",
    )
    toml = load_shots(seq / "shots.toml")
    as_json = write_shots(
        seq,
        [
            {"name": "sh010", "plate": "clip/frames", "masks": ["clip/masks"], "frames": "1-3", "fps": "24000/1001"},
            {"name": "sh020", "plate": "./clip/frames", "preset": "final", "run": "elsewhere/sh020",
             "render": "renders/sh020", "render_format": "png", "preview": False},
        ],
        {"preset": "draft", "set": ["steps=40"], "export_chunk": 3},
    )  # fmt: skip
    assert load_shots(as_json).shots == toml.shots
    frames, masks = str(seq / "clip" / "frames"), str(seq / "clip" / "masks")
    assert toml.shots[0] == Shot.model_construct(
        name="sh010", plate=frames, run=str(seq / "runs" / "sh010"), masks=(masks,), frames=(1, 3),
        fps="24000/1001", preset="draft", set=("steps=40",), export_chunk=3,
    )  # fmt: skip
    assert toml.shots[1] == Shot.model_construct(
        name="sh020", plate=frames, run=str(seq / "elsewhere" / "sh020"), render=str(seq / "renders" / "sh020"),
        preset="final", set=("steps=40",), export_chunk=3, render_format="png", preview=False,
    )  # fmt: skip


def test_a_bare_shot_takes_every_default(seq):
    shot = load_shots(write_shots(seq, [{"name": "a", "plate": "clip/frames"}])).shots[0]
    assert (shot.preset, shot.set, shot.export_chunk, shot.preview, shot.render) == (
        DEFAULT_PRESET, (), DEFAULT_EXPORT_CHUNK, True, None)  # fmt: skip


GOOD = {"name": "sh010", "plate": "clip/frames"}


@pytest.mark.parametrize(
    ("shot", "defaults", "says"),
    [
        ({**GOOD, "frams": "1-3"}, None, "shot 'sh010': unknown key 'frams' — did you mean 'frames'?"),
        ({**GOOD, "frames": "3-1"}, None, "shot 'sh010': 'frames' '3-1' is reversed — write frames = \"1-3\""),
        ({**GOOD, "frames": "1..3"}, None, "shot 'sh010': 'frames' is '1..3'"),
        ({**GOOD, "frames": [1, 3]}, None, "'frames' is list [1, 3], not a FIRST-LAST string"),
        ({**GOOD, "export_chunk": 0}, None, "shot 'sh010': 'export_chunk' is 0 — give export_chunk a number >= 1"),
        ({**GOOD, "render_chunk": -5}, None, "'render_chunk' is -5 — give render_chunk a number >= 1"),
        ({**GOOD, "export_chunk": "50"}, None, "'export_chunk' is str '50', not a whole number"),
        ({**GOOD, "export_chunk": True}, None, "'export_chunk' is bool True, not a whole number"),
        ({**GOOD, "plate": "clip/nothing"}, None, "shot 'sh010': plate"),
        ({**GOOD, "masks": ["clip/nope"]}, None, "mask folder"),
        ({**GOOD, "masks": "clip/masks"}, None, "'masks' is str 'clip/masks', not a list of strings"),
        ({**GOOD, "masks": ["clip/masks"], "auto_masks": True}, None, "both 'masks' and 'auto_masks'"),
        ({**GOOD, "auto_parts": True}, None, "'auto_parts' splits one object, but the shot has 0 mask folder(s)"),
        ({**GOOD, "masks": ["clip/masks"] * 2, "auto_parts": True}, None, "has 2 mask folder(s)"),
        ({**GOOD, "masks": ["clip/masks"], "auto_parts": 1}, None, "'auto_parts' is int 1, not true or false"),
        ({**GOOD, "masks": ["clip/masks"], "auto_parts": True, "preset": "paper"}, None, "with the paper model"),
        ({**GOOD, "preset": "drafty"}, None, "'preset' is 'drafty' — did you mean 'draft'?"),
        ({**GOOD, "set": ["stepz=3"]}, None, "shot 'sh010': 'set': unknown config key 'stepz' — did you mean 'steps'?"),
        ({**GOOD, "set": ["steps=x"]}, None, "'set': --set steps=x: not a valid int"),
        ({**GOOD, "fps": "fast"}, None, "shot 'sh010': 'fps': frame rate 'fast'"),
        ({**GOOD, "device": "gpu"}, None, "'device' is 'gpu'"),
        ({**GOOD, "render_format": "jpg"}, None, "'render_format' is 'jpg'"),
        ({**GOOD, "preview": "yes"}, None, "'preview' is str 'yes', not true or false"),
        ({**GOOD, "name": "sh 010"}, None, "name 'sh 010' is not a plain identifier"),
        ({**GOOD, "name": "x" * (C.SHOT_NAME_MAX + 1)}, None, "is not a plain identifier"),
        ({"plate": "clip/frames"}, None, "shot #1: no 'name'"),
        ({"name": "sh010"}, None, "shot 'sh010': no 'plate'"),
        ({**GOOD, "render": "runs/sh010/renders"}, None, "'render'"),
        (GOOD, {"name": "x"}, "'defaults' sets 'name', which is a shot's own — move 'name' into each shot"),
        (GOOD, {"export_chunks": 3}, "'defaults': unknown key 'export_chunks' — did you mean 'export_chunk'?"),
        (GOOD, {"export_chunk": 0}, "'export_chunk' is 0"),
    ],
)
def test_each_mistake_is_one_line_naming_the_file_the_shot_the_key_and_the_fix(seq, shot, defaults, says):
    assert says in _error(write_shots(seq, [shot], defaults))


def test_the_contract_names_the_keys_a_shot_declares():
    """The add-on writes the shots file from the contract's keys (it has no pydantic), the engine reads it with
    ``Shot``: the two name the same keys and the same required ones, and every key [defaults] may give has a
    default of its own."""
    fields = Shot.model_fields
    assert len(set(C.SHOT_KEYS)) == len(C.SHOT_KEYS) and set(C.SHOT_KEYS) == set(fields)
    assert tuple(key for key, field in fields.items() if field.is_required()) == SHOT_REQUIRED_KEYS
    assert set(SHOT_DEFAULT_KEYS) <= set(fields) - set(SHOT_REQUIRED_KEYS)
    assert get_args(PassPrecision) == PASS_PRECISIONS  # the export's choices, as its parser declares them


@pytest.mark.parametrize("key", C.SHOT_KEYS)
def test_a_value_of_no_key_s_type_is_one_line_naming_the_key(seq, key):
    assert f": '{key}' is " in _error(write_shots(seq, [{**GOOD, key: {"x": 1}}]))


@pytest.mark.parametrize("text", ["1001-1100", "0:49", "7", " 3 - 5 ", "5-3", "+5", "1_000", "-5", "1..3", "1:2:3", ""])
def test_a_shot_s_frames_is_read_as_frames_on_the_command_line(seq, text):
    """The plan hands a shot's frames on to ``fit --frames``: what one accepts, the other does, as the same range."""
    path = write_shots(seq, [{**GOOD, "frames": text}])
    try:
        expected = frame_range(text)
    except argparse.ArgumentTypeError:
        assert "'frames'" in _error(path)
    else:
        assert load_shots(path).shots[0].frames == expected


def test_duplicate_names_and_run_folders_are_refused(seq):
    twice = write_shots(seq, [GOOD, {**GOOD, "name": "SH010"}])
    assert "shots 'sh010' and 'SH010' have the same name" in _error(twice)
    one_run = write_shots(seq, [{**GOOD, "run": "r"}, {**GOOD, "name": "sh020", "run": "r"}])
    assert "shots 'sh010' and 'sh020' have the same run folder" in _error(one_run)


def test_the_file_itself(seq):
    assert "is not a .toml or .json file" in _error(seq / "shots.yaml")
    assert "does not exist" in _error(seq / "missing.toml")
    (seq / "broken.toml").write_text("neural_atlas_shots = \n", encoding="utf-8")
    assert "is not valid TOML" in _error(seq / "broken.toml")
    (seq / "broken.json").write_text("{", encoding="utf-8")
    assert "is not valid JSON" in _error(seq / "broken.json")
    (seq / "v.json").write_text(json.dumps({C.SHOTS_LIST_KEY: [GOOD]}), encoding="utf-8")
    assert f"has no '{C.SHOTS_TAG}' version key — add {C.SHOTS_TAG} = {C.SHOTS_VERSION}" in _error(seq / "v.json")
    (seq / "v.json").write_text(json.dumps({C.SHOTS_TAG: 99, C.SHOTS_LIST_KEY: [GOOD]}), encoding="utf-8")
    assert "is a shots file of version 99" in _error(seq / "v.json")
    (seq / "v.json").write_text(json.dumps({C.SHOTS_TAG: 1, C.SHOTS_LIST_KEY: []}), encoding="utf-8")
    assert "'shots' is not a list of shots" in _error(seq / "v.json")
    (seq / "v.json").write_text(json.dumps({C.SHOTS_TAG: 1, "shot": [GOOD]}), encoding="utf-8")
    assert "the file: unknown key 'shot' — did you mean 'shots'?" in _error(seq / "v.json")


def test_the_cli_exits_2_with_the_one_line(seq):
    code, err = run_cli(C.VERB_FARM, FARM_PLAN, write_shots(seq, [{**GOOD, "frames": "9-2"}]))
    assert code == C.EXIT_BAD_INPUT
    assert len(err) == 1 and err[0].startswith(f"error: {seq / 'shots.json'}: shot 'sh010': 'frames'")


# --- properties -----------------------------------------------------------------------------------------------

_keys = st.text(string.ascii_lowercase + "_", min_size=1, max_size=12).filter(lambda k: k not in C.SHOT_KEYS)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(key=_keys)
def test_any_unknown_key_is_named(seq, key):
    message = _error(write_shots(seq, [{**GOOD, key: 1}]))
    assert f"shot 'sh010': unknown key '{key}'" in message


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(first=st.integers(0, 10**6), last=st.integers(0, 10**6), sep=st.sampled_from(["-", ":", " - "]))
def test_frames_are_accepted_exactly_when_in_order(seq, first, last, sep):
    path = write_shots(seq, [{**GOOD, "frames": f"{first}{sep}{last}"}])
    if first <= last:
        assert load_shots(path).shots[0].frames == (first, last)
    else:
        assert "is reversed" in _error(path)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(size=st.one_of(st.integers(-100, 100), st.floats(allow_nan=False), st.booleans(), st.text(max_size=3)))
def test_chunk_sizes_below_one_or_not_whole_numbers_are_refused(seq, size):
    path = write_shots(seq, [{**GOOD, "export_chunk": size}])
    if isinstance(size, int) and not isinstance(size, bool) and size >= 1:
        assert load_shots(path).shots[0].export_chunk == size
    else:
        assert "'export_chunk' is" in _error(path)


def test_a_relative_path_with_home_expands(seq, monkeypatch):
    monkeypatch.setenv("HOME", str(seq))
    shot = load_shots(write_shots(seq, [{**GOOD, "plate": "~/clip/frames"}])).shots[0]
    assert shot.plate == os.path.join(seq, "clip", "frames")
