"""A plate's colour space comes from its own header where the header says it (an EXR's ``oiio:ColorSpace`` tag or
OpenEXR's ``colorInteropID``), and what nothing says is assumed out loud: one ``note:`` line, and
``"colour_source": "assumed"`` in clip.json and in every manifest of the run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from engine import contract as C
from engine.fit import run_files
from engine.io import colour
from engine.io.clip import open_clip
from engine.io.images import write_rgba_exr
from engine.terms.colour import COLOUR_SOURCE_ASKED, COLOUR_SOURCE_ASSUMED, COLOUR_SOURCE_FILE, COLOUR_SOURCE_FORMAT
from engine.terms.manifest import validate_manifest
from engine.terms.run_folder import RUN_CLIP
from tests.engine.io.test_colour_headers import GOOD_OCIO_CONFIG
from tests.media_files import write_image

W, H = 8, 6
GREY = np.full((H, W, 3), 0.18, np.float32)


def _exr_plate(folder: Path, **tags: object) -> Path:
    """Two float EXR frames, plate.1001.exr and plate.1002.exr, with these header attributes (none: untagged)."""
    folder.mkdir(parents=True)
    for number in (1001, 1002):
        write_rgba_exr(folder / f"plate.{number}.exr", GREY, attributes=dict(tags))
    return folder


def test_an_exr_tagged_acescg_is_fitted_as_acescg(tmp_path: Path) -> None:
    """Before: the tag was never read; the plate was taken as Linear Rec.709 without a word."""
    info = open_clip(_exr_plate(tmp_path / "plate", **{"oiio:ColorSpace": "ACEScg"}))
    assert (info.colorspace, info.colour_source, info.colour_note) == ("ACEScg", COLOUR_SOURCE_FILE, "")


def test_an_alias_in_the_tag_and_openexrs_own_attribute_are_read(tmp_path: Path) -> None:
    aliased = open_clip(_exr_plate(tmp_path / "alias", **{"oiio:ColorSpace": "lin_ap0"}))
    interop = open_clip(_exr_plate(tmp_path / "interop", colorInteropID="lin_ap1_scene"))
    assert (aliased.colorspace, aliased.colour_source) == ("ACES2065-1", COLOUR_SOURCE_FILE)
    assert (interop.colorspace, interop.colour_source) == ("ACEScg", COLOUR_SOURCE_FILE)


def test_an_untagged_float_plate_is_assumed_linear_rec709_with_one_note(tmp_path: Path) -> None:
    plate = _exr_plate(tmp_path / "plate")
    info = open_clip(plate)
    assert (info.colorspace, info.colour_source) == (C.COLOUR_SCENE_LINEAR, COLOUR_SOURCE_ASSUMED)
    assert info.colour_note == (
        f"note: {plate / 'plate.1001.exr'}: colour space assumed 'Linear Rec.709 (sRGB)' (a float file with no "
        "colour-space tag and no chromaticities) — if the plate is in another, name it with --colorspace, e.g. ACEScg"
    )


def test_a_tag_the_config_does_not_know_is_named_in_the_note(tmp_path: Path) -> None:
    info = open_clip(_exr_plate(tmp_path / "plate", **{"oiio:ColorSpace": "show_lut_v3"}))
    assert (info.colorspace, info.colour_source) == (C.COLOUR_SCENE_LINEAR, COLOUR_SOURCE_ASSUMED)
    assert "a float file with a tag 'show_lut_v3' that ocio://default does not know" in info.colour_note


def test_a_tag_in_the_built_in_names_maps_to_the_studio_configs_space(tmp_path: Path, monkeypatch) -> None:
    """$OCIO's config calls scene-linear Rec.709 "lin_rec709"; a file tagged with the built-in config's name for it
    is read in that space, not assumed."""
    config = tmp_path / "studio.ocio"
    config.write_text(GOOD_OCIO_CONFIG, encoding="utf-8")
    monkeypatch.setenv("OCIO", str(config))
    info = open_clip(_exr_plate(tmp_path / "plate", **{"oiio:ColorSpace": "Linear Rec.709 (sRGB)"}))
    assert (info.colorspace, info.colour_source, info.colour_config) == ("lin_rec709", "file", str(config))


def test_chromaticities_and_file_types_that_define_colour_are_not_assumed(tmp_path: Path) -> None:
    rec709 = _exr_plate(tmp_path / "rec709", chromaticities=colour.REC709_CHROMATICITIES)
    pngs = tmp_path / "png"
    pngs.mkdir()
    write_image(pngs / "00000.png", np.full((H, W, 3), 128, np.uint8))
    assert open_clip(rec709).colour_source == COLOUR_SOURCE_FILE
    assert (open_clip(pngs).colour_source, open_clip(pngs).colour_note) == (COLOUR_SOURCE_FORMAT, "")
    asked = open_clip(_exr_plate(tmp_path / "asked"), colorspace="acescg")
    assert (asked.colorspace, asked.colour_source, asked.colour_note) == ("ACEScg", COLOUR_SOURCE_ASKED, "")


def test_a_16bit_tiff_says_it_was_assumed_srgb(tmp_path: Path) -> None:
    folder = tmp_path / "tif"
    folder.mkdir()
    write_image(folder / "00000.tif", np.full((H, W, 3), 30000, np.uint16))
    info = open_clip(folder)
    assert (info.colorspace, info.colour_source) == (C.COLOUR_SRGB, COLOUR_SOURCE_ASSUMED)
    assert "(an integer file whose header names no colour space)" in info.colour_note


@pytest.mark.parametrize("where", ["clip record", "manifest"])
def test_an_unknown_colour_source_is_refused(assumed_run, where: str) -> None:
    path = assumed_run.run / RUN_CLIP if where == "clip record" else assumed_run.manifest
    record = json.loads(path.read_text(encoding="utf-8"))
    clip = record if where == "clip record" else record["clip"]
    clip["colour_source"] = "guessed"
    error = run_files.RunFileError if where == "clip record" else C.ManifestError
    with pytest.raises(error, match="unknown colour_source 'guessed'"):
        run_files.validate_run_file(RUN_CLIP, record) if where == "clip record" else validate_manifest(record)
    clip["colour_source"] = COLOUR_SOURCE_FILE  # every known value passes
    run_files.validate_run_file(RUN_CLIP, record) if where == "clip record" else validate_manifest(record)


# --- a fit of an untagged EXR plate, through the command line --------------------------------------------------


def test_the_fit_says_it_once_and_the_run_and_its_manifest_record_it(assumed_run) -> None:
    notes = [line for line in assumed_run.fit_err.splitlines() if line.startswith("note:")]
    assert notes == [open_clip(assumed_run.plate).colour_note]
    clip = json.loads((assumed_run.run / RUN_CLIP).read_text(encoding="utf-8"))
    assert (clip["colorspace"], clip["colour_source"]) == (C.COLOUR_SCENE_LINEAR, COLOUR_SOURCE_ASSUMED)
    manifest = json.loads(assumed_run.manifest.read_text(encoding="utf-8"))
    assert (manifest["clip"]["colorspace"], manifest["clip"]["colour_source"]) == (C.COLOUR_SCENE_LINEAR, "assumed")
