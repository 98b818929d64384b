"""Plates in studio colour spaces through Blender's compositor: the tree loads each plate in Blender's colour space
for the manifest's OCIO space and writes the EXR render in the plate's scene-linear space, so Blender's render
equals ``engine render`` for an ACEScg EXR, a log (ACEScct) DPX and an sRGB PNG plate; where this Blender has no
such space (4.5: no ACEScct) the import says so in one line. And Blender's decode of 8-bit sRGB is the engine's."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from neural_atlas.addon.core import tree_plan as P

from engine import contract as C
from engine.terms.colour import COLOUR_BUILTIN_CONFIG
from engine.terms.export_names import frame_padding
from tests.addon.fake_export import blender_srgb_lut, read_exr_rgba
from tests.addon.helpers import engine_python

ROOT = Path(__file__).resolve().parents[2]
BLENDER_45 = frozenset({"ACES2065-1", "ACEScg", "Linear Rec.709", "Linear Rec.2020", "Non-Color", "sRGB"})
BLENDER_50 = BLENDER_45 | {"ACEScc", "ACEScct"}


def test_manifest_colour_spaces_map_to_blender_names():
    assert P.plate_colorspace({"colorspace": "sRGB"}) == "sRGB"  # an old manifest
    assert P.plate_colorspace({"colorspace": "linear"}) == "Linear Rec.709"
    for name, blender in [
        (C.COLOUR_SRGB, "sRGB"),
        ("srgb_tx", "sRGB"),
        (C.COLOUR_SCENE_LINEAR, "Linear Rec.709"),
        ("ACEScg", "ACEScg"),
        ("lin_ap1", "ACEScg"),
        ("ACES2065-1", "ACES2065-1"),
    ]:
        clip = {"colorspace": name, "colour_config": COLOUR_BUILTIN_CONFIG}
        assert P.plate_colorspace(clip, BLENDER_45) == P.plate_colorspace(clip, BLENDER_50) == blender
    log = {"colorspace": "ACEScct", "colour_config": COLOUR_BUILTIN_CONFIG}
    assert P.plate_colorspace(log, BLENDER_50) == "ACEScct"
    with pytest.raises(P.PlanError) as err:
        P.plate_colorspace(log, BLENDER_45)
    assert "has no 'ACEScct'" in str(err.value) and "Blender 5.0" in str(err.value)
    assert "engine render --format plate" in str(err.value)
    # a studio config's own name that Blender also has is taken as it is
    assert P.plate_colorspace({"colorspace": "Rec.1886", "colour_config": "/s/c.ocio"}, BLENDER_45 | {"Rec.1886"})
    # the EXR render: the plate's space when scene-linear, else Linear Rec.709 (as engine render --format exr)
    assert P.output_colorspace({"colorspace": "ACEScg", "colour_config": "ocio://default"}) == "ACEScg"
    assert P.output_colorspace({"colorspace": "ACEScct", "colour_config": "ocio://default"}) == "Linear Rec.709"
    assert P.output_colorspace({"colorspace": "sRGB"}) == "Linear Rec.709"


def test_blender_decodes_srgb_as_the_engine_does(blender, tmp_path):
    """Blender's decode of an 8-bit sRGB PNG (a ramp of the 256 code values), measured through a compositor render,
    equals the engine's decode of the same file (``load_edit``) exactly; the exact IEC formula differs by 2.4e-5."""
    py = engine_python("render", "OpenImageIO")
    lut = blender_srgb_lut(blender, tmp_path).astype(np.float32)
    script = (
        "import sys; from engine.edit.equations import load_edit; "
        "print(' '.join(repr(float(v)) for v in load_edit(sys.argv[1])[0, :, 0]))"
    )
    engine = np.array(subprocess.run([py, "-c", script, str(tmp_path / "ramp.png")], cwd=ROOT, check=True,
                                     capture_output=True, text=True).stdout.split(), np.float32)  # fmt: skip
    codes = np.arange(256) / 255.0
    formula = np.where(codes <= 0.04045, codes / 12.92, ((codes + 0.055) / 1.055) ** 2.4)
    print(f"sRGB decode, Blender {blender.app.version_string}: engine {np.abs(lut - engine).max():.3g}, "
          f"exact formula {np.abs(lut - formula).max():.3g}")  # fmt: skip
    assert np.array_equal(lut, engine)


@pytest.mark.parametrize("kind", ["acescg", "acescct", "srgb"])
def test_blender_render_equals_engine_render(blender, tmp_path, kind):
    from neural_atlas.addon import compat, compositor
    from neural_atlas.addon.ops.import_run import import_manifest

    py = engine_python("render", "OpenImageIO")
    made = subprocess.run(
        [py, "-m", "tests.colour_plates", kind, str(tmp_path / "export"), "paint"],
        cwd=ROOT, check=True, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    manifest = made.stdout.strip().splitlines()[-1]
    props = blender.context.scene.neural_atlas
    props.filter_type = P.FILTER_NEAREST
    if kind == "acescct" and "ACEScct" not in compat.colorspace_names():
        with pytest.raises(P.PlanError) as err:
            import_manifest(blender.context, manifest, setup_paint=False)
        assert "has no 'ACEScct'" in str(err.value)
        return
    plan = import_manifest(blender.context, manifest, setup_paint=False)
    space = {"acescg": "ACEScg", "acescct": "ACEScct", "srgb": "sRGB"}[kind]
    assert blender.data.movieclips[P.PLATE_CLIP].colorspace_settings.name == space
    assert plan.output_colorspace == ("ACEScg" if kind == "acescg" else "Linear Rec.709")
    out_b, out_e = tmp_path / "blender", tmp_path / "engine"
    compositor.render(blender.context.scene, str(out_b), "exr", plan.output_colorspace)
    settings = blender.context.scene.render.image_settings  # the artist's output settings are given back
    assert (settings.color_management, settings.file_format) == ("FOLLOW_SCENE", "PNG")
    subprocess.run(
        [py, "-m", "engine", "render", manifest, "--out", str(out_e), "--filter", "nearest", "--no-bar"],
        cwd=ROOT, check=True, timeout=300, capture_output=True,
    )  # fmt: skip
    errors = []
    clip = json.loads(Path(manifest).read_text())["clip"]
    padding = frame_padding(clip["frame_files"], clip["frame_numbers"])  # engine render pads as the plate's files
    assert padding == 4  # plate.0000.exr ..: not the five digits a plate without padding of its own gives
    names = [f"edit.{f:0{padding}d}.exr" for f in plan_frames(manifest)]
    # Render Edited Clip names its frames as engine render does: one sequence, whichever rendered it
    assert sorted(p.name for p in out_b.glob("edit.*")) == sorted(p.name for p in out_e.glob("edit.*")) == names
    for name in names:
        a = read_exr_rgba(out_b / name)[..., :3]
        b = read_exr_rgba(out_e / name)[..., :3]
        errors.append(float(np.abs(a - b).max() / max(1.0, float(np.abs(b).max()))))
    print(f"Blender {blender.app.version_string} vs engine render, {kind} plate: {max(errors):.3g}")
    assert max(errors) <= TOLERANCE[kind], errors


#: Blender vs engine (relative to the frame's largest value): the plate decoded by each side's OCIO config (the
#: same transforms; Blender's float matrices differ in the last bits), the paint by the same 8-bit sRGB decode.
TOLERANCE = {"acescg": 2e-5, "acescct": 2e-5, "srgb": 0.0}


def plan_frames(manifest: str) -> list[int]:
    return list(C.load_manifest(manifest)["passes"]["frames"])
