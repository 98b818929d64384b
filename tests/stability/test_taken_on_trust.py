"""Frame numbers and rates that look valid but are not a plate's: refused before anything is read or written, in
one line naming the file or the flag and the fix (a plate numbered below 0, ``--start-frame -5``, ``--fps 1e-300``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from engine import contract as C
from engine.cli_options import start_frame
from engine.errors import InputError
from engine.io.clip import open_clip
from engine.terms.clip import MAX_START_FRAME
from engine.terms.manifest import validate_manifest
from engine.terms.run_folder import RUN_CLIP
from tests.engine_cli import run_cli
from tests.media_files import write_image
from tests.stability.bad_inputs import TINY_FIT


def _plate(folder: Path, names: list[str]) -> Path:
    folder.mkdir(parents=True)
    for name in names:
        write_image(folder / name, np.full((24, 32, 3), 128, np.uint8))
    return folder


@pytest.mark.parametrize(
    ("names", "source"),
    [
        (["plate.-003.png", "plate.-002.png", "plate.-001.png"], ""),  # a folder read in reverse time order before
        (["plate.-001.png", "plate.0000.png", "plate.0001.png"], ""),
        (["plate.-001.png", "plate.0000.png", "plate.0001.png"], "plate.####.png"),  # a pattern fitted, then export
        (["plate_-002.png", "plate_-001.png"], ""),
        (["-002.png", "-001.png"], ""),
    ],
)
def test_a_plate_numbered_below_0_is_refused_before_anything_is_written(tmp_path, names, source):
    """No verb can number such a plate (Blender's scenes, the exported passes, Nuke's scripts start at 0): ``fit``
    refuses it in one line naming the first such file, and writes no run folder."""
    plate = _plate(tmp_path / "plate", names)
    clip = plate / source if source else plate
    code, lines = run_cli(C.VERB_FIT, clip, "--out", tmp_path / "run", *TINY_FIT)
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1, lines
    assert "numbered below 0" in lines[0] and "renumber the frame files from 0" in lines[0], lines
    assert any(name in lines[0] for name in names if "-" in name), lines
    assert not (tmp_path / "run").exists()


def test_a_dash_before_the_number_is_a_separator_not_a_sign(tmp_path):
    plate = _plate(tmp_path / "plate", ["shot-0001.png", "shot-0002.png", "shot-0003.png"])
    assert open_clip(plate).frame_numbers == (1, 2, 3)


@pytest.mark.parametrize(
    "flag",
    [["--start-frame", "-5"], ["--start-frame", "99999999999999999999"], ["--fps", "1e-300"], ["--fps", "1e308"]],
)
def test_a_start_frame_or_rate_no_plate_has_is_refused_before_anything_is_written(tmp_path, flag):
    """Before: the fit wrote its run folder and then blamed RUN/clip.json ("restore it"), or fitted and the export
    crashed. Now the flag is refused as the command line is read (exit 2), naming the range it takes."""
    plate = _plate(tmp_path / "plate", ["0000.png", "0001.png"])
    with pytest.raises(SystemExit) as exit_:
        run_cli(C.VERB_FIT, plate, "--out", tmp_path / "run", *TINY_FIT, *flag)
    assert exit_.value.code == C.EXIT_BAD_INPUT
    assert not (tmp_path / "run").exists()


def test_the_start_frame_range():
    assert start_frame("0") == 0 and start_frame("1001") == 1001 and start_frame(str(MAX_START_FRAME))
    for bad in ("-1", str(MAX_START_FRAME + 1), "1e3", "", "x"):
        with pytest.raises(Exception, match=f"from 0 to {MAX_START_FRAME}"):
            start_frame(bad)


def test_open_clip_refuses_a_negative_pattern_range(tmp_path):
    plate = _plate(tmp_path / "plate", ["plate.-001.png", "plate.0000.png"])
    with pytest.raises(InputError, match="numbered below 0"):
        open_clip(plate / "plate.-1-0#.png")


def test_masks_and_parts_never_write_into_the_plates_folder_named_by_a_pattern_or_into_a_run_folder(tmp_path):
    """The plate given as a pattern (``plate.####.png``): its folder is still the plate's own, and masks or strokes
    named like its frames there would be read as frames; a run folder's root holds the fit's own files. Each is one
    line naming the folder, and nothing is written."""
    from engine.data.synthetic import SceneSpec, make_scene

    scene = make_scene(SceneSpec(width=48, height=32, frames=4, fg_size=(16, 12), fg_start=(10.0, 6.0)))
    plate = tmp_path / "plate"
    plate.mkdir()
    for i, frame in enumerate(scene.frames):
        write_image(plate / f"plate.{i:04d}.png", (np.clip(frame, 0, 1) * 255).astype(np.uint8))
    masks = tmp_path / "masks"
    masks.mkdir()
    for i, mask in enumerate(scene.masks):
        write_image(masks / f"plate.{i:04d}.png", (mask * 255).astype(np.uint8))
    run = tmp_path / "run"
    run.mkdir()
    (run / RUN_CLIP).write_text("{}")
    pattern = plate / "plate.####.png"
    before = sorted(p.name for p in plate.iterdir())
    for verb, extra, out, said in (
        (C.VERB_MASKS, [], plate, "is the clip's own frame folder"),
        (C.VERB_PARTS, ["--mask", masks], plate, "is the clip's own frame folder"),
        (C.VERB_PARTS, ["--mask", masks], run, "is a fit's run folder"),
        (C.VERB_MASKS, [], run, "is a fit's run folder"),
    ):
        code, lines = run_cli(verb, pattern, *extra, "--out", out)
        assert code == C.EXIT_BAD_INPUT and len(lines) == 1, (verb, lines)
        assert lines[0].startswith(f"error: {out.resolve()}: {said}"), lines
    assert sorted(p.name for p in plate.iterdir()) == before and sorted(p.name for p in run.iterdir()) == [RUN_CLIP]


@pytest.mark.parametrize(
    ("pattern", "good"),
    [
        ("atlas.{frame:04d}.exr", True),
        ("atlas.{frame:05d}.exr", True),  # an export made before the padding followed the plate
        ("atlas.{frame:010d}.exr", True),
        ("atlas.{frame:011d}.exr", False),
        ("atlas.{frame:0999999999d}.exr", False),  # formatting it would take gigabytes
        ("atlas.{frame:04d}.{frame:04d}.exr", False),
        ("atlas.%04d.{frame:04d}.exr", False),
        ("atlas.{0}.exr", False),
    ],
)
def test_a_manifests_pass_pattern_is_checked_before_it_is_formatted(tmp_path, pattern, good):
    import json

    from tests.export_td.shots import fake_export

    data = json.loads(fake_export(tmp_path).read_text())
    data["passes"]["pattern"] = pattern
    if good:
        validate_manifest(data)
    else:
        with pytest.raises(C.ManifestError, match="does not name a pass file"):
            validate_manifest(data)


def test_a_scribble_image_far_larger_than_the_clip_is_refused_before_it_is_decoded(tmp_path, monkeypatch):
    """A 16000x12000 stroke image (a few hundred KB of PNG that decodes to gigabytes) for a 32x24 clip: one line
    from its header, no pixel decoded."""
    import cv2

    from engine.data import scribbles

    plate = _plate(tmp_path / "plate", ["0000.png", "0001.png"])
    strokes = tmp_path / "strokes"
    strokes.mkdir()
    cv2.imwrite(str(strokes / "0000.png"), np.zeros((12000, 16000, 4), np.uint8))
    decoded: list[str] = []
    monkeypatch.setattr(scribbles, "cv2_read", lambda path, *a: decoded.append(str(path)))
    info = open_clip(plate)
    with pytest.raises(InputError, match="scribble image is 16000x12000 but the clip is 32x24") as err:
        scribbles.read_scribbles(strokes, info, (32, 24))
    assert str(err.value).startswith(str(strokes / "0000.png")) and decoded == []


def test_one_mask_folder_given_twice_is_one_line(tmp_path):
    """``--mask M --mask M`` (or M and a link to it) would fit two identical layers, each owning half the object."""
    from engine.data.synthetic import SceneSpec, make_scene, write_scene

    frames, masks = write_scene(make_scene(SceneSpec(width=32, height=24, frames=3, fg_size=(12, 10))), tmp_path)
    (tmp_path / "same").symlink_to(masks)
    for second in (masks, tmp_path / "same"):
        code, lines = run_cli(
            C.VERB_FIT, frames, "--mask", masks, "--mask", second, "--out", tmp_path / "run", *TINY_FIT
        )
        assert code == C.EXIT_BAD_INPUT and len(lines) == 1, lines
        assert lines[0].startswith(f"error: {second}: given twice as --mask (also as {masks})"), lines
        assert not (tmp_path / "run").exists()


def test_two_stroke_files_of_one_frame_are_one_line(tmp_path):
    """``0.png`` and ``00000.png`` in one scribble folder: the reader used to keep one of them without a word."""
    from engine.data.scribbles import read_scribbles

    plate = _plate(tmp_path / "plate", ["0000.png", "0001.png"])
    strokes = tmp_path / "strokes"
    strokes.mkdir()
    for name in ("0.png", "00000.png"):
        write_image(strokes / name, np.zeros((24, 32, 4), np.uint8))
    with pytest.raises(InputError, match=r"0\.png and 00000\.png both have frame number 0"):
        read_scribbles(strokes, open_clip(plate), (32, 24))


def test_strokes_of_any_type_the_scribble_reader_reads_are_found_in_the_run_folder(tmp_path):
    """A fit finds the artist's strokes in RUN_DIR/parts saved as TIFF as ``--scribbles`` reads them (it looked for
    PNG only, so they were read by one and ignored by the other)."""
    from engine.fit.auto_parts import strokes_in_run
    from engine.fit.run_folder import RunFolder

    folder = RunFolder(tmp_path / "run").auto_parts
    folder.mkdir(parents=True)
    assert strokes_in_run(tmp_path / "run") is None
    write_image(folder / "0000.tif", np.zeros((24, 32, 4), np.uint8))
    assert strokes_in_run(tmp_path / "run") == str(folder)


def test_an_ocio_config_argument_with_a_newline_is_one_line(tmp_path):
    """``nuke --ocio-config`` with a trailing newline (pasted from a shell) was written into the script as given."""
    from engine.export.nuke import script_colour

    clip = {"colorspace": "sRGB", "kind": "sequence"}
    with pytest.raises(InputError, match="--ocio-config holds a newline or a control character"):
        script_colour(clip, "ocio://default\n")


@pytest.mark.parametrize("pattern", ["plate.100-107x2#.png", "plate.100-102,105-107#.png"])
def test_a_pattern_range_that_skips_frames_is_one_line_naming_it(tmp_path, pattern):
    """Every frame 100-107 exists; a stepped range used to be reported as missing frame 101."""
    plate = _plate(tmp_path / "plate", [f"plate.{n}.png" for n in range(100, 108)])
    with pytest.raises(InputError, match="skips frames, but a fit follows the motion from each frame to the next"):
        open_clip(plate / pattern)
    assert open_clip(plate / "plate.100-107#.png").frame_numbers == tuple(range(100, 108))


def test_an_ocio_config_openimageio_would_replace_by_its_own_is_one_line(tmp_path):
    """A config whose only colour space is data (``raw``): OpenImageIO takes its own built-in config in its place
    without an error, so a run would record the studio file and convert with other spaces."""
    from engine.io.colour import load_config

    config = tmp_path / "raw.ocio"
    config.write_text(
        "ocio_profile_version: 2.1\nroles:\n  default: raw\ncolorspaces:\n  - !<ColorSpace>\n    name: raw\n"
        "    isdata: true\n"
    )
    with pytest.raises(InputError, match="OpenImageIO cannot use this OCIO config") as err:
        load_config(str(config))
    assert str(err.value).startswith(str(config))
    config.write_text(config.read_text() + "  - !<ColorSpace>\n    name: lin\n")
    assert load_config(str(config)).getColorSpaceNames() == ["raw", "lin"]
