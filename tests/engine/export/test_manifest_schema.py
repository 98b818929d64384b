"""The manifest's JSON Schema (engine/export/manifest.schema.json) against the models it is generated from, the
manifests exports write, and ``engine.terms.manifest.validate_manifest``, the check every reader goes through.

The schema is checked through its pydantic models (``engine.export.manifest_schema``): the file is their
``model_json_schema()``, which the first test holds it to; ``jsonschema`` is not among the test environment's
packages. On the fuzz cases of tests/contract/test_manifest_fuzz.py the models and ``validate_manifest`` agree: a
manifest ``validate_manifest`` accepts, the models accept, and one the models accept but it refuses is refused
for a rule JSON Schema cannot say (``CROSS_FIELD_RULES``).
"""

from __future__ import annotations

import json
import re
import tomllib
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import BaseModel, ValidationError

from engine import contract as C
from engine.export import manifest_schema as S
from engine.terms.cli import INSTALLED_MODULE
from engine.terms.colour import COLORSPACES, COLOUR_SOURCES
from engine.terms.export_names import PASS_PRECISIONS, ROLE_BACKGROUND
from engine.terms.manifest import (
    MANIFEST_FIELDS,
    MANIFEST_KEYS,
    MANIFEST_LAYER_FIELDS,
    MANIFEST_OPTIONAL_FIELDS,
    MANIFEST_OPTIONAL_LAYER_FIELDS,
    MANIFEST_TAG,
    MANIFEST_VERSION,
    validate_manifest,
)
from engine.terms.run_folder import BG_MOTIONS, SCENE_KEYS
from tests.contract.test_manifest_fuzz import FUZZ, JSON, PLAUSIBLE, _mutated, _nodes
from tests.engine.export.tiny_run import export, make_run
from tests.engine.fake_export import make_fake_export
from tests.paths import ROOT

#: What ``validate_manifest`` refuses that the schema lets through: rules across fields, or beyond what a JSON
#: Schema keyword says. Each is the start of ``validate_manifest``'s message (a pattern) and the rule in words.
CROSS_FIELD_RULES: dict[str, str] = {
    r"manifest 'clip' has unknown kind or colour space": (
        "clip.colorspace is sRGB or linear where there is no clip.colour_config; with one, both are printable"
    ),
    r"manifest 'clip' frame_numbers are not ascending": "clip.frame_numbers ascend (the schema says distinct)",
    r"manifest 'clip' first_frame and last_frame": "clip.first_frame and last_frame are frame_numbers' ends",
    r"manifest 'clip' lists \d+ frame files for \d+ frames": "a sequence has one frame file per frame number",
    r"manifest 'passes' frames .* are not distinct frames of the clip": "passes.frames are among the clip's",
    r"manifest 'passes' resolution is not the clip's": "passes.resolution is clip.resolution",
    r"manifest 'passes' pattern .* does not name a pass file": "passes.pattern, formatted, is one file name",
    r"manifest layer \d+ has index": "a layer's index is its position in layers",
    r"manifest layer \d+ is a \w+ layer": "layer 0 is the background, the only one",
    r"manifest layer names .* are not unique": "layer names are unique",
    r"manifest 'scene' says .* layers but the manifest has": "scene.num_layers is the number of layers",
}
# Where a JSON Schema validator in another language reads the schema otherwise than ``validate_manifest`` (the
# fuzz cases below cannot reach these; said here so that a reader of the schema knows):
# - JSON Schema's "integer" takes a number with no fraction (1.0); ``validate_manifest`` (and the models) take only
#   an integer as written (1), but for the version tag, which it compares as a number (1.0 passes, as in the schema);
# - ECMA-262 patterns match ASCII digits for \d and end at ``$``; Python's ``re`` (the timecode's check) takes
#   other digits and a newline before the end.


@pytest.fixture(scope="module")
def real(tmp_path_factory) -> dict[str, Any]:
    """A real export's manifest (a tiny fit, exported), decoded."""
    _, _, run = make_run(tmp_path_factory.mktemp("manifest_schema"))
    return json.loads(export(run).read_text(encoding="utf-8"))


def _accepted(data: Any) -> tuple[bool, str | None]:
    """Whether the models accept ``data``, and ``validate_manifest``'s refusal (None: it accepts)."""
    try:
        S.Manifest.model_validate(data)
        schema_ok = True
    except ValidationError:
        schema_ok = False
    try:
        validate_manifest(data)
    except C.ManifestError as exc:
        return schema_ok, str(exc)
    return schema_ok, None


def _agree(value: Any) -> None:
    """The models and ``validate_manifest`` agree on ``value`` (as a file holds it), but for CROSS_FIELD_RULES."""
    data = json.loads(json.dumps(value))
    schema_ok, refusal = _accepted(data)
    if refusal is None:
        assert schema_ok, "validate_manifest accepts a manifest the schema refuses"
    elif schema_ok:
        assert any(re.match(rule, refusal) for rule in CROSS_FIELD_RULES), refusal


def test_the_file_is_the_schema_the_models_make():
    assert S.SCHEMA_PATH.read_text(encoding="utf-8") == S.schema_text(), "run: python -m engine.export.manifest_schema"
    schema = json.loads(S.SCHEMA_PATH.read_text(encoding="utf-8"))
    assert (schema["$schema"], schema["$id"], schema["title"]) == (S.SCHEMA_DIALECT, S.SCHEMA_ID, S.SCHEMA_TITLE)
    assert schema["properties"][MANIFEST_TAG]["const"] == MANIFEST_VERSION


def _fields(model: type[BaseModel]) -> tuple[set[str], set[str]]:
    """The required and the optional keys of ``model`` (as the manifest spells them)."""
    required = {f.alias or name for name, f in model.model_fields.items() if f.is_required()}
    return required, {f.alias or name for name, f in model.model_fields.items()} - required


def _enum(model: type[BaseModel], key: str) -> tuple[str, ...]:
    """The values the schema allows for ``key`` of ``model``."""
    return tuple(S.manifest_schema()["$defs"][model.__name__]["properties"][key]["enum"])


def test_the_models_name_the_contracts_fields_and_values():
    parts = {"clip": S.Clip, "passes": S.Passes, "fit": S.Fit}
    assert _fields(S.Manifest) == ({MANIFEST_TAG, *MANIFEST_KEYS}, {"scene"})
    for section, model in parts.items():
        assert _fields(model) == (set(MANIFEST_FIELDS[section]), set(MANIFEST_OPTIONAL_FIELDS.get(section, {})))
    assert _fields(S.Layer) == (set(MANIFEST_LAYER_FIELDS), set(MANIFEST_OPTIONAL_LAYER_FIELDS))
    assert _fields(S.Scene) == (set(SCENE_KEYS), set())
    assert _enum(S.Clip, "kind") == C.CLIP_KINDS
    assert _enum(S.Clip, "colour_source") == COLOUR_SOURCES
    assert _enum(S.Layer, "role") == (ROLE_BACKGROUND, C.ROLE_FOREGROUND)
    assert _enum(S.Passes, "precision") == PASS_PRECISIONS
    assert _enum(S.Scene, "background_motion") == BG_MOTIONS


def test_real_exports_manifests_follow_the_schema(real, tmp_path):
    h, w = 6, 8
    plate = np.full((2, h, w, 3), 0.5, np.float32)
    layer = (lambda t, xs, ys: (xs / w, 1.0 - ys / h, np.ones(xs.shape)), (w, h))
    fake = json.loads(make_fake_export(tmp_path, plate, [layer, layer]).read_text(encoding="utf-8"))
    for manifest in (real, fake):
        S.Manifest.model_validate(manifest)
        assert _accepted(manifest) == (True, None)


def test_the_schema_refuses_what_validate_manifest_refuses_field_by_field(real):
    """A few refusals by name: types strict, bounds, patterns, absent is not null."""
    cases = [
        (("clip", "fps"), 0),
        (("clip", "resolution"), [0, 32]),
        (("clip", "timecode"), "1:00:00:00"),
        (("layers", 0, "name"), "Back ground"),
        (("layers", 0, "atlas_box"), [0, 0, 1]),
        (("fit", "steps"), True),
        (("passes", "frames"), [0, 0]),
        ((MANIFEST_TAG,), True),
        (("scene",), None),
    ]
    for at, value in cases:
        schema_ok, refusal = _accepted(_mutated(real, at, value, drop=False))
        assert not schema_ok and refusal is not None, at
    assert _accepted(_mutated(real, (MANIFEST_TAG,), 1.0, drop=False)) == (True, None)


@FUZZ
@given(
    value=JSON
    | st.dictionaries(st.sampled_from([*MANIFEST_KEYS, "scene", "x"]), JSON, max_size=8).map(
        lambda d: {MANIFEST_TAG: MANIFEST_VERSION, **d}
    )
)
def test_any_json_is_judged_alike(value):
    _agree(value)


@FUZZ
@given(data=st.data())
def test_a_real_manifest_with_one_part_changed_is_judged_alike(real, data):
    at = data.draw(st.sampled_from(_nodes(real)), label="at")
    drop = data.draw(st.booleans(), label="drop")
    replacement = None if drop else data.draw(JSON | PLAUSIBLE, label="replacement")
    _agree(_mutated(real, at, replacement, drop))


def test_each_cross_field_rule_is_one_the_schema_lets_through(real):
    """Every rule listed as beyond the schema is met: a manifest breaking only it passes the models."""
    clip, passes, layers = real["clip"], real["passes"], real["layers"]
    breaks = [
        (("clip", "colour_config"), None),  # dropped: the export's colour space is not a legacy one
        (("clip", "frame_numbers"), clip["frame_numbers"][::-1]),
        (("clip", "first_frame"), clip["first_frame"] + 1),
        (("clip", "frame_files"), clip["frame_files"][:1]),
        (("passes", "frames"), [max(clip["frame_numbers"]) + 1]),
        (("passes", "resolution"), [passes["resolution"][0] + 1, passes["resolution"][1]]),
        (("passes", "pattern"), "a/{frame}.exr"),
        (("layers", 0, "index"), 1),
        (("layers", 1, "role"), ROLE_BACKGROUND),
        (("layers", 1, "name"), layers[0]["name"]),
        (("scene", "num_layers"), len(layers) + 1),
    ]
    assert len(breaks) == len(CROSS_FIELD_RULES)
    matched = set()
    assert real["clip"]["colorspace"] not in COLORSPACES
    for at, value in breaks:
        schema_ok, refusal = _accepted(_mutated(real, at, value, drop=value is None))
        assert schema_ok and refusal is not None, (at, refusal)
        matched |= {rule for rule in CROSS_FIELD_RULES if re.match(rule, refusal)}
    assert matched == set(CROSS_FIELD_RULES)


def test_the_schema_file_ships_with_the_engine():
    """pyproject.toml's package-data names it (tests/packaging checks that the wheel holds every engine file)."""
    package_data = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]
    shipped = package_data["package-data"][INSTALLED_MODULE]
    assert S.SCHEMA_PATH.relative_to(ROOT / "engine").as_posix() in shipped
