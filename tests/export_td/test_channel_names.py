"""The UV pass's channel names: Blender's own for its UV pass (U, V, A), so no reader takes the coverage for depth.

Checked readers: Blender (a Cycles render's UV pass in a multilayer EXR, and its Image node's sockets on our pass
files), OpenImageIO (its ``z_channel`` and ``alpha_channel``), Nuke's EXR reader rule (``nuke_channel_name``). An
export made with the older X, Y, Z names says so in its manifest (``uv_channels``) and reads as before."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from engine import contract as C
from engine.export.manifest import Manifest
from engine.export.nuke import nuke_channel_name
from engine.io.images import read_exr, write_exr, write_png
from engine.terms.cli import VERB_RENDER
from engine.terms.export_names import LEGACY_UV_CHANNELS
from engine.terms.manifest import validate_manifest
from tests.engine.export.blender_probe import blender_pythons, probe_image_node
from tests.engine_cli import run_cli
from tests.export_td.shots import fake_export

#: A Cycles render (8x8, one sample: under a second) of the default scene with the UV pass, as a multilayer EXR.
BLENDER_UV_PASS = r"""
import os, sys
import bpy
bpy.ops.wm.read_factory_settings(use_empty=False)
scene = bpy.context.scene
scene.render.engine = "CYCLES"
scene.cycles.samples = 1
scene.cycles.device = "CPU"
scene.render.resolution_x = scene.render.resolution_y = 8
scene.render.resolution_percentage = 100
scene.view_layers[0].use_pass_uv = True
scene.render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
scene.render.filepath = sys.argv[-1]
bpy.ops.render.render(write_still=True)
os._exit(0)
"""


def _spec(path: Path) -> oiio.ImageSpec:
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    spec = inp.spec()
    inp.close()
    return spec


def test_the_uv_pass_has_blenders_own_channel_names(tmp_path):
    pythons = blender_pythons()
    if not pythons:
        pytest.skip("no Python with bpy")
    out = tmp_path / "blender_uv.exr"
    proc = subprocess.run([pythons[0], "-c", BLENDER_UV_PASS, str(out)], capture_output=True, text=True, timeout=300)
    assert out.is_file(), proc.stdout[-2000:] + proc.stderr[-2000:]
    blender = [c for c in _spec(out).channelnames if c.startswith("ViewLayer.UV.")]
    assert blender == ["ViewLayer.UV.A", "ViewLayer.UV.U", "ViewLayer.UV.V"]
    assert {c.rsplit(".", 1)[1] for c in blender} == set(C.UV_CHANNELS)


def test_no_reader_takes_the_coverage_for_depth(tmp_path):
    m = Manifest(fake_export(tmp_path))
    path = m.pass_path(m.frames[0])
    spec = _spec(path)
    names = list(spec.channelnames)
    assert spec.z_channel == -1  # OpenImageIO: no depth (a "Z" or "*.Z" channel would be)
    assert names[spec.alpha_channel] == "Atlas.UVBackground.A"  # its one alpha: a coverage, as every "*.A" here
    uv = [n for n in names if n.startswith("Atlas.UV")]
    assert uv == [f"Atlas.UV{layer}.{c}" for layer in ("Background", "Foreground") for c in "AUV"]
    assert [nuke_channel_name(n) for n in uv[:3]] == [
        "Atlas_UVBackground.alpha",
        "Atlas_UVBackground.U",
        "Atlas_UVBackground.V",
    ]  # Nuke: a layer of its own, never depth.Z or rgba.alpha
    for layer in m.layers:
        assert layer["uv_channels"] == ["U", "V", "A"]  # u, v, coverage: the order every reader takes them in


def test_blenders_image_node_gives_map_uv_the_pass_as_one_vector(tmp_path):
    pythons = blender_pythons()
    if not pythons:
        pytest.skip("no Python with bpy")
    m = Manifest(fake_export(tmp_path))
    for python in pythons:
        got = probe_image_node(m.pass_path(m.frames[0]), python)
        assert got["layers"] == "'Atlas'"
        assert got["sockets"] == [
            ["AlphaBackground", "VALUE"],
            ["AlphaForeground", "VALUE"],
            ["UVBackground", "VECTOR"],
            ["UVForeground", "VECTOR"],
        ]


def test_an_export_with_the_older_xyz_names_reads_and_renders_the_same(tmp_path):
    """Rename every pass file's UV channels to X, Y, Z and say so in the manifest: the passes read back equal, and
    render writes the same frames."""
    manifest = fake_export(tmp_path / "new")
    old = fake_export(tmp_path / "old")
    data = json.loads(old.read_text())
    for layer in data["layers"]:
        layer["uv_channels"] = list(LEGACY_UV_CHANNELS)
        layer["channels"] = [C.channel_name(layer["uv_pass"], c) for c in LEGACY_UV_CHANNELS] + layer["channels"][3:]
    old.write_text(json.dumps(validate_manifest(data)))
    m_old, m_new = Manifest(old), Manifest(manifest)
    for f in m_old.frames:
        chans = read_exr(m_old.pass_path(f))
        for layer in data["layers"]:
            for new, legacy in zip(C.UV_CHANNELS, LEGACY_UV_CHANNELS, strict=True):
                chans[C.channel_name(layer["uv_pass"], legacy)] = chans.pop(C.channel_name(layer["uv_pass"], new))
        write_exr(m_old.pass_path(f), chans)
        for a, b in zip(m_old.read_passes(f), m_new.read_passes(f), strict=True):
            assert np.array_equal(a.uv, b.uv) and np.array_equal(a.z, b.z) and np.array_equal(a.alpha, b.alpha)
    outs = []
    for path in (old, manifest):
        for k, layer in enumerate(Manifest(path).layers):  # the same paint on both, so the UVs are used
            w, h = layer["atlas_size"]
            paint = np.random.default_rng(k).random((h, w, 4)).astype(np.float32)
            write_png(Manifest(path).edit_path(layer), paint, 8)
        outs.append(path.parents[3] / "out")
        assert run_cli(VERB_RENDER, path, "--out", outs[-1], "--no-bar") == (0, [])
    for f in m_new.frames:
        a, b = (read_exr(out / f"edit.{f:05d}.exr") for out in outs)
        assert all(np.array_equal(a[c], b[c]) for c in "RGBA")
    for layer in m_new.layers:
        m_new.edit_path(layer).unlink()  # no paint: the plate
    assert run_cli(VERB_RENDER, manifest, "--out", tmp_path / "plate", "--no-bar") == (0, [])
    f = m_new.frames[0]
    painted, plate = read_exr(outs[1] / f"edit.{f:05d}.exr"), read_exr(tmp_path / "plate" / f"edit.{f:05d}.exr")
    assert np.abs(painted["G"] - plate["G"]).max() > 0.1  # the paint shows: the UVs were read
