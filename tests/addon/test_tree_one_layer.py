"""A background-only run (engine.data.scene_analysis: no masks, or no moving object found) exports one layer: the
compositor tree then holds that layer alone — one edit image and Map UV over the plate, no sums."""

from __future__ import annotations

import json

import pytest
from fake_export import make_export
from neural_atlas.addon import tree_plan as P

from engine import contract as C

SCENE = {
    "schema": C.SCHEMA_VERSION,
    "components": "auto",
    "num_layers": 1,
    "layers_source": C.SCENE_LAYERS_NONE,
    "background_motion": C.BG_MOTION_STATIC,
    "flow": True,
    "active_terms": ["rgb", "gradient", "rigidity", "flow"],
    "reasons": {"layers": "background only: no masks were given"},
}


def _one_layer_manifest(tmp_path):
    path = make_export(tmp_path)
    data = json.loads(path.read_text())
    data["layers"] = data["layers"][:1]
    data["scene"] = SCENE
    path.write_text(json.dumps(data))
    return path


def test_one_layer_manifest_plans_a_tree_with_only_the_background(tmp_path):
    path = _one_layer_manifest(tmp_path)
    manifest = C.load_manifest(str(path))  # the add-on's reader accepts the optional "scene"
    plan = P.plan_tree(manifest, str(path))
    assert plan.layers == ["Background"]
    kinds = plan.kinds()
    assert kinds[P.MAP_UV] == 1 and kinds[P.ALPHA_OVER] == 1 and kinds[P.OUTPUT] == 1
    assert P.ADD_COLOR not in kinds and P.ADD_VALUE not in kinds and P.SET_ALPHA not in kinds
    assert P.SEPARATE not in kinds
    names = {n.name for n in plan.nodes}
    assert not any("Foreground" in n for n in names)
    assert {i.name for i in plan.images} == {
        P.PASSES_IMAGE,
        P.edit_image_name("Background"),
        P.atlas_image_name("Background"),
    }
    # the background's Map UV goes straight over the plate
    over = [link for link in plan.links if link.to_node == f"{P.PREFIX}Over" and link.to_socket == "fg"]
    assert len(over) == 1 and over[0].from_node == f"{P.PREFIX}MapUV_Background"


def test_manifest_whose_scene_disagrees_with_its_layers_is_refused(tmp_path):
    path = _one_layer_manifest(tmp_path)
    data = json.loads(path.read_text())
    data["scene"] = {**SCENE, "num_layers": 2}
    path.write_text(json.dumps(data))
    with pytest.raises(C.ManifestError, match="2 layers") as err:
        C.load_manifest(str(path))
    assert str(path) in str(err.value)
