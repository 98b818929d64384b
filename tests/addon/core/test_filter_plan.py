"""The Filter as plan data (no bpy): one setting named as ``engine render --filter``; where Map UV has no bilinear
filter (Blender 4.x) each layer gets the bilinear group of four nearest taps and a Switch the filter flips (the
group's numbers against the engine: tests/addon/test_preview_equals_render.py)."""

from __future__ import annotations

from pathlib import Path

import fake_export as X
import pytest
from neural_atlas.addon.core import preview_plan as V
from neural_atlas.addon.core import tree_plan as P

from engine import contract as C


def _plan(tmp_path: Path, filt: str, taps: bool) -> P.TreePlan:
    mp = X.make_export(tmp_path)
    return P.plan_tree(C.load_manifest(str(mp)), str(mp), filt, bilinear_taps=taps)


@pytest.mark.parametrize("filt", P.FILTERS)
def test_each_layer_switches_between_nearest_and_the_bilinear_group(tmp_path, filt):
    plan = _plan(tmp_path, filt, taps=True)
    assert [g.name for g in plan.groups] == [P.BILINEAR_GROUP]
    nodes = {n.name: n for n in plan.nodes}
    for layer in plan.layers:
        switch = nodes[P.filter_switch_name(layer)]
        assert switch.kind == P.SWITCH and switch.params == {"on": filt == P.FILTER_BILINEAR}
        group = nodes[f"NA_Bilinear_{layer}"]
        assert group.params["group"] == P.BILINEAR_GROUP and group.params["size"] == list(X.ATLAS_SIZES[layer])
        into = {(k.from_node, k.to_socket) for k in plan.links if k.to_node == switch.name}
        assert into == {(f"NA_MapUV_{layer}", "off"), (group.name, "on")}
        assert nodes[f"NA_MapUV_{layer}"].params == {"filter": filt}
        # the blend takes the switch's result, not the Map UV's
        assert not [k for k in plan.links if k.from_node == f"NA_MapUV_{layer}" and k.to_node != switch.name]


def test_without_taps_the_map_uv_filters_itself(tmp_path):
    plan = _plan(tmp_path, P.FILTER_BILINEAR, taps=False)
    assert plan.groups == []
    assert not [n for n in plan.nodes if n.kind in (P.SWITCH, P.GROUP)]


def test_the_filters_are_the_engines_names_and_the_previews():
    assert P.FILTERS == ("bilinear", "nearest") and P.FILTER_DEFAULT == "bilinear"
    assert V.INTERPOLATION == {"bilinear": "Linear", "nearest": "Closest"}
    with pytest.raises(P.PlanError, match="unknown filter 'smooth'"):
        P.plan_tree({}, "", "smooth")


def test_the_bilinear_group_has_four_nearest_taps():
    group = P.bilinear_group()
    taps = [n for n in group.nodes if n.kind == P.MAP_UV]
    assert len(taps) == 4 and all(n.params == {"filter": P.FILTER_NEAREST} for n in taps)
    assert [name for name, _ in group.inputs] == ["Image", "UV", "Width", "Height"]
    names = [n.name for n in group.nodes]
    assert len(names) == len(set(names))
    linked = {k.to_node for k in group.links} | {k.from_node for k in group.links}
    assert linked == set(names)  # every node is wired
