"""An artist's day in Blender (bpy 4.5 and 5.0), in one test: import, paint, save, close, reopen, open another shot,
come back, copy the shot folder elsewhere, move it again, relink the run folder alone, widen the range, render. After
every step the live preview, Render Edited Clip and ``engine render`` of the same manifest agree at every exported
frame; nothing is black; nothing is stale (the preview and the render show the paint as it is now, the other shot's
paint while it is open); no stroke is lost (every stroke painted so far is in the edit layers' files and in Blender).

Refining in the copied shot (Refine: ``fit --refine``, export, realign) is not a step here: it needs a real fit of
a real clip, which these tiny exports are not (``test_refine.py`` refines a real fit in place).

Painting operators cannot run headless (docs/blender-compat.md#painting): a stroke is its pixels, written into the
edit image as a brush would, and left unsaved until a save. The engine runs in its own interpreter
(``helpers.engine_python``)."""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402
from test_day_reopen import _pixels, _relative_manifest  # noqa: E402
from test_preview_equals_render import (  # noqa: E402
    ENGINE_TOLERANCE,
    PREVIEW_TOLERANCE,
    blender_render,
    engine_render,
    preview_render,
    worst,
)

TAG = f"[bpy {bpy.app.version_string}]"


@dataclass(frozen=True)
class Stroke:
    """Opaque paint over rows ``rows`` of a layer's edit image (rows bottom-up, as Blender keeps them)."""

    layer: str
    rgba: tuple[float, float, float, float]
    rows: tuple[int, int]

    def paint(self) -> None:
        img = bpy.data.images[P.edit_image_name(self.layer)]
        px = _pixels(img)
        px[self.rows[0] : self.rows[1]] = self.rgba
        img.pixels.foreach_set(px.ravel())
        img.update()
        assert img.is_dirty

    def held_by(self, px: np.ndarray) -> bool:
        """Does ``px`` (the edit image's pixels, rows bottom-up, 0..1) hold this stroke?"""
        return bool(np.abs(px[self.rows[0] : self.rows[1]] - np.array(self.rgba)).max() <= 1 / 255)


@dataclass
class Day:
    """What the day has done so far: the strokes of the open shot, and each step's numbers."""

    tmp: Path
    strokes: list[Stroke] = field(default_factory=list)
    lines: list[str] = field(default_factory=list)
    engine: dict[str, dict[int, np.ndarray]] = field(default_factory=dict)
    """Each step's ``engine render``, by step."""

    def check(self, step: str, manifest: Path, engine: dict[int, np.ndarray] | None = None) -> dict[int, np.ndarray]:
        """The preview (unsaved paint included), then Render Edited Clip (which saves it), then ``engine render`` of
        ``manifest`` (or ``engine``: an earlier engine render of the same plate and paint, where the files did not
        change); every stroke in Blender and on disk. Returns the render."""
        folder = self.tmp / "steps" / step.replace(" ", "_")
        shown = preview_render(folder)
        rendered = blender_render(folder / "blender")
        if engine is None:
            engine = engine_render(manifest, folder / "engine", P.FILTER_DEFAULT)
        self.engine[step] = engine
        preview_err, render_err = worst(shown, rendered), worst(rendered, engine)
        darkest = min(float(img[..., :3].mean()) for frames in (shown, rendered) for img in frames.values())
        self.lines.append(f"{step}: preview vs render {preview_err:.1e}, render vs engine {render_err:.1e}")
        assert preview_err <= PREVIEW_TOLERANCE, step
        assert render_err <= ENGINE_TOLERANCE, step
        assert darkest > 0.05, f"{step}: a black frame (mean {darkest:.3f})"
        for stroke in self.strokes:
            edit = bpy.data.images[P.edit_image_name(stroke.layer)]
            assert stroke.held_by(_pixels(edit)), f"{step}: {stroke} lost in Blender"
            on_disk = X.read_png_rgba8(Path(bpy.path.abspath(edit.filepath)))[::-1] / 255.0
            assert stroke.held_by(on_disk), f"{step}: {stroke} lost on disk"
        return rendered

    def paint(self, stroke: Stroke) -> None:
        stroke.paint()
        self.strokes.append(stroke)


def _shot(blender, root: Path, seed: int, stroke: Stroke) -> Path:
    """A shot folder as a studio keeps one (``scene.blend``, ``run``, ``plate``; every path relative), imported,
    painted and saved; returns its manifest."""
    manifest = _relative_manifest(X.make_export(root, seed=seed))
    assert blender.ops.wm.save_as_mainfile(filepath=str(root / "scene.blend")) == {"FINISHED"}
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    stroke.paint()
    assert blender.ops.wm.save_mainfile() == {"FINISHED"}
    return manifest


def _open(path: Path) -> None:
    assert bpy.ops.wm.open_mainfile(filepath=str(path)) == {"FINISHED"}


def _same(a: dict[int, np.ndarray], b: dict[int, np.ndarray]) -> float:
    return worst(a, b)


@pytest.mark.slow
def test_an_artists_day(blender, tmp_path):
    day = Day(tmp_path)
    other_manifest = _shot(blender, tmp_path / "other", 1, Stroke("Background", (0.0, 0.3, 1.0, 1.0), (0, 8)))
    other = day.check("the other shot, made", other_manifest)
    bpy.ops.wm.read_factory_settings(use_empty=True)

    shot = tmp_path / "shot"
    manifest = _relative_manifest(X.make_export(shot))
    assert blender.ops.wm.save_as_mainfile(filepath=str(shot / "scene.blend")) == {"FINISHED"}
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    bare = day.check("import", manifest)

    day.paint(Stroke("Background", (1.0, 0.4, 0.0, 1.0), (0, 6)))
    day.paint(Stroke("Foreground", (0.0, 1.0, 0.2, 1.0), (0, 4)))
    painted = day.check("paint", manifest)
    assert _same(painted, bare) > 0.3  # the strokes show: nothing stale

    day.paint(Stroke("Background", (0.9, 0.0, 0.9, 1.0), (20, 24)))
    assert bpy.ops.wm.save_mainfile() == {"FINISHED"}  # Ctrl+S writes the paint too
    saved = day.check("save", manifest)
    assert _same(saved, painted) > 0.3

    bpy.ops.wm.read_factory_settings(use_empty=True)  # closed
    _open(shot / "scene.blend")
    reopened = day.check("reopen", manifest, day.engine["save"])  # the same plate and paint: the same reference
    assert _same(reopened, saved) <= 1e-6

    _open(tmp_path / "other" / "scene.blend")
    strokes, day.strokes = day.strokes, [Stroke("Background", (0.0, 0.3, 1.0, 1.0), (0, 8))]
    assert _same(day.check("reopen another shot", other_manifest, day.engine["the other shot, made"]), other) <= 1e-6
    day.strokes = strokes
    _open(shot / "scene.blend")
    assert _same(day.check("come back", manifest, day.engine["save"]), saved) <= 1e-6

    copy = tmp_path / "elsewhere" / "shot"
    shutil.copytree(shot, copy)
    _open(copy / "scene.blend")
    for img in (bpy.data.images[P.edit_image_name(layer)] for layer in ("Background", "Foreground")):
        assert Path(bpy.path.abspath(img.filepath)).resolve().is_relative_to(copy.resolve()), img.filepath
    copy_manifest = copy / manifest.relative_to(shot)
    assert _same(day.check("copied", copy_manifest), saved) <= 1e-6
    day.paint(Stroke("Foreground", (1.0, 1.0, 0.0, 1.0), (10, 12)))
    assert bpy.ops.wm.save_mainfile() == {"FINISHED"}
    in_copy = day.check("painted in the copy", copy_manifest)
    original = X.read_png_rgba8(shot / "run" / "edits" / "Foreground.png")[::-1] / 255.0
    assert not day.strokes[-1].held_by(original)  # the copy's paint stays in the copy
    # (refine in the copy: not a step here, see the module's docstring)

    moved = tmp_path / "moved_again" / "shot"
    shutil.move(str(copy), str(moved))
    _open(moved / "scene.blend")
    moved_manifest = moved / manifest.relative_to(shot)
    assert _same(day.check("moved again", moved_manifest), in_copy) <= 1e-6
    engine_now = day.engine["moved again"]

    run = tmp_path / "runs_elsewhere" / "run"
    run.parent.mkdir()
    shutil.move(str(moved / "run"), str(run))  # the run folder alone: the plate stays in the shot folder
    _open(moved / "scene.blend")
    assert bpy.ops.neural_atlas.relink("EXEC_DEFAULT", filepath=str(run)) == {"FINISHED"}
    # the relinked manifest's relative plate paths name nothing now: `engine render` takes the plate's paths as at
    # export (the first shot folder's plate, the same pixels), Blender the plate the scene's clip shows
    relinked = run / manifest.relative_to(shot / "run")
    assert _same(day.check("relinked", relinked), in_copy) <= 1e-6
    assert _same(day.engine["relinked"], engine_now) <= 1e-6

    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = X.FRAMES[0] - 2, X.FRAMES[-1] + 2
    widened = day.check("range widened", run / manifest.relative_to(shot / "run"), engine_now)
    assert _same(widened, in_copy) <= 1e-6
    assert "not rendered: the export has passes for frames" in scene.neural_atlas.render_status
    assert sorted(widened) == list(X.FRAMES)  # and no other file: the frames outside the export are not rendered
    assert len(list((tmp_path / "steps" / "range_widened" / "blender").glob("edit.*"))) == len(X.FRAMES)
    print(f"{TAG} the day: " + "; ".join(day.lines))
    assert os.path.isdir(shot / "run")  # the first shot folder was copied, not moved
