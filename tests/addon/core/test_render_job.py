"""Render Edited Clip's frame list, progress line and ETA (``core.render_job``)."""

from __future__ import annotations

import pytest
from neural_atlas.addon.core import render_job as RJ


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
