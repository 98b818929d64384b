"""Property tests of the manifest readers: whatever a hand edit, another tool or a damaged disk leaves in a
manifest.json, ``contract.load_manifest``, ``engine.export.manifest.Manifest`` and the add-on's pure reader
(``addon/core/tree_plan.plan_tree``) return a valid object or raise their one-line error, never another exception;
and a manifest they accept renders its first frame or fails in one line.

Two sources of manifests: arbitrary JSON (any value, any nesting, and objects that carry the manifest's tag), and
a real export's manifest with one part, at any depth, removed or replaced by any value or by a value of the
kind a reader meets there (paths, frame numbers, names).
"""

from __future__ import annotations

import copy
import importlib
import importlib.util
import json
import shutil
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from engine import contract as C
from engine.edit.render import load_edits, render_frames
from engine.errors import InputError
from engine.export.manifest import Manifest
from engine.terms.manifest import MANIFEST_KEYS, MANIFEST_TAG, MANIFEST_VERSION
from tests.engine.export.tiny_run import export, make_run
from tests.json_values import JSON_VALUES
from tests.paths import ROOT

JSON = JSON_VALUES
#: Values a reader meets in a manifest, so mutations get past the type checks and reach the code behind them.
PLAUSIBLE = st.one_of(
    st.integers(min_value=-3, max_value=70000),
    st.lists(st.integers(min_value=-2, max_value=8), min_size=0, max_size=5),
    st.sampled_from(
        [
            "",
            ".",
            "..",
            "../..",
            "../../..",
            "/",
            "/tmp/elsewhere.png",
            "passes",
            "atlases/Background.png",
            "../../edits",
            "../../edits/Background.png",
            "../../edits/layout.json",
            "../../checkpoint.pt",
            "../../../clip/frames",
            "atlas.{frame:05d}.exr",
            "{frame.real}",
            "{0}",
            "sequence",
            "movie",
            "linear",
            "sRGB",
            "Background",
            "Foreground",
            "X",
            "V",
        ]
    ),
    st.lists(st.sampled_from(["X", "Y", "Z", "V", ""]), max_size=4),
    st.lists(st.floats(min_value=-2, max_value=2), min_size=4, max_size=4),
)
FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _tree_plan() -> ModuleType:
    """The add-on's ``core.tree_plan``, imported as the extension package (its relative imports need that)."""
    if "neural_atlas" not in sys.modules:
        spec = importlib.util.spec_from_file_location(
            "neural_atlas", ROOT / "__init__.py", submodule_search_locations=[str(ROOT)]
        )
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules["neural_atlas"] = module
        spec.loader.exec_module(module)
    return importlib.import_module("neural_atlas.addon.core.tree_plan")


TREE_PLAN = _tree_plan()
#: What the add-on's reader may raise: its own contract module's ManifestError (the extension package's copy).
ADDON_ERRORS = (TREE_PLAN.PlanError, TREE_PLAN.C.ManifestError)


@pytest.fixture(scope="module")
def real(tmp_path_factory) -> tuple[Path, dict[str, Any]]:
    """A real export's manifest (decoded) and where fuzzed manifests are written: an export folder beside it with
    the same passes and atlases, so every relative path resolves as in the real one."""
    root = tmp_path_factory.mktemp("manifest_fuzz")
    _, _, run = make_run(root)
    manifest = export(run)
    fuzz = manifest.parent.parent / "v999"
    shutil.copytree(manifest.parent, fuzz)
    return fuzz / C.MANIFEST_NAME, json.loads(manifest.read_text())


def _one_line(exc: BaseException) -> None:
    assert "\n" not in str(exc) and str(exc).strip(), repr(exc)


def _read_everything(path: Path) -> None:
    """Every reader on the file at ``path``: a valid result or its one-line error; an accepted manifest renders its
    first frame (in memory) or fails in one line, and plans the add-on's tree or fails in one line."""
    try:
        data = C.load_manifest(str(path))
    except C.ManifestError as exc:
        _one_line(exc)
        with pytest.raises(InputError) as refused:
            Manifest(path)
        _one_line(refused.value)
        return
    manifest = Manifest(path)
    try:
        edits = load_edits(manifest)
        frames = list(render_frames(manifest, edits, [manifest.frames[0]]))
        assert len(frames) == 1 and frames[0][1].shape == (*manifest.resolution[::-1], 3)
    except InputError as exc:
        _one_line(exc)
    try:
        TREE_PLAN.plan_tree(data, str(path))
    except ADDON_ERRORS as exc:
        _one_line(exc)


@FUZZ
@given(
    value=JSON
    | st.dictionaries(st.sampled_from([*MANIFEST_KEYS, "scene", "x"]), JSON, max_size=8).map(
        lambda d: {MANIFEST_TAG: MANIFEST_VERSION, **d}
    )
)
def test_any_json_is_a_manifest_or_one_line(real, value):
    path, _ = real
    path.write_text(json.dumps(value))
    _read_everything(path)


def test_files_that_are_not_json_objects_are_one_line(real):
    path, _ = real
    for text in ("", "{", "[" * 100000 + "]" * 100000, '{"a": NaN}'):
        path.write_text(text)
        _read_everything(path)
    path.write_bytes(b"\xff\xfe not utf-8")
    _read_everything(path)


def _nodes(value: Any, at: tuple = ()) -> list[tuple]:
    """The path (keys and indices) of every part of a decoded manifest, the whole excepted."""
    found = [at] if at else []
    if isinstance(value, dict):
        for key, item in value.items():
            found += _nodes(item, (*at, key))
    elif isinstance(value, list):
        for i, item in enumerate(value):
            found += _nodes(item, (*at, i))
    return found


def _mutated(data: dict[str, Any], at: tuple, replacement: Any, drop: bool) -> dict[str, Any]:
    out = copy.deepcopy(data)
    parent = out
    for step in at[:-1]:
        parent = parent[step]
    if drop:
        del parent[at[-1]]
    else:
        parent[at[-1]] = replacement
    return out


@pytest.mark.slow
@FUZZ
@given(data=st.data())
def test_a_real_manifest_with_one_part_changed_is_read_or_refused_in_one_line(real, data):
    path, manifest = real
    at = data.draw(st.sampled_from(_nodes(manifest)), label="at")
    drop = data.draw(st.booleans(), label="drop")
    replacement = None if drop else data.draw(JSON | PLAUSIBLE, label="replacement")
    path.write_text(json.dumps(_mutated(manifest, at, replacement, drop)))
    _read_everything(path)


def test_the_real_manifest_itself_renders_and_plans(real):
    path, manifest = real
    path.write_text(json.dumps(manifest))
    m = Manifest(path)
    assert len(list(render_frames(m, load_edits(m), [m.frames[0]]))) == 1
    plan = TREE_PLAN.plan_tree(C.load_manifest(str(path)), str(path))
    assert plan.layers == [layer["name"] for layer in manifest["layers"]]
