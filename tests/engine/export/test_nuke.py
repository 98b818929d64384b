"""Passes for Nuke, Flame and Natron, and the Nuke script of the edit.

Nuke cannot run here: the script is parsed back (tests/engine/export/nk_script.py) and checked for its node
classes, knobs, input wiring, the files it reads and the channels it names (as OpenImageIO lists them and as
Nuke's EXR reader renames them), and a numpy model of its nodes computes the same frames as `engine render`.
Blender's view of the same pass files (its Image node's layers and sockets) is checked with bpy 4.5 and 5.0.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from engine import contract as C
from engine.export.manifest import Manifest
from engine.export.nuke import (
    NukeScriptError,
    _comment,
    file_knob_path,
    nuke_channel_name,
    nuke_script,
    quote,
    sequence_pattern,
)
from engine.io.images import read_exr, write_exr, write_png
from engine.terms.cli import VERB_NUKE, VERB_RENDER
from engine.terms.export_names import EDIT_LAYER_EXT, EDITS_DIR, NUKE_SCRIPT_NAME
from engine.terms.versions import ENGINE_VERSION
from tests.engine.export import nk_script as NK
from tests.engine.export.blender_probe import blender_pythons, probe_image_node
from tests.engine.export.tiny_run import export, make_run
from tests.engine.fake_export import make_fake_export
from tests.engine_cli import run_cli

#: What OpenImageIO lists for an export of two layers (Background, Foreground) with ``--stmap``: sorted by layer, R G
#: B A in order (without it: the first eight).
OIIO_CHANNELS = (
    "Atlas.AlphaBackground.V",
    "Atlas.AlphaForeground.V",
    "Atlas.UVBackground.A",
    "Atlas.UVBackground.U",
    "Atlas.UVBackground.V",
    "Atlas.UVForeground.A",
    "Atlas.UVForeground.U",
    "Atlas.UVForeground.V",
    "STMapBackground.R",
    "STMapBackground.G",
    "STMapBackground.B",
    "STMapBackground.A",
    "STMapForeground.R",
    "STMapForeground.G",
    "STMapForeground.B",
    "STMapForeground.A",
)
#: The same channels as Nuke's EXR reader names them (ExrChannelNameToNuke, Nuke's NDK).
NUKE_CHANNELS = (
    "Atlas_AlphaBackground.V",
    "Atlas_AlphaForeground.V",
    "Atlas_UVBackground.alpha",
    "Atlas_UVBackground.U",
    "Atlas_UVBackground.V",
    "Atlas_UVForeground.alpha",
    "Atlas_UVForeground.U",
    "Atlas_UVForeground.V",
    "STMapBackground.red",
    "STMapBackground.green",
    "STMapBackground.blue",
    "STMapBackground.alpha",
    "STMapForeground.red",
    "STMapForeground.green",
    "STMapForeground.blue",
    "STMapForeground.alpha",
)


def test_nuke_names_channels_by_its_readers_rule():
    assert [nuke_channel_name(c) for c in OIIO_CHANNELS] == list(NUKE_CHANNELS)
    assert nuke_channel_name("R") == "red" and nuke_channel_name("Z") == "Z"
    assert nuke_channel_name("Ci.A") == "alpha"  # RenderMan's primary layer is Nuke's main one
    assert nuke_channel_name("diffuse.left.Red", views=["left"]) == "diffuse.red"
    assert nuke_channel_name("3d.pass.x.y") == "d_pass.x_y"  # leading digits dropped, three parts at most


@pytest.fixture(scope="module")
def exported(tmp_path_factory) -> Path:
    """A tiny real fit (48x32, 4 frames, 2 layers) and its export with the STMap copy (``--stmap``): the manifest's
    path."""
    root = tmp_path_factory.mktemp("nuke_run")
    _frames, _masks, run = make_run(root)
    return export(run, stmap=True)


@pytest.fixture(scope="module")
def exported_plain(exported) -> Path:
    """The same fit exported again as by default (no STMap copy): the manifest's path."""
    return export(exported.parent.parent.parent)


def _oiio_spec(path: Path) -> oiio.ImageSpec:
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    inp.close()
    return spec


def test_pass_files_hold_the_stmap_layers_as_copies_of_the_uv_passes(exported):
    m = Manifest(exported)
    path = m.pass_path(m.data["passes"]["frames"][0])
    spec = _oiio_spec(path)
    assert tuple(spec.channelnames) == OIIO_CHANNELS
    assert all(spec.channelformat(i) == oiio.FLOAT for i in range(spec.nchannels))  # float32: exact copies
    # no channel is named Z, so OpenImageIO sees no depth; every "*.A" it may take as alpha is a coverage
    assert spec.z_channel == -1
    assert spec.channelnames[spec.alpha_channel].endswith(".A")
    chans = read_exr(path)
    for layer in m.layers:
        name = layer["name"]
        assert layer["stmap_pass"] == f"STMap{name}"
        assert layer["stmap_channels"] == [f"STMap{name}.{c}" for c in "RGBA"]
        uv = [chans[f"Atlas.UV{name}.{c}"] for c in "UVA"]
        st = [chans[f"STMap{name}.{c}"] for c in "RGBA"]
        assert np.array_equal(st[0], uv[0]) and np.array_equal(st[1], uv[1]) and np.array_equal(st[3], uv[2])
        assert not st[2].any()


def test_by_default_the_pass_files_hold_no_stmap_copy(exported, exported_plain):
    """The UV and alpha passes alone, bit for bit those of the export with the copy; the manifest names no STMap."""
    m, full = Manifest(exported_plain), Manifest(exported)
    frame = m.data["passes"]["frames"][0]
    spec = _oiio_spec(m.pass_path(frame))
    assert tuple(spec.channelnames) == OIIO_CHANNELS[:8]
    assert all("stmap_pass" not in layer and "stmap_channels" not in layer for layer in m.layers)
    plain, with_copy = read_exr(m.pass_path(frame)), read_exr(full.pass_path(frame))
    assert all(np.array_equal(values, with_copy[name]) for name, values in plain.items())
    nk = NK.parse((m.folder / NUKE_SCRIPT_NAME).read_text(encoding="utf-8"))
    _check_wiring(nk, m, m.folder)


@pytest.mark.slow
def test_blender_sees_the_atlas_passes_exactly_as_before(exported):
    """Blender skips one-dot channel names: the Image node offers the one layer Atlas and the same sockets."""
    pythons = blender_pythons()
    if not pythons:
        pytest.skip("no Python with bpy")
    m = Manifest(exported)
    path = m.pass_path(m.data["passes"]["frames"][0])
    versions = []
    for python in pythons:
        got = probe_image_node(path, python)
        versions.append(tuple(got["version"]))
        assert got["layers"] == "'Atlas'" and got["layer"] == "Atlas"
        assert got["sockets"] == [
            ["AlphaBackground", "VALUE"],
            ["AlphaForeground", "VALUE"],
            ["UVBackground", "VECTOR"],
            ["UVForeground", "VECTOR"],
        ]
    print(f"Blender versions probed: {versions}")


def test_export_writes_the_nuke_script_beside_the_manifest(exported):
    m = Manifest(exported)
    script = m.folder / NUKE_SCRIPT_NAME
    nk = NK.parse(script.read_text(encoding="utf-8"))
    frames = m.data["passes"]["frames"]
    w, h = m.clip["resolution"]
    assert nk.version == "13.0 v1"
    assert nk.root["project_directory"] == "[python {nuke.script_directory()}]"
    assert (nk.root["first_frame"], nk.root["last_frame"]) == (str(min(frames)), str(max(frames)))
    assert nk.root["format"] == f"{w} {h} 0 0 {w} {h} 1 NA_{w}x{h}"
    assert nk.root.get("fps") == (f"{m.clip['fps']:.6g}" if m.clip["fps"] else None)
    classes = [n.cls for n in nk.nodes]
    assert classes == ["Read", *(["Copy", "Read", "Premult", "STMap", "Merge2"] * 2), "Merge2", "Read", "Merge2"]
    _check_wiring(nk, m, script.parent)


def _check_wiring(nk: NK.NkScript, m: Manifest, script_dir: Path) -> None:
    """Every layer's chain as the edit equation wants it, every file the script reads there, every channel it
    names in the pass files."""
    (out,) = nk.leftover  # one result: nothing dangles
    assert out.name == "NA_Over_plate" and out.knobs["operation"] == "over"
    plate, total = out.inputs  # Merge: input 0 is B (the plate), input 1 is A (the edits, premultiplied)
    assert plate.cls == "Read" and plate.name == "NA_Plate"
    frames = m.data["passes"]["frames"]
    pass_read = nk.node("NA_Passes")
    assert pass_read.knobs["raw"] == "true"  # data: no colour conversion
    nuke_names = {nuke_channel_name(c) for c in _oiio_spec(NK.file_for(pass_read, script_dir, frames[0])).channelnames}
    for f in frames:
        assert NK.file_for(pass_read, script_dir, f).samefile(m.pass_path(f))
    for number, frame_file in zip(m.clip["frame_numbers"], m.clip["frame_files"], strict=True):
        assert NK.file_for(plate, script_dir, number).samefile(m.resolve(frame_file))
    layers = []
    node = total
    while node.knobs.get("operation") == "plus":  # the sum of the layers, the last added at input 0
        layers.append(node.inputs[0])
        node = node.inputs[1]
    layers.append(node)
    assert [n.name for n in reversed(layers)] == [f"NA_Coverage_{layer['name']}" for layer in m.layers]
    for layer, mask in zip(m.layers, reversed(layers), strict=True):
        name = layer["name"]
        assert mask.knobs["operation"] == "mask"
        warped, coverage = mask.inputs
        assert warped.cls == "STMap" and warped.knobs["uv"] == "rgb" and warped.knobs["channels"] == "rgba"
        src, stmap = warped.inputs  # STMap: input 0 is src, input 1 is the stmap
        assert stmap is coverage and stmap.cls == "Copy" and stmap.inputs == [pass_read, pass_read]
        uv = [f"Atlas_UV{name}.{c}" for c in ("U", "V", "alpha")]  # the UV pass: u, v, coverage
        assert [stmap.knobs[f"from{k}"] for k in range(3)] == uv and set(uv) <= nuke_names
        assert [stmap.knobs[f"to{k}"] for k in range(3)] == ["rgba.red", "rgba.green", "rgba.alpha"]
        assert nk.layers[f"Atlas_UV{name}"] == uv  # declared before use, as Nuke writes custom layers
        edit = src.inputs[0] if src.cls == "Premult" else src
        assert edit.cls == "Read" and edit.name == f"NA_Edit_{name}"
        edit_file = Path(C.edit_layer_file(str(m.resolve(layer["edit_layer"]))))
        assert NK.file_for(edit, script_dir, frames[0]).samefile(edit_file)
        png = edit_file.suffix == EDIT_LAYER_EXT
        assert (src.cls == "Premult") == png
        # the config's own names (tests/export_td/test_nuke_colour.py opens the config the Root declares)
        want = "sRGB Encoded Rec.709 (sRGB)" if png else "Linear Rec.709 (sRGB)"
        assert nk.root["customOCIOConfigPath"] == "ocio://default" and edit.knobs["colorspace"] == want


def _paint(path: Path, size: tuple[int, int], seed: int, as_exr: bool) -> None:
    """A random RGBA edit layer: 8-bit sRGB straight alpha (PNG) or linear premultiplied float (EXR)."""
    w, h = size
    rng = np.random.default_rng(seed)
    rgba = rng.random((h, w, 4)).astype(np.float32)
    rgba[..., 3] = np.where(rng.random((h, w)) < 0.3, 0.0, rgba[..., 3])
    if as_exr:
        write_exr(path, {c: rgba[..., i] * (rgba[..., 3] if c != "A" else 1) for i, c in enumerate("RGBA")})
    else:
        write_png(path, rgba, 8)


@pytest.fixture
def painted(tmp_path) -> Path:
    """A hand-made export (two layers, 3 frames) whose Background is painted in a PNG and Foreground in a float
    EXR twin (which wins over its PNG, as everywhere)."""
    plate = np.random.default_rng(1).random((3, 12, 16, 3)).astype(np.float32)

    def background(t, xs, ys):
        return xs / 16, 1.0 - ys / 12, np.full(xs.shape, 0.7)

    def foreground(t, xs, ys):
        return (xs - 2 * t) / 10, 1.0 - (ys - 1) / 9, np.where(xs > 6, 0.3, 0.0)

    manifest = make_fake_export(tmp_path, plate, [(background, (16, 12)), (foreground, (10, 9))])
    edits = tmp_path / "run" / EDITS_DIR
    _paint(edits / "Background.png", (16, 12), 2, as_exr=False)
    _paint(edits / "Foreground.exr", (10, 9), 3, as_exr=True)
    return manifest


def test_the_script_computes_what_engine_render_does(painted, tmp_path):
    """Nearest texel (STMap's Impulse, `render --filter nearest`): the node model of the script gives the render's
    frames; the script is written in another folder, so its paths are relative to it."""
    out = tmp_path / "comp" / "shot.nk"
    out.parent.mkdir()
    assert run_cli(VERB_NUKE, painted, "--out", out, "--filter", "Impulse") == (0, [])
    nk = NK.parse(out.read_text(encoding="utf-8"))
    m = Manifest(painted)
    _check_wiring(nk, m, out.parent)
    assert not any(Path(n.knobs["file"]).is_absolute() for n in nk.nodes if n.cls == "Read" and n.name != "NA_Plate")
    rendered = tmp_path / "rendered"
    code, err = run_cli(VERB_RENDER, painted, "--out", rendered, "--filter", "nearest", "--no-bar")
    assert code == 0, err
    (result,) = nk.leftover
    worst = 0.0
    for frame in m.data["passes"]["frames"]:
        got = NK.evaluate(result, out.parent, frame, nk.root)
        want = read_exr(rendered / f"edit.{frame:05d}.exr")
        for c in "RGB":
            nuke = got[f"rgba.{dict(R='red', G='green', B='blue')[c]}"]
            worst = max(worst, float(np.abs(nuke - want[c]).max()))
        assert got["rgba.alpha"].max() > 0.1  # the paint shows
    assert worst < 2e-6, worst
    print(f"Nuke script model vs engine render (nearest): max abs difference {worst:.1e}")


def test_nuke_verb_refuses_an_existing_file_and_reads_any_export(painted, tmp_path):
    out = tmp_path / "shot.nk"
    out.write_text("the artist's comp")
    code, err = run_cli(VERB_NUKE, painted, "--out", out)
    assert code == C.EXIT_BAD_INPUT and len(err) == 1 and "exists" in err[0] and str(out) in err[0]
    assert out.read_text() == "the artist's comp"
    code, err = run_cli(VERB_NUKE, painted, "--out", tmp_path / "shot.txt")
    assert code == C.EXIT_BAD_INPUT and "ends in .nk" in err[0]
    data = json.loads(painted.read_text())
    for layer in data["layers"]:
        del layer["stmap_pass"], layer["stmap_channels"]
    old = tmp_path / "old" / "manifest.json"
    shutil.copytree(painted.parent, old.parent)
    old.write_text(json.dumps(data))
    assert run_cli(VERB_NUKE, old, "--out", tmp_path / "old.nk") == (0, [])  # without STMap layers: the UV pass
    assert NK.parse((tmp_path / "old.nk").read_text(encoding="utf-8")).node("NA_UV_Background").cls == "Copy"


def test_a_movie_plate_is_read_from_its_frame_one():
    manifest = json.loads(json.dumps(_movie_manifest()))
    nk = NK.parse(nuke_script(manifest, "/shots/a/run/exports/v001/manifest.json"))
    plate = nk.node("NA_Plate")
    assert plate.knobs["file"] == "../../plate.mov"
    assert (plate.knobs["frame_mode"], plate.knobs["frame"]) == ("expression", "frame+1")
    assert (plate.knobs["first"], plate.knobs["last"]) == ("11", "20")  # frames 10..19 of the movie
    assert (nk.root["first_frame"], nk.root["last_frame"], nk.root["fps"]) == ("10", "19", "23.976")


def _movie_manifest() -> dict:
    layer = {
        "name": "Background",
        "uv_pass": "UVBackground",
        "uv_channels": ["U", "V", "A"],
        "edit_layer": "../../edits/Background.png",
    }
    return {
        "clip": {
            "kind": "movie",
            "source": "../../plate.mov",
            "frame_files": [],
            "frame_numbers": list(range(10, 20)),
            "fps": 24000 / 1001,
            "resolution": [64, 48],
            "colorspace": "sRGB",
        },
        "passes": {
            "dir": "passes",
            "pattern": "atlas.{frame:05d}.exr",
            "frames": list(range(10, 20)),
            "exr_layer": "Atlas",
        },
        "layers": [layer],
    }


def test_sequence_patterns():
    assert sequence_pattern(["a/plate.1001.exr", "a/plate.1002.exr"], [1001, 1002]) == "a/plate.%04d.exr"
    assert sequence_pattern(["s2/00009.png", "s2/00010.png"], [9, 10]) == "s2/%05d.png"
    assert sequence_pattern(["x/f9.tif", "x/f10.tif"], [9, 10]) == "x/f%d.tif"
    with pytest.raises(NukeScriptError, match="not named with its frame number 3"):
        sequence_pattern(["a/plate.0002.exr"], [3])
    with pytest.raises(NukeScriptError, match="not one numbered sequence"):
        sequence_pattern(["a/p.0009.exr", "b/p.0010.exr"], [9, 10])


def test_knob_values_with_spaces_and_tcl_characters_stay_one_literal_value():
    for value in ("plain/path.%04d.exr", 'a dir/with "quotes"/[x] $HOME {y}\\z.exr', "C:/plates/shot 1/p.%04d.exr"):
        assert NK.unquote(quote(value)) == value
    assert quote("passes/atlas.%05d.exr") == "passes/atlas.%05d.exr"


def test_export_warns_and_writes_no_script_for_a_plate_nuke_cannot_read_as_one_sequence(tmp_path, capsys):
    from engine.export.manifest_writer import _write_nuke_script

    manifest = _movie_manifest()
    manifest["clip"].update(kind="sequence", frame_files=[f"../../clip/shot_{c}.png" for c in "abcdefghij"])
    _write_nuke_script(tmp_path, manifest)
    assert not (tmp_path / NUKE_SCRIPT_NAME).exists()
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(f"warning: no {NUKE_SCRIPT_NAME}: plate frame 'shot_a.png' is not named with its frame")


def test_stack_variables_are_named_by_the_layer_index_and_comments_stay_comments():
    """A layer's name never becomes part of Tcl code: the stack variables are numbered, the header is comments."""
    manifest = _movie_manifest()
    manifest["layers"].append(dict(manifest["layers"][0], name="Foreground", uv_pass="UVForeground"))
    lines = nuke_script(manifest, "/shots/a/run/exports/v001/manifest.json").splitlines()
    stack = [line for line in lines if line.startswith(("set ", "push "))]
    assert stack == [
        "set NA_passes [stack 0]",
        "push $NA_passes",
        "set NA_st_0 [stack 0]",
        "push $NA_st_0",
        "push $NA_passes",
        "push $NA_passes",
        "set NA_st_1 [stack 0]",
        "push $NA_st_1",
    ]
    assert (
        lines[0]
        == f"#! written by neural-atlas {ENGINE_VERSION} from an export's manifest (layers: Background, Foreground)"
    )
    assert lines[1].startswith("# ") and lines[2] == "version 13.0 v1"
    assert _comment("a\nb [c] \\") == "# a_b _c_ _"  # a newline would end it, a trailing backslash extend it


def test_export_warns_and_writes_no_script_for_a_plate_folder_holding_a_frame_token(tmp_path, capsys):
    from engine.export.manifest_writer import _write_nuke_script

    manifest = _movie_manifest()
    frames = [f"../../../shot#2/plate.{n:04d}.exr" for n in manifest["clip"]["frame_numbers"]]
    manifest["clip"].update(kind="sequence", frame_files=frames)
    _write_nuke_script(tmp_path, manifest)
    assert not (tmp_path / NUKE_SCRIPT_NAME).exists()
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith(
        f"warning: no {NUKE_SCRIPT_NAME}: the plate frame path '../../../shot#2/plate.0010.exr' holds '#', which a "
        "Nuke Read takes as a frame token or as Tcl (it has no escape for them) — rename the folder or file"
    )


def test_file_knob_paths():
    assert file_knob_path("../plates/p.0001.exr", "plate") == "../plates/p.0001.exr"
    assert file_knob_path("~p/p.0001.exr", "plate", "~p/p.%04d.exr") == "./~p/p.%04d.exr"  # not a home folder
    assert file_knob_path("/abs/~p/p.0001.exr", "plate") == "/abs/~p/p.0001.exr"
    for bad, said in (("a#/p.exr", "'#'"), ("a%d/p.exr", "'%'"), ("[x]$y\\", "'$[\\\\]'"), ("a\udcff/p", "UTF-8")):
        with pytest.raises(NukeScriptError, match=re.escape(said)):
            file_knob_path(bad, "plate")
