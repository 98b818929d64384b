"""Carry Paint (bpy 4.5 and 5.0): the paint of a split fit (one atlas per part) laid onto a one-layer fit of the
same plate imported in the scene, through the real engine (``realign --from`` another run folder): the status line
says how much of the paint landed, the edit image shows it at once, and the one-layer fit's edit layer it replaced
is kept in its history. The two fits are ``tests/engine/edit/test_carry.py``'s hand-made exports, written by the
engine's interpreter."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from helpers import engine_python  # noqa: E402
from neural_atlas.addon import preferences  # noqa: E402
from neural_atlas.addon.core import needs  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402

from engine import contract as C  # noqa: E402
from engine.terms.export_names import EDITS_DIR  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
TAG = f"[bpy {bpy.app.version_string}]"

#: The two fits, and paint on each part of the split one (``test_carry``'s stripes), made by the engine's Python.
MAKE = """
import sys
from pathlib import Path
from engine.edit.project_frame import save_edit_like
from tests.engine.edit.test_carry import _edit, _fits, _stripe
split, whole = _fits(Path(sys.argv[1]))
save_edit_like(_edit(split, "Foreground1"), _stripe((0.8, 0.1, 0.05)))
save_edit_like(_edit(split, "Foreground2"), _stripe((0.05, 0.2, 0.8)))
print(split)
print(whole)
"""


def test_carry_paint_lays_a_split_fits_paint_on_the_imported_one_layer_fit(blender, tmp_path, monkeypatch):
    py = engine_python(C.VERB_REALIGN, "scipy")
    monkeypatch.setenv(preferences.ENGINE_PYTHON_ENV, py)
    made = subprocess.run([py, "-c", MAKE, str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert made.returncode == 0, made.stderr[-2000:]
    split, whole = (Path(line) for line in made.stdout.split())
    props = blender.context.scene.neural_atlas
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(whole)) == {"FINISHED"}
    assert not blender.ops.neural_atlas.carry_paint.poll()  # greyed until Paint From names a fit
    with pytest.raises(RuntimeError, match=re.escape(needs.NO_CARRY_SOURCE)):
        blender.ops.neural_atlas.carry_paint("EXEC_DEFAULT")
    props.carry_from = str(split.parent.parent.parent)  # the split fit's run folder: its newest export
    assert blender.ops.neural_atlas.carry_paint("EXEC_DEFAULT") == {"FINISHED"}
    print(f"{TAG} {props.status}")
    found = re.fullmatch(
        rf"paint carried from {re.escape(str(split))}: (\d+)% of its pixels landed on this fit \(Foreground; "
        r"IoU (0\.\d\d) over 5 frames\)",
        props.status,
    )
    assert found and int(found[1]) >= 95 and float(found[2]) >= 0.9, props.status
    img = bpy.data.images[P.edit_image_name("Foreground")]
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    rgba = px.reshape(h, w, 4)
    assert (rgba[..., 3] > 0.5).sum() > 100 and (rgba[..., 0] > 0.5).sum() > 20 and (rgba[..., 2] > 0.5).sum() > 20
    assert len(list((whole.parent.parent.parent / EDITS_DIR / "history").iterdir())) == 1

    props.carry_from = str(whole.parent.parent.parent)  # its own run folder: Refine is what carries that
    with pytest.raises(RuntimeError, match="this fit's own run folder"):
        blender.ops.neural_atlas.carry_paint("EXEC_DEFAULT")
