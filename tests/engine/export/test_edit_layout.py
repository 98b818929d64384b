"""``edits/layout.json``: the atlas frame each edit layer was painted in, one declaration (``plan.EditLayout``); a
damaged file is one line naming what is wrong and the fix, before an export reads a box from it."""

from __future__ import annotations

import json

import pytest

from engine.errors import InputError
from engine.export.plan import read_layout
from engine.terms.export_names import EDITS_LAYOUT
from engine.terms.versions import SCHEMA_VERSION

GOOD = {"schema": SCHEMA_VERSION, "layers": {"Foreground": {"atlas_box": [-1, -0.5, 1, 0.5], "atlas_size": [64, 32]}}}


def test_no_layout_is_an_empty_one_and_a_good_one_reads_back(tmp_path):
    assert read_layout(tmp_path) == {"schema": SCHEMA_VERSION, "layers": {}}
    (tmp_path / EDITS_LAYOUT).write_text(json.dumps(GOOD), encoding="utf-8")
    assert read_layout(tmp_path) == GOOD


@pytest.mark.parametrize(
    ("data", "said"),
    [
        ({**GOOD, "layers": {"Foreground": {"atlas_box": "x", "atlas_size": [64, 32]}}}, "'layers' is not a dict"),
        ({**GOOD, "layers": {"Foreground": {"atlas_box": [0, 0, 1, 1]}}}, "has no 'layers.Foreground.atlas_size'"),
        ({**GOOD, "layers": []}, "'layers' is not a dict of atlas frames"),
        ({**GOOD, "schema": 99}, "edit layout has an unknown schema"),
        ([1, 2], "edit layout has an unknown schema"),
        ({**GOOD, "boxes": {}}, "edit layout has an unknown key 'boxes'"),
    ],
)
def test_a_damaged_layout_is_one_line(tmp_path, data, said):
    (tmp_path / EDITS_LAYOUT).write_text(json.dumps(data), encoding="utf-8")
    with pytest.raises(InputError) as info:
        read_layout(tmp_path)
    text = str(info.value)
    assert said in text and "restore it" in text and "\n" not in text
