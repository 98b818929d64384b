"""An export's pass files, opened by Blender (the bpy wheel): one compositor socket per pass.

Runs Blender in a subprocess (``blender_probe``). Skipped when bpy is not installed.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from engine.export.manifest import Manifest
from tests.engine.export.blender_probe import probe_image_node
from tests.engine.fake_export import make_fake_export

pytestmark = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="bpy is not installed")


def test_blender_sees_one_socket_per_pass(tmp_path):
    plate = np.full((2, 12, 16, 3), 0.5, np.float32)
    layer = (lambda t, xs, ys: (xs / 16, 1.0 - ys / 12, np.ones(xs.shape) * 0.5), (16, 12))
    m = Manifest(make_fake_export(tmp_path, plate, [layer, layer]))
    got = probe_image_node(m.pass_path(1))
    assert got["type"] == "MULTILAYER" and got["has_layers"] and got["layer"] == "Atlas"
    passes = {name: kind for name, kind in got["sockets"] if name not in ("Image", "Alpha")}
    assert set(passes) == {"UVBackground", "AlphaBackground", "UVForeground", "AlphaForeground"}
    assert passes["UVForeground"] in ("VECTOR", "RGBA") and passes["AlphaForeground"] == "VALUE"
