"""Which export a file should show after a refine: ``run_files.realigned_manifest`` from ``edits/aligned.json`` (the
contract's reader, shared with ``engine realign``)."""

from __future__ import annotations

import json

import pytest
from neural_atlas.addon.core import run_files as RF

from engine import contract as C
from engine.terms.export_names import EDITS_ALIGNED, EDITS_ALIGNED_TAG, EDITS_DIR


def _run(tmp_path, *versions: str):
    run = tmp_path / "run"
    for v in versions:
        (run / C.EXPORTS_DIR / v).mkdir(parents=True)
        (run / C.EXPORTS_DIR / v / C.MANIFEST_NAME).write_text("{}")
    (run / EDITS_DIR).mkdir(parents=True)
    return run


def _aligned(run, text: str) -> None:
    (run / EDITS_DIR / EDITS_ALIGNED).write_text(text)


def test_a_refined_run_points_an_older_manifest_at_the_export_its_paint_was_carried_onto(tmp_path):
    run = _run(tmp_path, "v001", "v002")
    old, new = (str(run / C.EXPORTS_DIR / v / C.MANIFEST_NAME) for v in ("v001", "v002"))
    assert RF.realigned_manifest(old) is None  # no record: nothing was re-aligned
    _aligned(run, json.dumps({EDITS_ALIGNED_TAG: 1, "export": "v002"}))
    assert RF.realigned_manifest(old) == new
    assert RF.realigned_manifest(new) is None  # already there
    _aligned(run, json.dumps({EDITS_ALIGNED_TAG: 1, "export": "v007"}))
    assert RF.realigned_manifest(old) is None  # that export is not there
    assert RF.realigned_manifest(str(tmp_path / C.MANIFEST_NAME)) is None  # not in a run's exports


@pytest.mark.parametrize(
    "text",
    ["{", "[]", '{"neural_atlas_aligned": 2, "export": "v002"}', '{"neural_atlas_aligned": 1, "export": 2}',
     '{"neural_atlas_aligned": 1, "export": "../../x"}'],
)  # fmt: skip
def test_a_record_that_is_not_one_changes_nothing_in_blender_and_is_one_line_to_the_engine(tmp_path, text):
    run = _run(tmp_path, "v001", "v002")
    _aligned(run, text)
    assert RF.realigned_manifest(str(run / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME)) is None
    with pytest.raises(ValueError, match="is not an edit-alignment record"):
        C.read_aligned_export(str(run))
