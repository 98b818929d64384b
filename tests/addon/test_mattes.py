"""Matte outputs (bpy 4.5 and 5.0): Render Edited Clip writes each layer's matte and the paint's coverage as float
EXR sequences in the render folder, numbered as the plate; the tree offers them as named Reroutes; every node the
tree makes sits in a labelled frame at the place the plan gives it; and the render itself is unchanged."""

from __future__ import annotations

import json
import os

import numpy as np
import OpenEXR
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from neural_atlas.addon import compat  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402

from engine import contract as C  # noqa: E402
from engine.terms.export_names import alpha_pass, pass_file_name  # noqa: E402

TAG = f"[bpy {bpy.app.version_string}]"
FRAMES = (1001, 1002, 1003)


def _read_matte(path) -> np.ndarray:
    """(H, W) float32 of a single-channel matte EXR, rows top-first; asserts it has the one channel ``V``."""
    with OpenEXR.File(str(path)) as f:
        ch = f.channels()
        assert list(ch) == ["V"], f"{path}: channels {list(ch)}"
        return np.asarray(ch["V"].pixels, np.float32)


def _passes(manifest, frame: int) -> dict[str, np.ndarray]:
    m = json.loads(manifest.read_text())
    with OpenEXR.File(str(manifest.parent / m["passes"]["dir"] / pass_file_name(frame))) as f:
        return {k: np.asarray(v.pixels, np.float64) for k, v in f.channels().items()}


def _paint_coverage(manifest, frame: int) -> np.ndarray:
    """sum_i A_i = sum_i edit_i(uv_i).a * Z_i (nearest), the alpha the tree puts over the plate, (H, W)."""
    m = json.loads(manifest.read_text())
    ch = _passes(manifest, frame)
    total = np.zeros((X.H, X.W))
    for layer in m["layers"]:
        edit = X.read_png_rgba8(C.edit_layer_file(layer["edit_layer"])).astype(np.float64) / 255.0
        uvp = layer["uv_pass"]
        u, v, z = (ch[C.channel_name(uvp, c)] for c in "XYZ")
        total += X.sample(edit, u, v, "nearest")[..., 3] * z
    return total


def _import(blender, manifest) -> None:
    scene = blender.context.scene
    scene.neural_atlas.filter_type = P.FILTER_NEAREST
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}


def test_render_writes_each_layers_matte_and_the_paints_per_plate_frame(blender, tmp_path):
    manifest = X.make_export(tmp_path, frames=FRAMES, foregrounds=2)
    _import(blender, manifest)
    out = tmp_path / "out"
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="exr") == {"FINISHED"}
    layers = X.layer_names(2)
    assert sorted(p.name for p in (out / P.MATTES_DIR).iterdir()) == sorted(
        [*layers, P.PAINT_MATTE, P.FOREGROUNDS_MATTE]
    )
    worst_layer = worst_paint = worst_object = 0.0
    for frame in FRAMES:
        ch = _passes(manifest, frame)
        for layer in layers:
            matte = _read_matte(P.matte_path(str(out), layer, frame))
            alpha = ch[C.channel_name(alpha_pass(layer), "V")]
            worst_layer = max(worst_layer, float(np.abs(matte - alpha).max()))
        # the paint's coverage: sum_i A_i, the alpha the render puts over the plate (plate * (1 - A) + rgb)
        paint = _read_matte(P.matte_path(str(out), P.PAINT_MATTE, frame))
        worst_paint = max(worst_paint, float(np.abs(paint - _paint_coverage(manifest, frame)).max()))
        # the whole object (every foreground layer: the parts Find Parts split it into) as one matte
        whole = _read_matte(P.matte_path(str(out), P.FOREGROUNDS_MATTE, frame))
        alphas = sum(ch[C.channel_name(alpha_pass(layer), "V")] for layer in layers[1:])
        worst_object = max(worst_object, float(np.abs(whole - alphas).max()))
    print(
        f"{TAG} mattes vs alpha passes: max abs err {worst_layer:.1e}; paint matte vs sum A_i: {worst_paint:.1e}; "
        f"foregrounds matte vs their alphas' sum {worst_object:.1e}"
    )
    assert worst_layer <= 1e-6 and worst_paint <= 1e-5 and worst_object <= 1e-6


def test_write_mattes_off_writes_none_and_the_render_is_the_same(blender, tmp_path):
    manifest = X.make_export(tmp_path, frames=FRAMES)
    _import(blender, manifest)
    scene = blender.context.scene
    scene.neural_atlas.write_mattes = False
    out = tmp_path / "out"
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="exr") == {"FINISHED"}
    assert sorted(p.name for p in out.iterdir()) == [f"edit.{f:05d}.exr" for f in FRAMES]
    err = X.render_error(out, manifest, "nearest", frames=FRAMES)
    print(f"{TAG} Write Mattes off: no mattes; render vs the render equation {err:.1e}")
    assert err <= 5e-5


def test_the_tree_groups_every_node_in_a_labelled_frame_where_the_plan_puts_it(blender, tmp_path):
    manifest = X.make_export(tmp_path, frames=FRAMES, foregrounds=2)
    _import(blender, manifest)
    tree = compat.scene_tree(blender.context.scene)
    plan = P.plan_tree(
        C.load_manifest(str(manifest)), str(manifest), P.FILTER_NEAREST, bilinear_taps=compat.BILINEAR_TAPS
    )
    ours = {n.name: n for n in tree.nodes if n.name.startswith(P.PREFIX)}
    assert set(ours) == {spec.name for spec in plan.nodes}
    frames = {n.name: n for n in ours.values() if n.bl_idname == "NodeFrame"}
    labels = sorted(f.label for f in frames.values())
    layers = X.layer_names(2)
    assert labels == sorted(["Plate", "Passes", "Blend", "Mattes", *(f"Layer {n}: edit + Map UV" for n in layers)])
    assert all(f.use_custom_color and f.parent is None for f in frames.values())
    worst = 0.0
    for spec in plan.nodes:
        node = ours[spec.name]
        if spec.kind == P.FRAME:
            continue
        assert node.parent is not None and node.parent.name == spec.parent, spec.name
        # a framed node's location is relative to its frame: where it is drawn is the frame's place plus that
        x, y = node.location
        parent = node.parent
        while parent is not None:
            x, y = x + parent.location[0], y + parent.location[1]
            parent = parent.parent
        worst = max(worst, abs(x - spec.location[0]), abs(y - spec.location[1]))
        if hasattr(node, "location_absolute"):  # 4.4+
            assert tuple(node.location_absolute) == pytest.approx(spec.location)
    assert worst < 1e-3
    # each matte is a named Reroute fed by its source: the layer's alpha pass, or the alpha the tree puts over
    for layer in layers:
        reroute = ours[P.matte_node_name(layer)]
        src = reroute.inputs[0].links[0].from_socket
        assert (src.node.name, src.name) == ("NA_Passes", alpha_pass(layer))
    paint = ours[P.matte_node_name(P.PAINT_MATTE)].inputs[0].links[0].from_socket.node
    alpha_into_over = ours["NA_SetAlpha"].inputs["Alpha"].links[0].from_socket.node
    assert paint == alpha_into_over


def test_frames_and_mattes_leave_the_render_bit_for_bit_the_same(blender, tmp_path):
    """The tree as planned vs the same tree with its frames, Reroutes and File Outputs removed (the tree before
    frames and mattes existed): every pixel of every frame equal."""
    manifest = X.make_export(tmp_path, frames=FRAMES, foregrounds=2)
    _import(blender, manifest)
    scene = blender.context.scene
    with_all = tmp_path / "with"
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(with_all), file_format="exr") == {"FINISHED"}
    tree = compat.scene_tree(scene)
    extra = [n for n in tree.nodes if n.bl_idname in ("NodeFrame", "NodeReroute", "CompositorNodeOutputFile")]
    extra += [n for n in tree.nodes if n.name.startswith(f"{P.PREFIX}AddForeground_")]  # the Foregrounds matte's sum
    assert len(extra) == 7 + 5 + 5 + 1
    for node in extra:
        tree.nodes.remove(node)
    bare = tmp_path / "bare"
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(bare), file_format="exr") == {"FINISHED"}
    assert not (bare / P.MATTES_DIR).exists()
    for frame in FRAMES:
        a = X.read_exr_rgba(with_all / f"edit.{frame:05d}.exr")
        b = X.read_exr_rgba(bare / f"edit.{frame:05d}.exr")
        assert np.array_equal(a, b), frame


def test_a_saved_blend_keeps_the_matte_folders_relative_to_it(blender, tmp_path):
    manifest = X.make_export(tmp_path, frames=FRAMES)
    _import(blender, manifest)
    blender.ops.wm.save_as_mainfile(filepath=str(tmp_path / "shot.blend"))
    out = tmp_path / "renders" / "v1"
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="exr") == {"FINISHED"}
    tree = compat.scene_tree(blender.context.scene)
    node = tree.nodes[P.matte_file_node_name("Foreground")]
    assert compat.file_output_dir(node).replace("\\", "/") == "//renders/v1/mattes/Foreground"
    assert all(os.path.isfile(P.matte_path(str(out), "Foreground", f)) for f in FRAMES)
