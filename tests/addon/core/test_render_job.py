"""Render Edited Clip's frame list, progress line and ETA (``core.render_job``)."""

from __future__ import annotations

import re

import pytest
from neural_atlas.addon.core import render_job as RJ

from engine.edit.render import frame_name_pattern
from engine.terms.export_names import PASS_FILE_DIGITS, RENDER_FRAME_PREFIX, frame_padding


def test_frame_list_is_an_animation_renders_frames():
    assert RJ.frame_list(1011, 1014) == [1011, 1012, 1013, 1014]
    assert RJ.frame_list(3, 9, 3) == [3, 6, 9]
    assert RJ.frame_list(5, 5) == [5]
    assert RJ.frame_list(5, 4) == []
    assert RJ.frame_list(1, 3, 0) == [1, 2, 3]  # a step below 1 renders every frame


def test_steps_are_frames_or_one_movie():
    assert RJ.steps_for("exr", [3, 4]) == [3, 4]
    assert RJ.steps_for("png", [3, 4]) == [3, 4]
    assert RJ.steps_for("movie", [3, 4]) == [None]


def test_progress_line_and_eta():
    p = RJ.RenderProgress(total=12)
    assert p.summary() == "frame 0/12" and p.eta() is None and p.fraction == 0.0
    p.add(2.0)
    p.add(4.0)
    assert p.fraction == pytest.approx(2 / 12)
    assert p.eta() == pytest.approx(10 * 3.0)  # ten frames left at the mean 3 s a frame
    assert p.summary() == "frame 2/12 · ETA 30s"
    for _ in range(10):
        p.add(3.0)
    assert p.finished and p.summary() == "frame 12/12"
    assert p.report("/out") == "rendered 12 frame(s) to /out"


def test_cancelled_render_says_the_finished_frames_stay():
    p = RJ.RenderProgress(total=50)
    p.add(1.0)
    p.cancelled = True
    assert p.report("/out") == "render cancelled after 1/50 frames; the finished frames stay in /out"


def test_a_movie_is_one_step_and_says_so():
    p = RJ.RenderProgress(total=1, movie=True, frames=48)
    assert p.summary() == "rendering the movie (48 frames) in one go…"
    p.add(20.0)
    assert p.finished and p.report("/out") == "rendered the movie to /out"


def _blender_name(template: str, frame: int, ext: str) -> str:
    """The file Blender writes for ``frame`` from an output path ``template``: its run of ``#`` replaced by the frame
    number zero-padded to as many digits (``RenderSettings.frame_path``), the format's extension added."""
    return re.sub(r"#+", lambda m: f"{frame:0{len(m.group())}d}", template) + ext


def _sequence(names: list[str], numbers: list[int]) -> dict:
    return {"kind": "sequence", "frame_files": [f"/shot/plate/{n}" for n in names], "frame_numbers": numbers}


#: (the manifest's clip record, the template): a shot's own four digits, the fake exports' five, a plate padded to
#: none, a movie (no files), names padded two ways, names that are not the frame number, no record at all.
CLIPS = [
    (_sequence(["plate.1001.png", "plate.1002.png", "plate.1003.png"], [1001, 1002, 1003]), "edit.####"),
    (_sequence([f"plate.{n:04d}.exr" for n in range(998, 1002)], list(range(998, 1002))), "edit.####"),
    (_sequence(["00003.png", "00004.png", "00005.png"], [3, 4, 5]), "edit.#####"),
    (_sequence(["f9.png", "f10.png"], [9, 10]), "edit.#"),
    (_sequence(["shot_000012.dpx"], [12]), "edit.######"),
    ({"kind": "movie", "frame_files": [], "frame_numbers": [0, 1, 2], "start_frame": 0}, "edit.#####"),
    (_sequence(["plate.1.exr", "plate.0002.exr"], [1, 2]), "edit.#####"),
    (_sequence(["take2_a.exr"], [7]), "edit.#####"),
    ({}, "edit.#####"),
]


@pytest.mark.parametrize(("clip", "template"), CLIPS)
def test_frames_are_named_as_engine_render_names_them(clip, template):
    """Render Edited Clip's template is ``edit.`` + a ``#`` per digit of ``frame_padding`` (the engine's one rule), so
    every frame Blender writes from it has the name ``engine render`` gives the same frame by default."""
    assert RJ.output_template(clip) == template
    numbers = clip.get("frame_numbers") or [0, 1]
    padding = frame_padding(clip.get("frame_files") or [], numbers)
    assert template == RENDER_FRAME_PREFIX + "#" * padding
    for ext in (".exr", ".png"):
        engine = frame_name_pattern(None, ext, padding)  # engine render's default names for this export
        for frame in [*numbers, numbers[-1] + 1, 12345]:  # a number longer than the padding keeps its digits
            assert _blender_name(template, frame, ext) == engine.format(frame=frame)


def test_a_shots_frames_keep_its_four_digits():
    clip = CLIPS[0][0]
    names = [_blender_name(RJ.output_template(clip), f, ".exr") for f in clip["frame_numbers"]]
    assert names == ["edit.1001.exr", "edit.1002.exr", "edit.1003.exr"]
    assert RJ.output_template({}) == "edit." + "#" * PASS_FILE_DIGITS  # no plate files: the engine's default
