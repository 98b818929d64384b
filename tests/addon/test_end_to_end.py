"""End to end with the real engine on a tiny synthetic clip: Fit Atlas (EXEC) fits and exports, the import
builds the tree, pixels are written into the edit layers, Blender renders every frame, and the result is
compared with ``python -m engine render`` on the same edits.

The engine runs in its own interpreter: NEURAL_ATLAS_TEST_ENGINE_PYTHON, else the checkout's .venv
(run.sh sets it for the bpy 5.0 venv, which has no torch). Skipped when that Python has no torch or its
engine has no export/render verbs yet.
"""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from fake_export import (  # noqa: E402
    blender_read_rgba8,
    blender_srgb_lut,
    edit_file,
    edit_names,
    lut_decoder,
    read_exr_rgba,
    reference_frame,
)
from helpers import engine_python, fit_panel  # noqa: E402
from neural_atlas.addon import compat  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402

from engine import contract as C  # noqa: E402
from engine.terms.export_names import EDITS_DIR  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
V5 = compat.V5
TAG = f"[bpy {bpy.app.version_string}]"
FAST = "steps=60 bootstrap_steps=30 global_rigidity_steps=20 eval_every=20"


def _engine_python() -> str:
    return engine_python("render", "torch")


def _paint(img_name: str, rgba, box) -> None:
    """Write a rectangle of paint (fractions of the atlas, rows bottom-up) as a brush would."""
    img = bpy.data.images[img_name]
    w, h = img.size
    px = np.zeros(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    px = px.reshape(h, w, 4)
    x0, y0, x1, y1 = box
    px[int(y0 * h) : int(y1 * h), int(x0 * w) : int(x1 * w)] = rgba
    img.pixels.foreach_set(px.ravel())
    img.update()


@pytest.mark.slow
def test_fit_paint_render_matches_engine_render(blender, tmp_path, monkeypatch):
    t0 = time.monotonic()
    py = _engine_python()
    clip_dir = tmp_path / "clip"
    subprocess.run(
        [
            py,
            "-c",
            "import sys; from pathlib import Path; "
            "from engine.data.synthetic import SceneSpec, make_scene, write_scene; "
            "from engine.io.images import read_image, write_rgba_exr; from engine.io.colour import srgb_to_linear; "
            "d = Path(sys.argv[1]); write_scene(make_scene(SceneSpec(width=64, height=48, frames=4)), d)\n"
            "for f in sorted((d / 'frames').glob('*.png')):\n"
            "    write_rgba_exr(d / 'frames_exr' / (f.stem + '.exr'), srgb_to_linear(read_image(f)[0][..., :3]))",
            str(clip_dir),
        ],
        cwd=ROOT,
        check=True,
        timeout=120,
    )
    monkeypatch.setenv("NEURAL_ATLAS_ENGINE_PYTHON", py)
    # a float (scene-linear EXR) plate, as in a VFX pipeline: Blender and the engine both read it raw, so the only
    # decode that differs is the one of 8-bit sRGB edit layers (OCIO vs the exact formula), measured below
    props = fit_panel(bpy, clip_dir / "frames_exr" / "00000.exr", clip_dir / "masks", tmp_path / "run", overrides=FAST)
    props.filter_type = P.FILTER_DEFAULT

    assert bpy.ops.neural_atlas.fit("EXEC_DEFAULT") == {"FINISHED"}, props.status
    t_fit = time.monotonic() - t0
    manifest = C.load_manifest(props.manifest)
    frames = manifest["passes"]["frames"]
    assert frames == [0, 1, 2, 3]
    tree = compat.scene_tree(blender.context.scene, create=False)
    ours = {n.name for n in tree.nodes if n.name.startswith(P.PREFIX)}
    # the render equation's nodes; the rest are the labelled frames around them and the matte outputs
    blend = set(
        [
            "NA_Plate",
            "NA_Passes",
            "NA_Edit_Background",
            "NA_Edit_Foreground",
            "NA_MapUV_Background",
            "NA_MapUV_Foreground",
            "NA_Alpha_Background",
            "NA_Alpha_Foreground",
            "NA_AddColor_1",
            "NA_AddAlpha_1",
            "NA_SetAlpha",
            "NA_Over",
            "NA_Output",
            "NA_Viewer",
        ]
    )
    assert blend <= ours
    others = ("NA_Frame_", "NA_Matte_", "NA_MatteFile_", "NA_Bilinear_", "NA_Filter_")  # 4.x: the bilinear group
    assert all(n.startswith(others) for n in ours - blend), sorted(ours - blend)
    uv = compat.input_socket(tree.nodes["NA_MapUV_Foreground"], P.MAP_UV, "uv")
    assert uv.links[0].from_socket.name == "UVForeground"

    _paint("NA_Edit_Foreground", (1.0, 0.1, 0.0, 1.0), (0.0, 0.0, 1.0, 1.0))  # the whole object turns red
    _paint("NA_Edit_Background", (0.0, 0.2, 1.0, 0.5), (0.0, 0.3, 1.0, 0.6))  # a half-transparent blue band
    assert bpy.ops.neural_atlas.save_edits("EXEC_DEFAULT") == {"FINISHED"}

    errors = {}
    exact = P.FILTER_DEFAULT  # bilinear: what engine render does by default
    manifest_path = Path(props.manifest)
    reader = blender_read_rgba8(bpy)
    lut = blender_srgb_lut(bpy, tmp_path / "lut")
    filters = [exact, P.FILTER_NEAREST]
    for filt in filters:
        props.filter_type = filt
        out_b = tmp_path / f"blender_{filt}"
        assert bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out_b), file_format="exr") == {"FINISHED"}
        out_e = tmp_path / f"engine_{filt}"
        engine_filter = filt  # the panel's filter is named as engine render's
        render_argv = [py, "-m", "engine", "render", props.manifest, "--out", str(out_e), "--format", "exr"]
        subprocess.run(
            [*render_argv, "--filter", engine_filter],
            cwd=ROOT,
            check=True,
            timeout=300,
            stdout=subprocess.DEVNULL,
        )
        errs = []
        # one sequence, whichever rendered it: Render Edited Clip names its frames as engine render does
        assert edit_names(out_b) == edit_names(out_e) == [edit_file(manifest_path, f) for f in frames]
        for f in frames:
            a = read_exr_rgba(out_b / edit_file(manifest_path, f))[..., :3]
            b = read_exr_rgba(out_e / edit_file(manifest_path, f))[..., :3]
            assert a.shape == b.shape == (48, 64, 3)
            errs.append(float(np.abs(a - b).max()))
        errors[filt] = max(errs)
        if filt == exact:
            # the tree against the render equation on this real export, with Blender's own 8-bit decode
            ref_errs = []
            for f in frames:
                a = read_exr_rgba(out_b / edit_file(manifest_path, f))[..., :3]
                ref = reference_frame(manifest_path, f, engine_filter, lut_decoder(lut), reader)
                ref_errs.append(float(np.abs(a - ref).max()))
            errors["tree_vs_equation"] = max(ref_errs)
        # the paint is really there: the blue band over the background
        img = read_exr_rgba(out_b / edit_file(manifest_path, frames[0]))
        assert ((img[..., 2] > 0.4) & (img[..., 0] < 0.3)).sum() > 100

    # float edit layers: the PNG paint becomes RUN/edits/<Layer>.exr (linear, premultiplied), the tree and the
    # engine both switch to it, paint is written in float and saved as float; nothing but float is decoded
    props.filter_type = exact
    pngs = {
        name: (Path(props.run_dir) / EDITS_DIR / f"{name}.png").read_bytes() for name in ("Foreground", "Background")
    }
    assert bpy.ops.neural_atlas.float_edits("EXEC_DEFAULT") == {"FINISHED"}
    for name in ("Foreground", "Background"):
        img = bpy.data.images[P.edit_image_name(name)]
        assert img.filepath.endswith(f"{name}.exr") and img.is_float and img.colorspace_settings.name == "Non-Color"
        assert (Path(props.run_dir) / EDITS_DIR / f"{name}.png").read_bytes() == pngs[name]  # PNG untouched
    exr_fg = read_exr_rgba(Path(props.run_dir) / EDITS_DIR / "Foreground.exr")
    assert np.abs(exr_fg - np.float32([1.0, 0.1**0 * 0.01002, 0.0, 1.0])).max() < 1e-3  # sRGB 0.1 -> 0.0100
    _paint("NA_Edit_Foreground", (2.0, 0.5, 0.001, 1.0), (0.0, 0.0, 1.0, 1.0))  # > 1 and < 1/255: float only
    _paint("NA_Edit_Background", (0.0, 0.1, 0.5, 0.5), (0.0, 0.3, 1.0, 0.6))  # premultiplied: 0.2, 1.0 at a=0.5
    assert bpy.ops.neural_atlas.save_edits("EXEC_DEFAULT") == {"FINISHED"}
    saved = read_exr_rgba(Path(props.run_dir) / EDITS_DIR / "Foreground.exr")
    assert np.abs(saved[0, 0] - np.float32([2.0, 0.5, 0.001, 1.0])).max() == 0.0  # top row: exact float paint
    out_b, out_e = tmp_path / "blender_float", tmp_path / "engine_float"
    assert bpy.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out_b), file_format="exr") == {"FINISHED"}
    engine_filter = exact
    render_argv = [py, "-m", "engine", "render", props.manifest, "--out", str(out_e), "--format", "exr"]
    subprocess.run(
        [*render_argv, "--filter", engine_filter], cwd=ROOT, check=True, timeout=300, stdout=subprocess.DEVNULL
    )
    errs = []
    assert edit_names(out_b) == edit_names(out_e) == [edit_file(manifest_path, f) for f in frames]
    for f in frames:
        a = read_exr_rgba(out_b / edit_file(manifest_path, f))[..., :3]
        b = read_exr_rgba(out_e / edit_file(manifest_path, f))[..., :3]
        errs.append(float(np.abs(a - b).max()))
        assert a.max() > 1.0  # the float paint above 1 (no plate value is) went through both
    errors["float_" + exact] = max(errs)
    print(f"{TAG} end to end: fit+export+import {t_fit:.1f} s, total {time.monotonic() - t0:.1f} s, errors {errors}")
    # float edit layers on a float plate: nothing is decoded, Blender and the engine agree to float precision.
    # Bilinear (5.0) places each sample in float32, and its result varies by ~1e-5 from run to run: a texel
    # position rounded by an ulp of the atlas width moves the sample across a paint edge (a jump of up to 2.0
    # here) by that much
    atlas_w = max(bpy.data.images[P.edit_image_name(n)].size[0] for n in ("Foreground", "Background"))
    float_tol = max(1e-5, atlas_w * 2.0**-24 * 2.0)
    assert errors["float_" + exact] <= float_tol, (errors, float_tol)
    # the tree is exact, and 8-bit sRGB PNG edit layers and plates are decoded by the same OCIO transform on both
    # sides (docs/colour.md): 0 with Nearest, Bilinear's float rounding (5.0's Map UV, 4.x's bilinear group)
    assert errors["tree_vs_equation"] <= 1e-5, errors
    assert errors[exact] <= 1e-5, errors
    assert errors[P.FILTER_NEAREST] <= 1e-5, errors
