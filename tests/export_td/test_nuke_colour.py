"""The Nuke script's colour: its Root sets ONE OCIO config (the export's, or the studio's ``--ocio-config``) and every
colour space the script names is a name of that config, checked by opening the config the Root declares with
PyOpenColorIO, the library Nuke loads configs with."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from engine import contract as C
from engine.export.manifest import Manifest
from engine.export.nuke import nuke_script
from engine.terms.cli import VERB_NUKE
from engine.terms.export_names import EDITS_DIR
from tests.engine.export import nk_script as NK
from tests.engine_cli import run_cli
from tests.export_td.shots import fake_export, renumber

OCIO = NK.pyocio()
needs_ocio = pytest.mark.skipif(OCIO is None, reason="PyOpenColorIO comes with bpy, which is not installed here")


def _check_names_resolve(nk: NK.NkScript, declared: str) -> dict[str, str]:
    """The Root declares ``declared`` under OCIO colour management, and each colour name of the script is a colour
    space of it (a name, an alias or a role, as OCIO resolves them): {where: the config's name}."""
    root = nk.root
    assert (root["colorManagement"], root["OCIO_config"], root["customOCIOConfigPath"]) == ("OCIO", "custom", declared)
    config = OCIO.Config.CreateFromFile(root["customOCIOConfigPath"])
    resolved = {}
    for where, name in NK.colour_knobs(nk).items():
        space = config.getColorSpace(name)
        assert space is not None, f"{where} {name!r} is not a colour space of {declared}"
        resolved[where] = space.getName()
    return resolved


@needs_ocio
def test_an_older_exports_srgb_plate_is_named_in_the_built_in_config(tmp_path):
    """A manifest whose plate says "sRGB" with no config (made before colour management): the built-in config."""
    manifest = fake_export(tmp_path)
    assert "colour_config" not in json.loads(manifest.read_text())["clip"]
    m = Manifest(manifest)
    nk = NK.parse(nuke_script(m.data, str(m.path)))
    assert _check_names_resolve(nk, "ocio://default") == {
        "NA_Edit_Background.colorspace": "sRGB Encoded Rec.709 (sRGB)",
        "NA_Edit_Foreground.colorspace": "sRGB Encoded Rec.709 (sRGB)",
        "NA_Plate.colorspace": "sRGB Encoded Rec.709 (sRGB)",
        "Root.workingSpaceLUT": "Linear Rec.709 (sRGB)",
    }


@needs_ocio
def test_an_acescg_plate_and_a_float_edit_layer_share_the_exports_config(tmp_path):
    manifest = renumber(fake_export(tmp_path), 1001, 4, half_exr=True)
    data = json.loads(manifest.read_text())
    data["clip"].update(colorspace="ACEScg", colour_config="ocio://default")
    manifest.write_text(json.dumps(data))
    (tmp_path / "run" / EDITS_DIR / "Foreground.exr").write_bytes(b"")  # a float twin wins: read as linear
    nk = NK.parse(nuke_script(data, str(manifest)))
    assert _check_names_resolve(nk, "ocio://default") == {
        "NA_Edit_Background.colorspace": "sRGB Encoded Rec.709 (sRGB)",
        "NA_Edit_Foreground.colorspace": "Linear Rec.709 (sRGB)",
        "NA_Plate.colorspace": "ACEScg",
        "Root.workingSpaceLUT": "Linear Rec.709 (sRGB)",
    }


def _blender_config() -> Path:
    import importlib.util

    spec = importlib.util.find_spec("bpy")
    assert spec is not None and spec.origin is not None
    (config,) = Path(spec.origin).parent.glob("*/datafiles/colormanagement/config.ocio")
    return config


@needs_ocio
def test_a_studio_config_names_every_space_in_its_own_words(tmp_path):
    """``engine nuke --ocio-config``: Blender's own config, whose sRGB space is called "sRGB" and scene-linear
    Rec.709 "Linear Rec.709": the script sets it and uses only its names."""
    studio = _blender_config()
    manifest = fake_export(tmp_path)
    out = tmp_path / "comp" / "shot.nk"
    assert run_cli(VERB_NUKE, manifest, "--out", out, "--ocio-config", studio) == (0, [])
    nk = NK.parse(out.read_text(encoding="utf-8"))
    assert _check_names_resolve(nk, str(studio)) == {
        "NA_Edit_Background.colorspace": "sRGB",
        "NA_Edit_Foreground.colorspace": "sRGB",
        "NA_Plate.colorspace": "sRGB",
        "Root.workingSpaceLUT": "Linear Rec.709",
    }


@needs_ocio
def test_a_studio_config_without_the_plates_space_is_one_line(tmp_path):
    manifest = fake_export(tmp_path)
    data = json.loads(manifest.read_text())
    data["clip"].update(colorspace="ACEScct", colour_config="ocio://default")
    manifest.write_text(json.dumps(data))
    studio = _blender_config()
    out = tmp_path / "shot.nk"
    code, err = run_cli(VERB_NUKE, manifest, "--out", out, "--ocio-config", studio)
    assert code == C.EXIT_BAD_INPUT and len(err) == 1, err
    assert err[0].startswith(f"error: {studio}: has no colour space 'ACEScct' (the plate's) — give --ocio-config")
    assert not out.exists()
    code, err = run_cli(VERB_NUKE, manifest, "--out", out, "--ocio-config", tmp_path / "nowhere.ocio")
    assert code == C.EXIT_BAD_INPUT and len(err) == 1 and "OCIO config does not exist" in err[0], err
