"""Preview equals render (bpy 4.5 and 5.0): the panel's one Filter setting, named as ``engine render --filter`` names
it, samples the edit layers the same way in the live preview (the shader's image interpolation), in Render Edited
Clip (the compositor: Map UV on 5.0, and on 4.x, whose Map UV has no bilinear filter, the bilinear group's nearest
taps) and in ``engine render``, on every Blender version.

Hard-edged strokes (unsaved, written as a brush leaves them) make the filters differ by tenths at the paint's
edges: the three renders are compared there. The engine runs in its own interpreter (``helpers.engine_python``)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from helpers import engine_python  # noqa: E402
from neural_atlas.addon import preview_plane  # noqa: E402
from neural_atlas.addon.core import preview_plan as V  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402
from test_day_reopen import _pixels  # noqa: E402

from engine.terms.cli import VERB_RENDER  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
TAG = f"[bpy {bpy.app.version_string}]"
#: What the artist sees while painting against what the render writes (the issue's bar).
PREVIEW_TOLERANCE = 1e-3
#: Render Edited Clip against ``engine render``: the 8-bit sRGB plate and edits are decoded by OCIO's float32 curve in
#: both, within 2.4e-5 of each other (docs/colour.md); the filters themselves agree to 1e-6.
ENGINE_TOLERANCE = 1e-4
#: Where the two filters differ by more than this, a pixel is at a paint edge.
EDGE = 0.05


def _brush(img, rgba: tuple[float, float, float, float], box: tuple[float, float, float, float]) -> None:
    """A stroke over the texels in ``box`` (u0, v0, u1, v1), left unsaved: straight sRGB values on byte steps, as
    a brush leaves them in an 8-bit image."""
    px = _pixels(img)
    h, w, _ = px.shape
    u0, v0, u1, v1 = box
    px[int(v0 * h) : int(v1 * h), int(u0 * w) : int(u1 * w)] = np.round(np.array(rgba) * 255) / 255
    img.pixels.foreach_set(px.ravel())
    img.update()
    assert img.is_dirty


def engine_render(manifest: Path, out: Path, filt: str) -> dict[int, np.ndarray]:
    """``engine render MANIFEST --filter filt`` of the edit layers saved in the run folder; RGBA per frame."""
    py = engine_python(VERB_RENDER, "torch")
    args = [py, "-m", "engine", VERB_RENDER, str(manifest), "--out", str(out), "--format", "exr", "--filter", filt]
    done = subprocess.run([*args, "--no-bar"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    return frames(out)


def frames(out: Path) -> dict[int, np.ndarray]:
    """The ``edit.<frame>.exr`` files in ``out`` (padded as the plate's files: ``engine render`` and Render Edited Clip
    name them alike), RGBA by frame number; every exported frame is there."""
    found = {int(p.name.split(".")[1]): X.read_exr_rgba(p) for p in out.glob("edit.*.exr")}
    assert sorted(found) == list(X.FRAMES), sorted(found)
    return found


def engine_filters() -> tuple[str, ...]:
    """The engine's filter names (``engine render --filter``), from its own interpreter (this one may lack the
    engine's packages)."""
    py = engine_python(VERB_RENDER, "torch")
    code = "from engine.edit.equations import FILTERS; print(*FILTERS)"
    done = subprocess.run([py, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    return tuple(done.stdout.split())


def blender_render(out: Path) -> dict[int, np.ndarray]:
    """Render Edited Clip (it saves the paint first) to EXR; RGBA per frame."""
    assert bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out), file_format="exr") == {"FINISHED"}
    return frames(out)


def preview_render(folder: Path) -> dict[int, np.ndarray]:
    """The live preview at each exported frame, as the viewport's Rendered shading shows it; RGBA per frame."""
    scene = bpy.context.scene
    return {
        f: X.read_exr_rgba(Path(preview_plane.render_frame(scene, f, str(folder / f"preview.{f}.exr"))))
        for f in X.FRAMES
    }


def worst(a: dict[int, np.ndarray], b: dict[int, np.ndarray], where: dict[int, np.ndarray] | None = None) -> float:
    """The largest RGB difference over the frames (only where ``where`` holds, when given)."""
    errs = []
    for f in a:
        diff = np.abs(a[f][..., :3] - b[f][..., :3]).max(axis=-1)
        errs.append(float(diff[where[f]].max() if where is not None else diff.max()))
    return max(errs)


def test_the_filter_is_named_and_defaults_as_engine_render(registered):
    """The panel's Filter offers exactly engine render's --filter names, and defaults to engine render's default;
    the preview's interpolation exists for each."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    props = bpy.context.scene.neural_atlas
    items = props.bl_rna.properties["filter_type"].enum_items
    assert tuple(item.identifier for item in items) == P.FILTERS == engine_filters()
    assert props.filter_type == P.FILTER_DEFAULT == "bilinear"
    assert {V.INTERPOLATION[f] for f in P.FILTERS} == {"Linear", "Closest"}


@pytest.mark.slow
def test_preview_equals_render_equals_engine_render_at_paint_edges(blender, tmp_path):
    """Hard-edged strokes on both layers; for each filter: the live preview, Render Edited Clip and engine render
    --filter of the same name agree at every pixel, paint edges included, at every exported frame; Render Edited Clip
    and engine render write the same file names (a plate numbered with four digits: edit.0003.exr ..)."""
    manifest = X.make_export(tmp_path, plate_name="plate.{frame:04d}.png")
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    _brush(bpy.data.images[P.edit_image_name("Background")], (1.0, 0.1, 0.0, 1.0), (0.3, 0.2, 0.8, 0.7))
    _brush(bpy.data.images[P.edit_image_name("Foreground")], (0.0, 0.9, 1.0, 0.5), (0.1, 0.1, 0.6, 0.6))
    props = blender.context.scene.neural_atlas
    assert props.filter_type == P.FILTER_BILINEAR  # nothing chosen: the default
    shown, rendered, engine = {}, {}, {}
    for filt in P.FILTERS:
        props.filter_type = filt
        rendered[filt] = blender_render(tmp_path / f"blender_{filt}")
        shown[filt] = preview_render(tmp_path / f"preview_{filt}")
        engine[filt] = engine_render(manifest, tmp_path / f"engine_{filt}", filt)
        names = [X.edit_file(manifest, f) for f in X.FRAMES]
        assert X.edit_names(tmp_path / f"blender_{filt}") == X.edit_names(tmp_path / f"engine_{filt}") == names
        assert names == [f"edit.{f:04d}.exr" for f in X.FRAMES]
    edges = {
        f: np.abs(engine["bilinear"][f][..., :3] - engine["nearest"][f][..., :3]).max(axis=-1) > EDGE for f in X.FRAMES
    }
    filters_differ = worst(engine["bilinear"], engine["nearest"])
    report = []
    for filt in P.FILTERS:
        at_edges = worst(shown[filt], rendered[filt], edges)
        preview_err, render_err = worst(shown[filt], rendered[filt]), worst(rendered[filt], engine[filt])
        report.append(
            f"{filt}: preview vs render {preview_err:.1e} (edges {at_edges:.1e}), render vs engine {render_err:.1e}"
        )
        assert preview_err <= PREVIEW_TOLERANCE and at_edges <= PREVIEW_TOLERANCE, filt
        assert render_err <= ENGINE_TOLERANCE, filt
    print(
        f"{TAG} {sum(int(e.sum()) for e in edges.values())} edge pixels, filters differ by {filters_differ:.2f}; "
        + "; ".join(report)
    )
    assert sum(int(e.sum()) for e in edges.values()) > 50 and filters_differ > 0.2  # the edges are real
