"""A record the engine keeps in memory and the model that checks its file declare the same fields: a field added
to one and not the other fails here, not in a user's run folder (``clip.json``: ``ClipRecord`` and ``ClipFile``;
``scene.json``: ``SceneAnalysis`` and ``SceneFile``, and the part of it a manifest carries)."""

from __future__ import annotations

import dataclasses

from engine.data.scene_analysis import SceneAnalysis
from engine.export import manifest_schema as S
from engine.fit.run_files import ClipFile, SceneFile
from engine.fit.run_folder import ClipRecord
from engine.terms.run_folder import SCENE_FIELDS, SCENE_KEYS


def _required(model) -> set[str]:  # type: ignore[no-untyped-def]
    return {name for name, f in model.model_fields.items() if f.is_required()}


def test_the_clip_record_and_its_files_model_name_the_same_fields():
    record = {f.name: f for f in dataclasses.fields(ClipRecord)}
    assert set(record) == set(ClipFile.model_fields)
    # a field the file may lack has a default in memory too (a record written before the field was kept)
    optional = set(ClipFile.model_fields) - _required(ClipFile)
    lacking = {
        name
        for name in optional
        if record[name].default is dataclasses.MISSING and record[name].default_factory is dataclasses.MISSING
    }
    assert not lacking, f"ClipRecord has no default for {sorted(lacking)}, which clip.json may lack"


def test_the_scene_analysis_its_files_model_and_the_manifests_part_agree():
    assert {f.name for f in dataclasses.fields(SceneAnalysis)} == set(SceneFile.model_fields)
    assert set(SCENE_KEYS) <= set(SceneFile.model_fields)  # the manifest carries a part of it
    assert set(S.Scene.model_fields) == set(SCENE_KEYS) == set(SCENE_FIELDS)
    written = SceneAnalysis().to_dict()
    assert set(written) - {"schema"} == set(SceneFile.model_fields)
