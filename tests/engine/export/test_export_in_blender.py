"""An export's pass files, opened by Blender (the bpy wheel): one compositor socket per pass.

Runs Blender in a subprocess (bpy must not share the test process with torch's threads, and bpy 4.5 can
hang on exit: the script ends with os._exit). Skipped when bpy is not installed.
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys

import numpy as np
import pytest

from engine.export.manifest import Manifest
from tests.engine.fake_export import make_fake_export

pytestmark = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="bpy is not installed")

SCRIPT = r"""
import json, os, sys
import bpy
path = sys.argv[-1]
scene = bpy.context.scene
if bpy.app.version >= (5, 0, 0):
    tree = bpy.data.node_groups.new("probe", "CompositorNodeTree")
    scene.compositing_node_group = tree
else:
    scene.use_nodes = True
    tree = scene.node_tree
img = bpy.data.images.load(path)
img.colorspace_settings.name = "Non-Color"
node = tree.nodes.new("CompositorNodeImage")
node.image = img
out = {
    "type": img.type,
    "has_layers": bool(node.has_layers),
    "layer": node.layer,
    "sockets": {s.name: s.type for s in node.outputs if s.enabled},
}
print("RESULT " + json.dumps(out), flush=True)
os._exit(0)
"""


def test_blender_sees_one_socket_per_pass(tmp_path):
    plate = np.full((2, 12, 16, 3), 0.5, np.float32)
    layer = (lambda t, xs, ys: (xs / 16, 1.0 - ys / 12, np.ones(xs.shape) * 0.5), (16, 12))
    m = Manifest(make_fake_export(tmp_path, plate, [layer, layer]))
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(m.pass_path(1))], capture_output=True, text=True, timeout=120
    )
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert lines, proc.stdout + proc.stderr
    got = json.loads(lines[0][len("RESULT ") :])
    assert got["type"] == "MULTILAYER" and got["has_layers"] and got["layer"] == "Atlas"
    passes = {name: kind for name, kind in got["sockets"].items() if name not in ("Image", "Alpha")}
    assert set(passes) == {"UVBackground", "AlphaBackground", "UVForeground", "AlphaForeground"}
    assert passes["UVForeground"] in ("VECTOR", "RGBA") and passes["AlphaForeground"] == "VALUE"
