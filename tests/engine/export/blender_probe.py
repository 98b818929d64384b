"""What Blender's compositor Image node makes of a pass file, asked of a Python with bpy in a subprocess.

bpy must not share the test process with torch's threads, and bpy 4.5 can hang on exit (the probe ends with
``os._exit``). ``blender_pythons`` lists the Pythons with bpy here (this one and ``.venv-bpy5``'s).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

from tests.paths import ROOT

PROBE = r"""
import json, os, sys
import bpy
scene = bpy.context.scene
if bpy.app.version >= (5, 0, 0):
    tree = bpy.data.node_groups.new("probe", "CompositorNodeTree")
    scene.compositing_node_group = tree
else:
    scene.use_nodes = True
    tree = scene.node_tree
img = bpy.data.images.load(sys.argv[-1])
img.colorspace_settings.name = "Non-Color"
node = tree.nodes.new("CompositorNodeImage")
node.image = img
layer = node.layer
try:
    node.layer = "no such layer"
except TypeError as exc:
    layers = str(exc).rsplit("(", 1)[1].rstrip(")")
out = {"version": list(bpy.app.version[:2]), "type": img.type, "has_layers": bool(node.has_layers),
       "layer": layer, "layers": layers, "sockets": [[s.name, s.type] for s in node.outputs if s.enabled]}
print("RESULT " + json.dumps(out), flush=True)
os._exit(0)
"""


def blender_pythons() -> list[str]:
    """The Pythons here that import bpy (bpy 4.5 in this venv, 5.0 in ``.venv-bpy5``)."""
    found = []
    for python in (sys.executable, str(ROOT / ".venv-bpy5" / "bin" / "python")):
        if Path(python).exists():
            probe = subprocess.run([python, "-c", "import bpy"], capture_output=True, timeout=120)
            if probe.returncode == 0:
                found.append(python)
    return found


def probe_image_node(path: str | Path, python: str = sys.executable) -> dict[str, Any]:
    """The Image node's view of ``path``: Blender version, image type, layers, the selected layer, its sockets."""
    proc = subprocess.run([python, "-c", PROBE, str(path)], capture_output=True, text=True, timeout=180)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert lines, proc.stdout + proc.stderr
    return json.loads(lines[0][len("RESULT ") :])
