"""Frame numbers and names in what the engine writes for the user: padded as the plate's files are, and named with
``render --name``. The manifest's ``passes.pattern`` names the pass files for every reader (render, the Nuke script,
the add-on)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from engine import contract as C
from engine.export.manifest import Manifest
from engine.export.nuke import nuke_script, pass_sequence_pattern
from engine.io.images import read_exr
from engine.terms.cli import VERB_RENDER
from engine.terms.export_names import PASS_FILE_DIGITS, blender_pattern, frame_padding, pass_file_name, pass_pattern
from tests.engine.export import nk_script as NK
from tests.engine_cli import run_cli
from tests.export_td.shots import fake_export, renumber
from tests.folders import visible_names


@pytest.mark.parametrize(
    ("names", "numbers", "padding"),
    [
        (["/p/plate.1001.exr", "/p/plate.1002.exr"], [1001, 1002], 4),
        (["/p/plate.0998.exr", "/p/plate.1001.exr"], [998, 1001], 4),
        (["/p/shot_00009.png", "/p/shot_00010.png"], [9, 10], 5),
        (["/p/f9.tif", "/p/f10.tif"], [9, 10], 1),
        (["/p/plate.001.dpx"], [1], 3),
        ([], [0, 1, 2], PASS_FILE_DIGITS),  # a movie: no files of its own
        (["/p/plate.1.exr", "/p/plate.0002.exr"], [1, 2], PASS_FILE_DIGITS),  # padded two ways
        (["/p/take2_a.exr"], [7], PASS_FILE_DIGITS),  # not named with its number
    ],
)
def test_frame_padding_is_the_plates(names, numbers, padding):
    assert frame_padding(names, numbers) == padding


def test_pass_patterns_of_a_four_digit_plate():
    assert pass_pattern(4) == "atlas.{frame:04d}.exr" and blender_pattern(4) == "atlas.####.exr"
    assert pass_file_name(1001, 4) == "atlas.1001.exr" and pass_file_name(12) == "atlas.00012.exr"
    assert pass_sequence_pattern("atlas.{frame:04d}.exr") == "atlas.%04d.exr"
    assert pass_sequence_pattern("atlas.{frame:01d}.exr") == "atlas.%d.exr"
    assert pass_sequence_pattern("atlas.{frame:05d}.exr") == "atlas.%05d.exr"  # exports made before


@pytest.fixture
def shot(tmp_path) -> Path:
    """A fake export of a plate.1001.png .. plate.1003.png plate, passes atlas.1001.exr .. (manifest pattern 4)."""
    return renumber(fake_export(tmp_path), 1001, 4)


def test_render_names_frames_with_the_plates_padding_by_default(shot, tmp_path):
    out = tmp_path / "out"
    assert run_cli(VERB_RENDER, shot, "--out", out, "--no-bar") == (0, [])
    assert visible_names(out) == ["edit.1001.exr", "edit.1002.exr", "edit.1003.exr"]
    assert Manifest(shot).pass_path(1002).name == "atlas.1002.exr"  # the manifest's pattern, as every reader takes it


@pytest.mark.parametrize(
    ("name", "files"),
    [
        ("shot_v001.####.exr", ["shot_v001.1001.exr", "shot_v001.1002.exr", "shot_v001.1003.exr"]),
        ("shot_v001_%06d.exr", ["shot_v001_001001.exr", "shot_v001_001002.exr", "shot_v001_001003.exr"]),
        ("comp.{x}.##.EXR", ["comp.{x}.1001.EXR", "comp.{x}.1002.EXR", "comp.{x}.1003.EXR"]),  # braces are text
    ],
)
def test_render_name_pattern(shot, tmp_path, name, files):
    out = tmp_path / "out"
    assert run_cli(VERB_RENDER, shot, "--out", out, "--name", name, "--no-bar") == (0, [])
    assert visible_names(out) == files
    default = tmp_path / "default"
    assert run_cli(VERB_RENDER, shot, "--out", default, "--no-bar") == (0, [])
    for f, got in zip((1001, 1002, 1003), files, strict=True):  # the same pixels under the chosen name
        assert read_exr(out / got).keys() == {"R", "G", "B", "A"}
        assert all((read_exr(out / got)[c] == read_exr(default / f"edit.{f}.exr")[c]).all() for c in "RGBA")


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["--name", "shot_v001.exr"], "--name 'shot_v001.exr' has no frame number token (#### or %04d)"),
        (["--name", "s.####.v##.exr"], "has more than one frame number token"),
        (["--name", "shot.####.png"], "does not end in .exr, the extension of these frames"),
        (["--name", "sub/shot.####.exr"], "is not a plain file name — give the folder to --out"),
        (["--name", "shot.####.exr", "--format", "png"], "does not end in .png"),
        (["--name", "shot.%4d.exr"], "--name 'shot.%4d.exr' pads its frame number with spaces"),
        (["--name", "shot.%999999999d.exr"], "pads its frame number with spaces"),
        (["--name", "shot_%s.%04d.exr"], "holds a % that is not its frame token"),
        (["--name", "shot.%%.%04d.exr"], "holds a % that is not its frame token"),
        (["--name", "shot.%0999999999d.exr"], "pads to more than 10 digits"),
        (["--name", f"{'s' * 300}.####.exr"], "is longer than a file name may be"),
    ],
)
def test_a_bad_name_is_one_line_and_writes_nothing(shot, tmp_path, args, said):
    out = tmp_path / "out"
    code, err = run_cli(VERB_RENDER, shot, "--out", out, "--no-bar", *args)
    assert code == C.EXIT_BAD_INPUT and len(err) == 1 and said in err[0], err
    assert not out.exists()


def test_the_nuke_script_reads_the_passes_through_the_manifests_pattern(shot):
    m = Manifest(shot)
    nk = NK.parse(nuke_script(m.data, str(m.path)))
    passes = nk.node("NA_Passes")
    assert passes.knobs["file"] == "passes/atlas.%04d.exr"
    for f in m.frames:
        assert NK.file_for(passes, m.folder, f).samefile(m.pass_path(f))


def test_an_export_made_with_five_digit_passes_still_reads(tmp_path):
    """An export made before the padding followed the plate: a 4-digit plate, passes atlas.01001.exr, and the
    manifest's pattern says so. Render and the Nuke script find its pass files."""
    manifest = renumber(fake_export(tmp_path), 1001, 4)
    data = json.loads(manifest.read_text())
    for f in data["passes"]["frames"]:
        (manifest.parent / "passes" / f"atlas.{f}.exr").rename(manifest.parent / "passes" / f"atlas.{f:05d}.exr")
    data["passes"].update(pattern="atlas.{frame:05d}.exr", blender_pattern="atlas.#####.exr")
    manifest.write_text(json.dumps(data))
    out = tmp_path / "out"
    assert run_cli(VERB_RENDER, manifest, "--out", out, "--no-bar") == (0, [])
    assert visible_names(out) == ["edit.1001.exr", "edit.1002.exr", "edit.1003.exr"]
    nk = NK.parse(nuke_script(data, str(manifest)))
    assert nk.node("NA_Passes").knobs["file"] == "passes/atlas.%05d.exr"
