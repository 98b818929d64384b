"""``parts CLIP --mask M --out FOLDER``: on a jumping body whose limb swings in front of it, stroke images that
``fit --scribbles`` reads, each stroke inside the part it names; run again, nothing changes; never over another
file; an object that moves as one piece gets no folder, and a bad mask folder is one line."""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np
import pytest

from bench.motion_scenes import make_motion_scene, part_masks, write_motion_clip
from engine import cli
from engine import contract as C
from engine.data.scribbles import NO_LABEL, read_scribbles
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.io.clip import open_clip
from tests.folders import tree_digest


def _parts(*args: object) -> tuple[int, list[str], list[str]]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main([C.VERB_PARTS, *map(str, args)])
    return code, out.getvalue().splitlines(), [line for line in err.getvalue().splitlines() if line.strip()]


@pytest.fixture(scope="module")
def jumping(tmp_path_factory) -> tuple[Path, dict[str, np.ndarray]]:
    """The limbs_jump scene as the bench makes it (480x272, 36 frames)."""
    scene = make_motion_scene("limbs_jump", width=480, height=272, frames=36)
    folder = write_motion_clip(scene, tmp_path_factory.mktemp("scene") / "limbs_jump")
    return folder, part_masks(scene)


@pytest.mark.slow  # the scene at the bench's size and its flow: about 20 s
def test_parts_writes_strokes_inside_each_part_and_a_second_run_changes_nothing(jumping, tmp_path):
    folder, truth = jumping
    out = tmp_path / "strokes"
    code, lines, err = _parts(folder / "frames", "--mask", folder / "masks", "--out", out)
    assert (code, err) == (0, [])
    assert lines[-1] == str(out.resolve())
    assert any(line.startswith("parts: 2 parts that move apart") for line in lines)
    info = open_clip(folder / "frames")
    labels = read_scribbles(out, info, (info.width, info.height))
    assert int((labels != NO_LABEL).any((1, 2)).sum()) >= 5  # strokes on at least five of the six key frames
    body, limb = labels == 0, labels == 1
    assert (body & truth["body"]).sum() >= 0.97 * body.sum() > 0
    assert (limb & truth["front_limb"]).sum() >= 0.97 * limb.sum() > 0
    written = tree_digest(out)
    code, again, err = _parts(folder / "frames", "--mask", folder / "masks", "--out", out)
    assert (code, err) == (0, [])
    assert again[-1] == lines[-1] and any("left as they are" in line for line in again)
    assert tree_digest(out) == written


@pytest.mark.slow  # the scene at the bench's size and its flow: about 20 s
def test_parts_never_writes_over_another_file(jumping, tmp_path):
    folder, _ = jumping
    out = tmp_path / "strokes"
    assert _parts(folder / "frames", "--mask", folder / "masks", "--out", out)[0] == 0
    first = sorted(out.iterdir())[0]
    first.write_bytes(b"an artist's own strokes")
    before = tree_digest(out)
    code, _, err = _parts(folder / "frames", "--mask", folder / "masks", "--out", out)
    assert code == C.EXIT_BAD_INPUT and len(err) == 1
    assert first.name in err[0] and "never overwritten" in err[0]
    assert tree_digest(out) == before


def test_an_object_moving_as_one_piece_gets_no_folder(tmp_path):
    frames, masks = write_scene(make_scene(SceneSpec(width=160, height=96, frames=8, fg_size=(40, 30))), tmp_path)
    out = tmp_path / "strokes"
    code, lines, err = _parts(frames, "--mask", masks, "--out", out)
    assert (code, err) == (0, [])
    assert "nothing to split" in lines[-1] and not out.exists()


@pytest.mark.slow  # the scene at the bench's size and its flow: about 20 s
def test_a_mask_folder_without_masks_is_one_line(jumping, tmp_path):
    folder, _ = jumping
    empty = tmp_path / "empty"
    empty.mkdir()
    code, _, err = _parts(folder / "frames", "--mask", empty, "--out", tmp_path / "strokes")
    assert code == C.EXIT_BAD_INPUT and len(err) == 1 and str(empty) in err[0]
    assert not (tmp_path / "strokes").exists()


@pytest.mark.parametrize("via_link", [False, True])
def test_the_clips_own_frame_folder_is_refused_before_anything_is_computed(tmp_path, via_link):
    """Stroke images named like the frames, beside them, would be read as frames of the clip: refused in one line
    whether ``--out`` names the frame folder or a link to it, and the folder is left as it was."""
    frames, masks = write_scene(make_scene(SceneSpec(width=160, height=96, frames=4)), tmp_path)
    out = Path(frames)
    if via_link:
        out = tmp_path / "strokes"
        out.symlink_to(frames, target_is_directory=True)
    before = tree_digest(Path(frames))
    code, _, err = _parts(frames, "--mask", masks, "--out", out)
    assert code == C.EXIT_BAD_INPUT and len(err) == 1
    assert "own frame folder" in err[0] and "folder of their own" in err[0]
    assert tree_digest(Path(frames)) == before


def test_a_file_as_the_folder_is_one_line(tmp_path):
    frames, masks = write_scene(make_scene(SceneSpec(width=160, height=96, frames=4)), tmp_path)
    out = tmp_path / "strokes.png"
    out.write_bytes(b"not a folder")
    code, _, err = _parts(frames, "--mask", masks, "--out", out)
    assert code == C.EXIT_BAD_INPUT and len(err) == 1
    assert "is a file, not a folder" in err[0] and "strokes" in err[0]
    assert out.read_bytes() == b"not a folder"
