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
    assert start_frame("0") == 0 and start_frame("1001") == 1001 and start_frame(str(C.MAX_START_FRAME))
    for bad in ("-1", str(C.MAX_START_FRAME + 1), "1e3", "", "x"):
        with pytest.raises(Exception, match=f"from 0 to {C.MAX_START_FRAME}"):
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
    (run / C.RUN_CLIP).write_text("{}")
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
    assert sorted(p.name for p in plate.iterdir()) == before and sorted(p.name for p in run.iterdir()) == [C.RUN_CLIP]
