"""The compositor tree as plain data (``core.tree_plan``): topology, the layers' images, float edit layers, and
manifest paths."""

from __future__ import annotations

import json
import os
from collections import Counter
from pathlib import Path

import pytest
from fake_export import FRAMES, make_export
from neural_atlas.addon.core import tree_plan as P

from engine import contract as C
from engine.terms.export_names import alpha_pass, pass_file_name
from engine.terms.run_folder import BG_MOTION_STATIC, SCENE_LAYERS_NONE
from engine.terms.versions import SCHEMA_VERSION


def kinds(plan: P.TreePlan) -> dict[str, int]:
    """How many nodes of each kind the plan has."""
    return dict(Counter(n.kind for n in plan.nodes))


def test_plan_topology_two_layers(tmp_path):
    mp = make_export(tmp_path)
    plan = P.plan_tree(C.load_manifest(str(mp)), str(mp), P.FILTER_NEAREST)
    assert kinds(plan) == {
        P.PLATE: 1,
        P.IMAGE: 3,  # passes + one edit layer per layer
        P.MAP_UV: 2,
        P.SEPARATE: 2,
        P.ADD_COLOR: 1,
        P.ADD_VALUE: 1,
        P.SET_ALPHA: 1,
        P.ALPHA_OVER: 1,
        P.OUTPUT: 1,
        P.VIEWER: 1,  # the Compositor's backdrop shows the composite
        P.FRAME: 6,  # Plate, Passes, one per layer, Blend, Mattes
        P.REROUTE: 3,  # a matte per layer + the paint's
        P.FILE_OUTPUT: 3,
    }
    assert all(n.name.startswith(P.PREFIX) for n in plan.nodes)
    assert all(i.name.startswith(P.PREFIX) for i in plan.images)
    links = {(lk.from_node, lk.from_socket, lk.to_node, lk.to_socket) for lk in plan.links}
    assert ("NA_Passes", "UVForeground", "NA_MapUV_Foreground", "uv") in links
    assert ("NA_Plate", "image", "NA_Over", "bg") in links
    assert ("NA_SetAlpha", "image", "NA_Over", "fg") in links
    assert ("NA_Over", "image", P.VIEWER_NODE, "image") in links
    assert ("NA_AddColor_1", "result", "NA_SetAlpha", "image") in links
    assert ("NA_AddAlpha_1", "value", "NA_SetAlpha", "alpha") in links
    assert (plan.frame_start, plan.frame_end) == (FRAMES[0], FRAMES[-1])
    assert plan.plate.sequence and plan.plate.frame_start == FRAMES[0]
    passes = next(i for i in plan.images if i.name == P.PASSES_IMAGE)
    assert passes.colorspace == "Non-Color" and passes.filepath.endswith(pass_file_name(FRAMES[0]))
    assert {i.colorspace for i in plan.images if i.name.startswith("NA_Edit_")} == {"sRGB"}


def test_plan_three_layers_sums_every_layer(tmp_path):
    mp = make_export(tmp_path)
    m = C.load_manifest(str(mp))
    extra = dict(m["layers"][1], name="Foreground2", index=2, uv_pass="UVForeground2")
    m["layers"].append(extra)
    plan = P.plan_tree(m, str(mp))
    k = kinds(plan)
    assert (k[P.MAP_UV], k[P.ADD_COLOR], k[P.ADD_VALUE], k[P.SEPARATE]) == (3, 2, 2 + 1, 3)  # + the Foregrounds sum
    assert plan.mattes == ["Background", "Foreground", "Foreground2", P.PAINT_MATTE, P.FOREGROUNDS_MATTE]
    assert P.plan_tree(C.load_manifest(str(mp)), str(mp)).mattes == ["Background", "Foreground", P.PAINT_MATTE]


def test_float_edit_layer_wins_over_the_png_when_both_exist(tmp_path):
    """contract.edit_layer_file: the export makes <Layer>.png; an <Layer>.exr beside it is used instead."""
    mp = make_export(tmp_path)
    m = C.load_manifest(str(mp))
    png = C.resolve_manifest_path(str(mp), m["layers"][1]["edit_layer"])
    assert png.endswith(".png") and C.edit_layer_file(png) == png
    spec = next(i for i in P.plan_tree(m, str(mp)).images if i.name == P.edit_image_name("Foreground"))
    assert (spec.filepath, spec.colorspace) == (png, "sRGB")
    exr = png[: -len(".png")] + C.EDIT_LAYER_FLOAT_EXT
    Path(exr).write_bytes(b"")  # existence is the rule; the content is read by Blender / the engine
    assert C.edit_layer_file(png) == exr
    assert C.edit_layer_file(exr) == exr and C.edit_layer_file("elsewhere/paint.png") == "elsewhere/paint.png"
    spec = next(i for i in P.plan_tree(m, str(mp)).images if i.name == P.edit_image_name("Foreground"))
    assert (spec.filepath, spec.colorspace) == (exr, "Non-Color")
    # an explicit edit override is used as given
    spec = next(i for i in P.plan_tree(m, str(mp), edits={"Foreground": png}).images if i.name.endswith("Foreground"))
    assert spec.filepath == png


def test_plan_from_a_three_layer_export(tmp_path):
    mp = make_export(tmp_path, foregrounds=2)
    m = C.load_manifest(str(mp))
    plan = P.plan_tree(m, str(mp), P.FILTER_NEAREST)
    assert plan.layers == ["Background", "Foreground1", "Foreground2"]
    k = kinds(plan)
    # ADD_VALUE: the paint's alpha sum (2) and the Foregrounds matte's (1)
    assert (k[P.IMAGE], k[P.MAP_UV], k[P.SEPARATE], k[P.ADD_COLOR], k[P.ADD_VALUE]) == (4, 3, 3, 2, 3)
    assert (k[P.SET_ALPHA], k[P.ALPHA_OVER], k[P.OUTPUT], k[P.PLATE]) == (1, 1, 1, 1)
    links = {(lk.from_node, lk.from_socket, lk.to_node, lk.to_socket) for lk in plan.links}
    for name in plan.layers:
        assert ("NA_Passes", f"UV{name}", f"NA_MapUV_{name}", "uv") in links
        assert any(i.name == f"NA_Edit_{name}" for i in plan.images)
    # every Map UV output reaches the colour sum exactly once, every alpha the alpha sum exactly once
    adds = [lk for lk in plan.links if lk.to_node.startswith("NA_AddColor_")]
    assert {lk.from_node for lk in adds if lk.from_node.startswith("NA_MapUV_")} == {
        f"NA_MapUV_{n}" for n in plan.layers
    }


def test_plan_rejects_gaps_and_unknown_edits(tmp_path):
    mp = make_export(tmp_path)
    m = C.load_manifest(str(mp))
    with pytest.raises(P.PlanError, match="unknown layer"):
        P.plan_tree(m, str(mp), edits={"Nope": "x.png"})
    m["passes"]["frames"] = [3, 5]
    with pytest.raises(P.PlanError, match="gaps"):
        P.plan_tree(m, str(mp))


def test_manifest_paths_resolve_relative_to_the_manifest(tmp_path):
    mp = make_export(tmp_path)
    data = json.loads(mp.read_text())
    plan = P.plan_tree(data, str(mp))
    atlas = next(i for i in plan.images if i.name == "NA_Atlas_Foreground")
    assert atlas.filepath == str(mp.parent / "atlases" / "Foreground.png")


def test_manifest_paths_absolute_stay_relative_normalise(tmp_path):
    """One rule for the add-on and the engine (``contract.resolve_manifest_path``)."""
    mp = str(tmp_path / "run" / "exports" / "v001" / C.MANIFEST_NAME)
    assert C.resolve_manifest_path(mp, "/elsewhere/paint.png") == "/elsewhere/paint.png"
    edit = C.resolve_manifest_path(mp, "../../edits/Foreground.png")
    assert edit == str(tmp_path / "run" / "edits" / "Foreground.png")
    assert C.resolve_manifest_path(mp, "./passes") == str(Path(mp).parent / "passes")


# --- one layer ------------------------------------------------------------------------------------------------
# A background-only run (engine.data.scene_analysis: no masks, or no moving object found) exports one layer: the
# compositor tree then holds that layer alone — one edit image and Map UV over the plate, no sums.
SCENE = {
    "schema": SCHEMA_VERSION,
    "components": "auto",
    "num_layers": 1,
    "layers_source": SCENE_LAYERS_NONE,
    "background_motion": BG_MOTION_STATIC,
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
    counts = kinds(plan)
    assert counts[P.MAP_UV] == 1 and counts[P.ALPHA_OVER] == 1 and counts[P.OUTPUT] == 1
    assert P.ADD_COLOR not in counts and P.ADD_VALUE not in counts and P.SET_ALPHA not in counts
    assert counts[P.SEPARATE] == 1  # only for the paint's matte: the alpha of the one Map UV
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


# --- what a manifest may make the add-on write, and read ----------------------------------------------------------
def _with_edit_layer(tmp_path: Path, edit_layer: str) -> Path:
    path = make_export(tmp_path)
    data = json.loads(path.read_text())
    data["layers"][1]["edit_layer"] = edit_layer
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize(
    "edit_layer",
    ["{tmp}/elsewhere/evil.png", "../../../elsewhere/evil.png", "../../checkpoint.pt", "../../exports/v000/x.png"],
    ids=["absolute_outside", "climbs_out", "onto_the_checkpoint", "into_another_export"],
)
def test_a_manifest_cannot_make_the_addon_write_outside_the_edits(tmp_path, edit_layer):
    """plan_tree refuses an edit layer outside the run folder's edits/ (and this export) in one line, naming the
    path; the float edit layer's path (Float Edit Layers' target) is refused the same way; nothing is created.
    (The add-on raises its own copy of the contract's ManifestError: the extension package's.)"""
    path = _with_edit_layer(tmp_path, edit_layer.format(tmp=tmp_path))
    manifest = C.load_manifest(str(path))
    with pytest.raises(P.C.ManifestError) as err:
        P.plan_tree(manifest, str(path))
    message = str(err.value)
    assert "\n" not in message and Path(edit_layer).name in message and message.startswith(str(path)), message
    with pytest.raises(P.C.ManifestError):
        P.float_edit_path(str(path), manifest["layers"][1])
    assert not (tmp_path / "elsewhere").exists() and not (tmp_path / "run" / "exports" / "v000").exists()


def test_a_float_edit_layer_linked_out_of_the_run_is_refused(tmp_path):
    """<Layer>.exr beside the PNG is a symlink to a file outside the run: the plan (what Save Edits writes) refuses
    it rather than write through the link."""
    path = make_export(tmp_path)
    outside = tmp_path / "elsewhere.exr"
    outside.write_bytes(b"the artist's other file")
    (tmp_path / "run" / "edits" / "Foreground.exr").symlink_to(outside)
    with pytest.raises(P.C.ManifestError, match=r"Foreground\.exr"):
        P.plan_tree(C.load_manifest(str(path)), str(path))
    assert outside.read_bytes() == b"the artist's other file"


def test_a_missing_plate_frame_is_one_line_naming_it(tmp_path):
    path = make_export(tmp_path)
    first = tmp_path / "plate" / f"{FRAMES[0]:05d}.png"
    first.unlink()
    with pytest.raises(P.PlanError) as err:
        P.plan_tree(C.load_manifest(str(path)), str(path))
    assert str(err.value).startswith(f"{first}: plate frame does not exist — ") and "\n" not in str(err.value)


def test_relative_plate_paths_resolve_from_the_manifest_wherever_the_run_is(tmp_path):
    """A manifest whose plate paths are relative (as export writes them) plans the same tree after the run folder
    and its plate moved together."""
    path = make_export(tmp_path / "a")
    data = json.loads(path.read_text())
    folder = path.parent
    data["clip"]["source"] = os.path.relpath(data["clip"]["source"], folder)
    data["clip"]["frame_files"] = [os.path.relpath(f, folder) for f in data["clip"]["frame_files"]]
    for layer in data["layers"]:
        layer["edit_layer"] = os.path.relpath(layer["edit_layer"], folder)
    path.write_text(json.dumps(data))
    before = P.plan_tree(C.load_manifest(str(path)), str(path))
    (tmp_path / "a").rename(tmp_path / "b")
    moved = tmp_path / "b" / path.relative_to(tmp_path / "a")
    after = P.plan_tree(C.load_manifest(str(moved)), str(moved))
    assert after.plate.filepath == before.plate.filepath.replace(str(tmp_path / "a"), str(tmp_path / "b"))
    assert [i.filepath for i in after.images] == [
        i.filepath.replace(str(tmp_path / "a"), str(tmp_path / "b")) for i in before.images
    ]


def test_plan_numbers_the_scene_as_the_plate_with_its_rate_and_aspect(tmp_path):
    """Frames 1001..1003 at 24000/1001 with 2:1 pixels: the scene runs 1001-1003 (every imported frame), the plate
    and the passes start at 1001, the rate is exact and the pixels anamorphic."""
    timing = {"rate": [24000, 1001], "fps": 24000 / 1001, "pixel_aspect": 2.0, "timecode": "01:00:00:00"}
    mp = make_export(tmp_path, frames=(1001, 1002, 1003), clip_fields=timing)
    plan = P.plan_tree(C.load_manifest(str(mp)), str(mp), P.FILTER_NEAREST)
    assert (plan.frame_start, plan.frame_end) == (1001, 1003)
    assert (plan.plate.frame_start, plan.plate.frame_duration) == (1001, 3)
    passes = next(i for i in plan.images if i.name == P.PASSES_IMAGE)
    assert (passes.frame_start, passes.frame_duration) == (1001, 3) and passes.filepath.endswith("atlas.01001.exr")
    assert plan.fps == (24000, 1001.0) and plan.pixel_aspect == (2.0, 1.0)


def test_plan_of_a_manifest_without_timing_keeps_square_pixels_and_its_float_rate(tmp_path):
    mp = make_export(tmp_path)  # fps 25.0, no rate, pixel_aspect or timecode: a manifest from before they were kept
    plan = P.plan_tree(C.load_manifest(str(mp)), str(mp), P.FILTER_NEAREST)
    assert plan.fps == (25, 1.0) and plan.pixel_aspect == (1.0, 1.0)
    data = json.loads(mp.read_text())
    data["clip"]["fps"] = None
    mp.write_text(json.dumps(data))
    assert P.plan_tree(C.load_manifest(str(mp)), str(mp), P.FILTER_NEAREST).fps is None


def test_plan_starts_a_movie_plate_at_its_first_frame_number(tmp_path):
    """A movie fitted with --start-frame 1001: its first frame shows at scene frame 1001 (0 without it)."""
    mp = make_export(tmp_path, frames=(1001, 1002, 1003))
    data = json.loads(mp.read_text())
    movie = tmp_path / "plate.mov"
    movie.write_bytes(b"\0")  # the plan only checks that the file is there
    data["clip"].update(kind="movie", source=str(movie), frame_files=[], start_frame=1001)
    mp.write_text(json.dumps(data))
    plan = P.plan_tree(C.load_manifest(str(mp)), str(mp), P.FILTER_NEAREST)
    assert not plan.plate.sequence and plan.plate.frame_start == 1001 and plan.frame_start == 1001
    del data["clip"]["start_frame"]
    mp.write_text(json.dumps(data))
    assert P.plan_tree(C.load_manifest(str(mp)), str(mp), P.FILTER_NEAREST).plate.frame_start == 0


def test_every_node_sits_in_a_labelled_frame(tmp_path):
    mp = make_export(tmp_path)
    plan = P.plan_tree(C.load_manifest(str(mp)), str(mp), P.FILTER_NEAREST)
    frames = {n.name: n for n in plan.nodes if n.kind == P.FRAME}
    assert sorted(f.params["label"] for f in frames.values()) == [
        "Blend",
        "Layer Background: edit + Map UV",
        "Layer Foreground: edit + Map UV",
        "Mattes",
        "Passes",
        "Plate",
    ]
    assert all(not f.parent and len(f.params["color"]) == 3 for f in frames.values())
    parent = {n.name: frames[n.parent].params["label"] for n in plan.nodes if n.kind != P.FRAME}
    assert len(parent) == len(plan.nodes) - len(frames)  # every other node has a frame
    assert parent["NA_Plate"] == "Plate" and parent["NA_Passes"] == "Passes"
    assert parent["NA_Edit_Foreground"] == parent["NA_MapUV_Foreground"] == "Layer Foreground: edit + Map UV"
    assert {parent[n] for n in ("NA_Alpha_Background", "NA_AddColor_1", "NA_SetAlpha", "NA_Over", "NA_Output")} == {
        "Blend"
    }
    assert {parent[P.matte_node_name(m)] for m in plan.mattes} == {"Mattes"}
    # the frames do not overlap: each frame's nodes lie left of, or below, the next frame's
    spans: dict[str, list[tuple[float, float]]] = {}
    for n in plan.nodes:
        if n.parent:
            spans.setdefault(n.parent, []).append(n.location)
    xs = {f: (min(x for x, _ in locs), max(x for x, _ in locs)) for f, locs in spans.items()}
    layer_frames = [f for f in frames if "Layer" in f]
    blend, mattes = P.frame_node_name(P.FRAME_BLEND), P.frame_node_name(P.FRAME_MATTES)
    node_width = 200.0
    assert all(xs[f][1] + node_width <= xs[blend][0] for f in layer_frames)
    assert xs[blend][1] + node_width <= xs[mattes][0]


def test_mattes_are_each_layers_alpha_pass_and_the_paints_coverage(tmp_path):
    mp = make_export(tmp_path)
    plan = P.plan_tree(C.load_manifest(str(mp)), str(mp))
    assert plan.mattes == ["Background", "Foreground", P.PAINT_MATTE]
    links = {(lk.from_node, lk.from_socket, lk.to_node, lk.to_socket) for lk in plan.links}
    for layer in ("Background", "Foreground"):
        assert ("NA_Passes", alpha_pass(layer), P.matte_node_name(layer), "in") in links
    # the paint's matte is the alpha the tree puts over the plate
    assert ("NA_AddAlpha_1", "value", P.matte_node_name(P.PAINT_MATTE), "in") in links
    assert ("NA_AddAlpha_1", "value", "NA_SetAlpha", "alpha") in links
    for matte in plan.mattes:
        assert (P.matte_node_name(matte), "out", P.matte_file_node_name(matte), "image") in links
        assert P.matte_of_file_node(P.matte_file_node_name(matte)) == matte
    assert P.matte_of_file_node("NA_MatteFile_") is None and P.matte_of_file_node("NA_Matte_Background") is None
    assert P.matte_path("/r", "Foreground", 1012) == os.path.join("/r", "mattes", "Foreground", "matte.01012.exr")
