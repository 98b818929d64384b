"""Property tests of the run folder's loaders: whatever a hand edit, another tool or a damaged disk leaves in
config.json, clip.json, metrics.json or scene.json, ``RunFolder.read_config/read_clip/read_metrics/read_scene``
return a valid object or raise ``InputError`` with a one-line message naming the file, never another exception.

Two sources of files: arbitrary JSON (any value, any nesting), and the files of a real fit with one part
replaced, removed or added.
"""

from __future__ import annotations

import contextlib
import io
import json
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from engine import cli
from engine import contract as C
from engine.config import check_config
from engine.errors import InputError
from engine.fit.run_folder import ClipRecord, RunFolder
from engine.terms.run_folder import RUN_CLIP, RUN_CONFIG, SCENE_FILE
from tests.json_values import JSON_VALUES
from tests.stability.bad_inputs import SPEC, TINY_FIT
from tests.stability.fitcheck import write_masks, write_sequence

JSON = JSON_VALUES

#: Each run file, with the loader that reads it and what a valid result must let its readers do.
LOADERS: dict[str, tuple[Callable[[RunFolder], Any], Callable[[Any], None]]] = {
    RUN_CONFIG: (RunFolder.read_config, lambda cfg: check_config(cfg)),
    RUN_CLIP: (RunFolder.read_clip, lambda rec: (rec.num_frames, rec.to_dict(), ClipRecord.from_dict(rec.to_dict()))),
    C.RUN_METRICS: (RunFolder.read_metrics, lambda m: (float(m["psnr"]), len(m["alpha_iou"]))),
    SCENE_FILE: (RunFolder.read_scene, lambda scene: (scene.summary(), scene.term_set, scene.to_dict())),
}
NAMES = list(LOADERS)


@pytest.fixture(scope="module")
def real_files(tmp_path_factory) -> dict[str, Any]:
    """The four files of a real (tiny) fit, decoded."""
    from engine.data.synthetic import make_scene

    d = tmp_path_factory.mktemp("fuzz_fit")
    scene = make_scene(SPEC)
    frames = write_sequence(d / "frames", scene.frames)
    masks = write_masks(d / "masks", scene.masks)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert cli.main(["fit", str(frames), "--mask", str(masks), "--out", str(d / "run"), *TINY_FIT]) == 0
    return {name: json.loads((d / "run" / name).read_text()) for name in NAMES}


def _load(name: str, text: str) -> bool:
    """Write ``text`` as run file ``name`` in a fresh folder and load it: a valid object (True), or one line
    (False)."""
    loader, use = LOADERS[name]
    with tempfile.TemporaryDirectory() as tmp:
        run = RunFolder(tmp)
        path = Path(tmp) / name
        path.write_text(text, encoding="utf-8")
        try:
            result = loader(run)
        except InputError as exc:
            message = str(exc)
            assert message.startswith(f"{path}: ") and "\n" not in message and " — " in message, message
            return False
        assert result is not None
        use(result)
        return True


def _dumps(value: Any) -> str:
    return json.dumps(value)  # NaN and Infinity as Python writes them (valid for Python's json.loads)


@settings(max_examples=300, deadline=None)
@given(name=st.sampled_from(NAMES), value=JSON)
def test_property_any_json_loads_or_is_one_line(name, value):
    _load(name, _dumps(value))


@settings(max_examples=100, deadline=None)
@given(name=st.sampled_from(NAMES), text=st.text(max_size=40))
def test_property_any_text_loads_or_is_one_line(name, text):
    _load(name, text)


def _mutate(data: Any, path: list[Any], action: str, value: Any) -> Any:
    """``data`` with the entry at ``path`` replaced by ``value``, removed, or given an extra key."""
    if not path:
        return value if action == "replace" else data
    head, *rest = path
    out = dict(data) if isinstance(data, dict) else list(data)
    if rest:
        out[head] = _mutate(out[head], rest, action, value)
    elif action == "replace":
        out[head] = value
    elif action == "remove":
        del out[head]
    elif isinstance(out, dict):
        out[f"{head}_extra"] = value
    return out


def _paths(data: Any, prefix: list[Any] | None = None) -> list[list[Any]]:
    """Every entry of a decoded file, as the keys and indices that reach it."""
    prefix = prefix or []
    items = data.items() if isinstance(data, dict) else enumerate(data) if isinstance(data, list) else []
    found = []
    for key, value in items:
        found.append([*prefix, key])
        found.extend(_paths(value, [*prefix, key]))
    return found


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_property_a_real_file_with_one_part_changed_loads_or_is_one_line(real_files, data):
    name = data.draw(st.sampled_from(NAMES))
    original = real_files[name]
    path = data.draw(st.sampled_from(_paths(original)))
    action = data.draw(st.sampled_from(["replace", "remove", "extra"]))
    value = data.draw(JSON)
    _load(name, _dumps(_mutate(original, path, action, value)))


def test_the_real_files_load(real_files):
    """Each file a real fit wrote loads (a refusal in one line would pass ``_load`` too: it must not be one)."""
    for name in NAMES:
        assert _load(name, _dumps(real_files[name])), name
