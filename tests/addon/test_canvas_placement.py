"""Paint canvases keep clear of the artist's scene (bpy 4.5 and 5.0): with a cube at the origin and a turned,
scaled box beside it, Import Atlas puts the canvas row past both (the world bound boxes share no point), a hidden
object does not push it away, and importing again after the artist moves an object moves the row past it."""

from __future__ import annotations

import itertools
import math

import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from mathutils import Vector  # noqa: E402
from neural_atlas.addon import edit_layers  # noqa: E402
from neural_atlas.addon.core import placement as L  # noqa: E402

TAG = f"[bpy {bpy.app.version_string}]"


def _world_box(obj) -> L.Box:
    return L.Box.around(tuple(obj.matrix_world @ Vector(c)) for c in obj.bound_box)


def _canvases(blender) -> list:
    return [o for o in blender.context.scene.objects if o.name.startswith("NA_Canvas_")]


def _check_clear(blender, scene_objects) -> float:
    """Asserts no canvas touches any of ``scene_objects`` or another canvas; returns the smallest X gap."""
    blender.context.view_layer.update()
    canvases = [_world_box(o) for o in _canvases(blender)]
    boxes = [_world_box(o) for o in scene_objects]
    assert len(canvases) == 2
    assert not any(c.overlaps(b) for c in canvases for b in boxes)
    assert not any(a.overlaps(b) for a, b in itertools.combinations(canvases, 2))
    return min(c.lo[0] for c in canvases) - max(b.hi[0] for b in boxes)


def test_canvases_are_placed_beyond_the_scene_objects(blender, tmp_path):
    ops = blender.ops
    ops.mesh.primitive_cube_add(size=2.0, location=(0.0, 0.0, 0.0))  # the factory cube
    cube = blender.context.active_object
    ops.mesh.primitive_cube_add(size=1.0, location=(2.5, 0.5, 0.3), rotation=(0.0, 0.0, math.radians(45)))
    turned = blender.context.active_object
    turned.scale = (3.0, 1.0, 1.0)
    ops.mesh.primitive_cube_add(size=1.0, location=(50.0, 0.0, 0.0))
    hidden = blender.context.active_object
    hidden.hide_set(True)
    manifest = X.make_export(tmp_path)
    assert ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    gap = _check_clear(blender, [cube, turned])
    reach = max(_world_box(o).hi[0] for o in (cube, turned))
    print(f"{TAG} canvases start {gap:.3f} past the scene's largest X ({reach:.3f}); the hidden box at x=50 ignored")
    assert gap == pytest.approx(L.MARGIN, abs=1e-5)
    assert max(_world_box(o).hi[0] for o in _canvases(blender)) < 45.0

    cube.location.x = 8.0  # the artist moves the cube; Paint Canvases places the row again
    layers = [o.name.removeprefix("NA_Canvas_") for o in _canvases(blender)]
    edit_layers.setup_canvases(blender.context, layers)
    gap = _check_clear(blender, [cube, turned])
    assert gap == pytest.approx(L.MARGIN, abs=1e-5)


def test_an_empty_scene_keeps_the_canvases_at_the_origin(blender, tmp_path):
    manifest = X.make_export(tmp_path)
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    xs = sorted(o.location.x for o in _canvases(blender))
    assert xs[0] == 0.0 and xs[1] == pytest.approx(1.2)
