"""The live preview as plain data (``core.preview_plan``) and the EXR pass splitter (``core.exr_passes``): the
material's equation, the image sequences' frame mapping, the camera framing, the 8-bit conversion and the split UV
files, bit for bit."""

from __future__ import annotations

import array
import json
from collections import Counter
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from fake_export import FRAMES, make_export, read_exr_rgba, write_exr
from neural_atlas.addon.core import exr_passes, float_edit
from neural_atlas.addon.core import preview_plan as V
from neural_atlas.addon.core import tree_plan as P

from engine import contract as C
from engine.terms.export_names import uv_pass


def _plan(tmp_path, filt=P.FILTER_BILINEAR, frame_paint=False, foregrounds=1):
    mp = make_export(tmp_path, foregrounds=foregrounds)
    manifest = C.load_manifest(str(mp))
    tree = P.plan_tree(manifest, str(mp), filt)
    return mp, V.plan_preview(tree, manifest, str(mp), filt, frame_paint)


def _evaluate(plan: V.PreviewPlan, values: dict[str, dict[str, float]]) -> float:
    """Evaluate the plan's graph for one pixel, one channel: ``values`` gives each image node's Color/Alpha/X/Y/Z."""
    nodes = {n.name: n for n in plan.nodes}
    incoming: dict[tuple[str, str | int], tuple[str, str | int]] = {
        (k.to_node, k.to_socket): (k.from_node, k.from_socket) for k in plan.links
    }

    def inp(name: str, socket: str | int, default: float = 0.0) -> float:
        src = incoming.get((name, socket))
        if src is None:
            return float(nodes[name].params.get("defaults", {}).get(socket, default))
        return out(*src)

    def out(name: str, socket: str | int) -> float:
        node = nodes[name]
        if node.kind == V.TEX_IMAGE:
            return values[name][str(socket)]
        if node.kind == V.SEPARATE_XYZ:
            return values[incoming[(name, "Vector")][0]]["XYZ"["XYZ".index(str(socket))]]
        if node.kind == V.MATH:
            a, b = inp(name, 0), inp(name, 1)
            return {"MULTIPLY": a * b, "ADD": a + b, "SUBTRACT": a - b}[node.params["operation"]]
        if node.kind == V.VECTOR_MATH:
            if node.params["operation"] == "SCALE":
                return inp(name, 0) * inp(name, "Scale")
            return inp(name, 0) + inp(name, 1)
        if node.kind == V.MIX:
            f = inp(name, "Factor")
            return inp(name, "A") * (1 - f) + inp(name, "B") * f
        if node.kind == V.EMISSION:
            return inp(name, "Color")
        if node.kind == V.VALUE:  # a driven value: the test's, else the node's own
            return float(values.get(name, {}).get("Value", node.params["value"]))
        raise AssertionError(node.kind)

    return out("Emission", "Emission")


def test_the_material_is_the_render_equation(tmp_path):
    """out = plate * (1 - sum A_i) + sum rgb_i with A_i = alpha_i * Z_i, rgb_i = premultiplied colour_i * Z_i."""
    _, plan = _plan(tmp_path, foregrounds=2)
    assert plan.layers == ["Background", "Foreground1", "Foreground2"]
    rng = np.random.default_rng(0)
    for _ in range(20):
        plate = rng.random()
        vals: dict[str, dict[str, float]] = {"Plate": {"Color": plate}}
        want_a = want_rgb = 0.0
        for layer in plan.layers:
            z, a = rng.random() / 3, rng.random()
            pre = rng.random() * a
            vals[f"UV_{layer}"] = {"X": rng.random(), "Y": rng.random(), "Z": z}
            vals[f"Edit_{layer}"] = {"Color": pre, "Alpha": a}
            want_a += a * z
            want_rgb += pre * z
        assert _evaluate(plan, vals) == pytest.approx(plate * (1 - want_a) + want_rgb, abs=1e-12)
    kinds = Counter(n.kind for n in plan.nodes)
    assert kinds[V.TEX_IMAGE] == 1 + 2 * 3 and kinds[V.OUTPUT] == 1 and V.FRAME_PAINT_NODE not in kinds


def test_outside_the_exported_frames_the_plate_shows_alone(tmp_path):
    """The layers' sums are gated by a value driven by the scene frame: 1 on the exported frames, 0 elsewhere (where
    the passes would hold their last frame), so the preview is the plate there; the panel's line says so."""
    _, plan = _plan(tmp_path)
    first, last = plan.export_frames
    node = next(n for n in plan.nodes if n.name == V.IN_EXPORT_NODE)
    for frame, want in ((first - 1, 0.0), (first, 1.0), (last, 1.0), (last + 1, 0.0)):
        assert float(eval(node.params["driver"], {"frame": frame})) == want  # as Blender's simple expression does
    vals: dict[str, dict[str, float]] = {"Plate": {"Color": 0.25}}
    for layer in plan.layers:
        vals[f"UV_{layer}"] = {"X": 0.0, "Y": 0.0, "Z": 1.0}
        vals[f"Edit_{layer}"] = {"Color": 0.5, "Alpha": 0.5}
    assert _evaluate(plan, vals) != pytest.approx(0.25)
    assert _evaluate(plan, {**vals, V.IN_EXPORT_NODE: {"Value": 0.0}}) == pytest.approx(0.25)
    assert V.outside_export(first, plan.export_frames) is None
    assert V.outside_export(last + 2, (first, last)) == (
        f"Frame {last + 2} is outside the export ({first}-{last}): the preview shows the plate without paint"
    )
    assert V.outside_export(first, None) is None


def test_frame_paint_lies_over_the_composite_by_its_alpha(tmp_path):
    _, plan = _plan(tmp_path, frame_paint=True)
    node = next(n for n in plan.nodes if n.name == V.FRAME_PAINT_NODE)
    assert node.params["image"] == P.FRAME_PAINT_IMAGE
    vals = {"Plate": {"Color": 0.25}, V.FRAME_PAINT_NODE: {"Color": 0.9, "Alpha": 0.5}}
    for layer in plan.layers:
        vals[f"UV_{layer}"] = {"X": 0.0, "Y": 0.0, "Z": 0.0}
        vals[f"Edit_{layer}"] = {"Color": 0.0, "Alpha": 0.0}
    assert _evaluate(plan, vals) == pytest.approx(0.25 * 0.5 + 0.9 * 0.5)
    # the frame paint is sampled at the plane's own UVs (no vector link): it can be painted on the plane
    assert not [k for k in plan.links if k.to_node == V.FRAME_PAINT_NODE]


@pytest.mark.parametrize(("filt", "interp"), [(P.FILTER_BILINEAR, "Linear"), (P.FILTER_NEAREST, "Closest")])
def test_edit_images_are_the_float_twins_with_the_panels_filter(tmp_path, filt, interp):
    _, plan = _plan(tmp_path, filt)
    for layer in plan.layers:
        edit = next(n for n in plan.nodes if n.name == f"Edit_{layer}")
        assert edit.params == {"image": V.mirror_image_name(layer), "interpolation": interp}
        assert plan.mirrors[layer] == V.mirror_image_name(layer)
    closest = {n.name for n in plan.nodes if n.kind == V.TEX_IMAGE and n.params["interpolation"] == "Closest"}
    assert {"Plate", "UV_Background", "UV_Foreground"} <= closest


def test_sequences_follow_the_scene_frame(tmp_path):
    """Scene frame F shows plate file F and UV file F (Blender: file = F - frame_start + 1 + frame_offset)."""
    _, plan = _plan(tmp_path)
    images = {i.name: i for i in plan.images}
    for name in (V.PREVIEW_PLATE_IMAGE, V.uv_image_name("Foreground")):
        img = images[name]
        assert img.source == "SEQUENCE" and img.user is not None
        for f in FRAMES:
            assert f - img.user.frame_start + 1 + img.user.frame_offset == f
        assert img.user.frame_duration == len(FRAMES)
    assert images[V.uv_image_name("Foreground")].colorspace == "Non-Color"
    # a shot numbered plate.1011.png at scene frame 1011, a file numbered unlike its frame keeps the file's number
    assert V.sequence_user(1011, 1011, 12) == V.SequenceUser(1011, 1010, 12)
    assert V.file_number("/a/shot_v2.0042.exr") == 42 and V.file_number("plate.png") is None


def test_framing_maps_render_pixel_centres_to_plate_pixel_centres():
    fit = V.framing((1920, 1080), (1.0, 1.0))
    w, h = fit.size
    assert (w / h, fit.ortho_scale, fit.shift) == (pytest.approx(16 / 9), pytest.approx(w), (0.0, 0.0))
    assert fit.origin[0] + w < 0.0  # left of the canvases at x >= 0
    assert fit.camera_location[:2] == pytest.approx((fit.origin[0] + w / 2, fit.origin[1] + h / 2))
    anamorphic = V.framing((1000, 800), (2.0, 1.0))  # 2:1 pixels: shown 2000 x 800
    assert anamorphic.size[0] / anamorphic.size[1] == pytest.approx(2.5)
    portrait = V.framing((400, 800))
    assert portrait.ortho_scale == pytest.approx(portrait.size[1])  # the longer side
    assert V.pixel_centre_uv(0, 0, (40, 24)) == (0.5 / 40, 0.5 / 24)


def test_an_8bit_edit_converts_as_float_edit_does():
    rng = np.random.default_rng(1)
    px = (rng.integers(0, 256, 4 * 300) / 255.0).astype(np.float32)
    want = float_edit.straight_srgb_to_premultiplied_linear(array.array("f", px.tolist()))
    np.testing.assert_allclose(V.straight_srgb_to_premultiplied(px), np.array(want, np.float32), rtol=0, atol=1e-7)


def test_uv_passes_split_bit_for_bit(tmp_path):
    mp, plan = _plan(tmp_path)
    split = next(s for s in plan.splits if s.layer == "Foreground")
    assert split.channels == tuple(C.channel_name(uv_pass("Foreground"), c) for c in "XYZ")
    pass_file, rgb_file = split.files[1]
    assert Path(rgb_file) == mp.parent / V.PREVIEW_UV_DIR / "Foreground" / f"uv.{FRAMES[1]:05d}.exr"
    ch = exr_passes.read_channels(pass_file, split.channels)
    exr_passes.write_rgb(rgb_file, *(ch[c] for c in split.channels))
    with OpenEXR.File(pass_file) as f:
        want = {k: np.asarray(v.pixels, np.float32) for k, v in f.channels().items()}
    got = read_exr_rgba(Path(rgb_file))
    for i, c in enumerate(split.channels):
        assert np.array_equal(got[..., i], want[c]) and np.array_equal(ch[c], want[c])


@pytest.mark.parametrize("shape", [(1, 1), (17, 33), (40, 7)])
def test_exr_reader_reads_what_openexr_writes(tmp_path, shape):
    rng = np.random.default_rng(2)
    chans = {"A.b.X": rng.random(shape, np.float32), "Z": rng.standard_normal(shape).astype(np.float32)}
    write_exr(tmp_path / "x.exr", chans)
    got = exr_passes.read_channels(str(tmp_path / "x.exr"))
    assert set(got) == set(chans) and all(np.array_equal(got[k], v) for k, v in chans.items())
    with pytest.raises(exr_passes.ExrError, match="has no channel"):
        exr_passes.read_channels(str(tmp_path / "x.exr"), ("Nope",))
    (tmp_path / "bad.exr").write_bytes(b"not an exr at all")
    with pytest.raises(exr_passes.ExrError, match="not an OpenEXR file"):
        exr_passes.read_channels(str(tmp_path / "bad.exr"))


def test_a_movie_plate_shows_its_frame_numbered_as_the_scene_frame(tmp_path):
    """A movie fitted with --start-frame 1001: scene frame F shows its frame numbered F, the (F - 1000)th of the
    file (an Image Texture counts a movie's frames from 1)."""
    mp = make_export(tmp_path, frames=(1001, 1002, 1003))
    data = json.loads(mp.read_text())
    movie = tmp_path / "plate.mov"
    movie.write_bytes(b"\0")  # the plan only checks that the file is there
    data["clip"].update(kind="movie", source=str(movie), frame_files=[], start_frame=1001)
    mp.write_text(json.dumps(data))
    manifest = C.load_manifest(str(mp))
    tree = P.plan_tree(manifest, str(mp))
    plate = V.plan_preview(tree, manifest, str(mp)).images[0]
    assert (plate.name, plate.source, plate.filepath) == (V.PREVIEW_PLATE_IMAGE, "MOVIE", str(movie))
    assert plate.user is not None
    for f in (1001, 1002, 1003):
        assert f - plate.user.frame_start + 1 + plate.user.frame_offset == f - 1000
    assert plate.user.frame_duration == 3
