"""``addon/headless.py`` (what the demo's Blender step and pipelines run): an export -> a .blend with the
add-on's tree -> the compositor's render, in a fresh process of this test's Blender (bpy 4.5 or 5.0)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from neural_atlas.addon import compat  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402

from engine import contract as C  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "addon" / "headless.py"
TAG = f"[bpy {bpy.app.version_string}]"


def _run(*args: str, temp: Path | None = None) -> subprocess.CompletedProcess:
    """headless.py in its own Python; ``temp``: its TMPDIR, where Blender makes its session temp folder."""
    env = os.environ if temp is None else {**os.environ, "TMPDIR": str(temp)}
    return subprocess.run(
        [sys.executable, str(SCRIPT), "--", *args], capture_output=True, text=True, timeout=300, cwd=ROOT, env=env
    )


def test_headless_builds_the_blend_and_renders_the_equation(blender, tmp_path):
    manifest = X.make_export(tmp_path)
    m = json.loads(manifest.read_text())
    fg_edit = Path(C.resolve_manifest_path(str(manifest), m["layers"][1]["edit_layer"]))
    other = tmp_path / "elsewhere" / "paint.png"
    other.parent.mkdir()
    shutil.copy(fg_edit, other)  # same pixels, another file: the override must be what the .blend uses
    out = tmp_path / "out"
    temp = tmp_path / "temp"
    temp.mkdir()
    proc = _run(
        str(manifest),
        *("--blend", str(out / "shot.blend"), "--render", str(out / "render"), "--filter", "exact"),
        *("--edit", f"Foreground={other}", "--report", str(out / "report.json")),
        temp=temp,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert list(temp.iterdir()) == []  # Blender's session temp folder gone, though the process left with os._exit
    report = json.loads((out / "report.json").read_text())
    assert report["exact"] and report["frames"] == list(X.FRAMES) and len(report["files"]) == len(X.FRAMES)
    assert report["engine_filter"] == "bilinear"  # exact: bilinear on every version
    assert "shot.blend" in proc.stdout.splitlines()[-1]

    decode = X.lut_decoder(X.blender_srgb_lut(bpy, tmp_path / "lut"))
    err = X.render_error(out / "render", manifest, report["engine_filter"], decode)
    print(f"{TAG} headless.py render vs the render equation ({report['engine_filter']}): {err:.2e}")
    assert err <= 1e-5

    # the saved .blend is what an artist opens: the add-on's tree, the override as the Foreground edit layer
    bpy.ops.wm.open_mainfile(filepath=str(out / "shot.blend"))
    tree = compat.scene_tree(bpy.context.scene, create=False)
    # 14 + frames and mattes; 4.x: a bilinear group and a Switch per layer
    assert len([n for n in tree.nodes if n.name.startswith(P.PREFIX)]) == 26 + (0 if compat.V5 else 4)
    assert os.path.isfile(P.matte_path(str(out / "render"), "Foreground", X.FRAMES[0]))  # beside the render
    edit = bpy.data.images[P.edit_image_name("Foreground")]
    assert Path(bpy.path.abspath(edit.filepath)).resolve() == other.resolve()
    assert bpy.data.objects.get("NA_Canvas_Foreground") is not None
    assert bpy.context.scene.frame_start == X.FRAMES[0] and bpy.context.scene.frame_end == X.FRAMES[-1]
    # the Run Folder is the export's run, relative to the .blend as Import Atlas stores it: Refine is not greyed
    run_dir = bpy.context.scene.neural_atlas.run_dir
    assert run_dir.startswith("//") and Path(bpy.path.abspath(run_dir)).resolve() == (tmp_path / "run").resolve()


def test_headless_bad_input_is_one_line_exit_2(tmp_path):
    proc = _run(str(tmp_path / "nowhere" / "manifest.json"), "--blend", str(tmp_path / "x.blend"))
    assert proc.returncode == 2
    assert (
        proc.stderr.strip().splitlines()[-1].startswith(f"error: {tmp_path / 'nowhere' / 'manifest.json'}: no manifest")
    )
    manifest = X.make_export(tmp_path)
    proc = _run(str(manifest), "--blend", str(tmp_path / "x.blend"), "--edit", "Foreground")
    assert proc.returncode == 2 and "is not LAYER=IMAGE" in proc.stderr
    proc = _run(str(manifest), "--blend", str(tmp_path / "x.blend"), "--edit", "Nope=" + str(manifest))
    assert proc.returncode == 2 and "unknown layer" in proc.stderr
    assert not (tmp_path / "x.blend").exists()
