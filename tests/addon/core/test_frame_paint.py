"""Paint on a plate frame without Blender (``core.frame_paint``, ``core.project_job``): where the paint of frame N
lives and where it is kept once landed, which frames are refused and how, the buttons' needs, the engine command,
and the job run with the real engine (its stage lines move the bar; the edit layer file on disk changes) and with a
stand-in engine cancelled (the line says the edit layers are as they were)."""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

import fake_export as X
import numpy as np
import pytest
from helpers import engine_python, fake_python
from neural_atlas.addon.core import engine_process as EP
from neural_atlas.addon.core import frame_paint as FP
from neural_atlas.addon.core.needs import NO_IMPORT
from neural_atlas.addon.core.project_job import ProjectFrameJob

from engine import contract as C


def test_the_paint_of_frame_n_lives_beside_the_edit_layers(tmp_path):
    manifest = X.make_export(tmp_path, frames=(1001, 1002))
    folder = FP.frames_dir(str(manifest), C.load_manifest(str(manifest)))
    assert folder == str(tmp_path / "run" / C.EDITS_DIR / "frames")
    assert FP.paint_file(folder, 1002) == str(tmp_path / "run" / "edits" / "frames" / "frame.01002.png")
    assert FP.paint_file(folder, 7) == os.path.join(folder, "frame.00007.png")


def test_a_manifest_cannot_send_the_paint_outside_its_run_folder(tmp_path):
    manifest = X.make_export(tmp_path)
    data = C.load_manifest(str(manifest))
    data["layers"][0]["edit_layer"] = "/etc/edits/Background.png"
    with pytest.raises(ValueError, match=re.escape("write path '/etc/edits/Background.png' is absolute")) as exc:
        FP.frames_dir(str(manifest), data)
    assert "\n" not in str(exc.value)


def test_a_landed_paint_is_kept_under_a_new_name_each_time():
    path = "/run/edits/frames/frame.01002.png"
    assert FP.landed_file(path, "20261125-021500-000001") == (
        "/run/edits/frames/landed/frame.01002.20261125-021500-000001.png"
    )
    a, b = FP.landed_file(path), (time.sleep(0.001), FP.landed_file(path))[1]
    assert a != b and os.path.dirname(a) == "/run/edits/frames/landed"


def test_frames_without_passes_are_refused_in_one_line():
    assert FP.frame_refusal(1002, [1001, 1002, 1003]) is None
    line = FP.frame_refusal(7, [1001, 1002, 1003])
    assert line == "Frame 7 has no passes in the imported export (frames 1001-1003): go to a frame inside it"
    assert FP.frame_refusal(1, []) == "The imported export has no passes: export the run again"


def test_the_buttons_say_what_they_need():
    assert FP.start_need("") == NO_IMPORT
    assert FP.start_need("/run/exports/v001/manifest.json") is None
    m = "/run/exports/v001/manifest.json"
    assert FP.land_need("", 3, True) == NO_IMPORT
    assert FP.land_need(m, None, False) == "Nothing to land: press Paint on Frame at the frame to paint on first"
    assert FP.land_need(m, 1002, False) == (
        "Nothing to land: the frame paint of frame 1002 is empty (paint over the plate first)"
    )
    assert FP.land_need(m, 1002, True) is None
    for line in (FP.NO_FRAME_PAINT, FP.EMPTY_PAINT.format(frame=1002)):
        assert len(line) < 200 and "\n" not in line  # Blender quotes at most 200 characters


def test_one_8bit_step_of_alpha_is_paint():
    assert not FP.has_paint(0.0) and not FP.has_paint(0.4 / 255)
    assert FP.has_paint(1 / 255) and FP.has_paint(1.0)


def test_the_engine_command_and_what_it_says_it_landed():
    argv = FP.project_frame_argv("/py", "/run/exports/v001/manifest.json", 1002, "/run/edits/frames/frame.01002.png")
    assert argv == [
        "/py",
        "-m",
        C.CLI_MODULE,
        C.VERB_PROJECT_FRAME,
        "/run/exports/v001/manifest.json",
        "--frame",
        "1002",
        "--edit",
        "/run/edits/frames/frame.01002.png",
    ]
    lines = ["Foreground: paint landed in /run/edits/Foreground.png", "warning: x", "Background: paint landed in /b"]
    assert FP.landed_layers(lines) == {"Foreground": "/run/edits/Foreground.png", "Background": "/b"}
    assert FP.log_file("/shots/run/exports/v001/manifest.json") == "/shots/run.frame-paint.log"


def _drive(job, limit: int = 3000) -> list[tuple[float, str]]:
    job.start()
    seen = []
    for _ in range(limit):
        more = job.step()
        seen.append((job.fraction, job.status_text()))
        if not more:
            return seen
        time.sleep(0.01)
    raise AssertionError("the job never finished")


def test_the_job_lands_paint_with_the_real_engine_and_shows_its_stages(tmp_path):
    python = engine_python(C.VERB_PROJECT_FRAME, "cv2, scipy")
    manifest = X.make_export(tmp_path)
    paint = np.zeros((X.H, X.W, 4), np.uint8)
    paint[8:16, 14:22] = (255, 40, 0, 255)  # over the foreground disc at frame 3
    X.write_png(tmp_path / "paint.png", paint)
    edit = tmp_path / "run" / "edits" / "Foreground.png"
    before = edit.read_bytes()
    job = ProjectFrameJob(python, str(manifest), 3, str(tmp_path / "paint.png"))
    seen = _drive(job)
    assert job.result is not None and job.result.status == EP.STATUS_OK, job.result
    assert job.landed["Foreground"] == str(edit) and edit.read_bytes() != before
    assert len(list((edit.parent / "history").glob("Foreground.*.png"))) == 1
    stages = [text for _, text in seen if text.startswith(FP.LAND_LABEL)]
    assert any(" 1/3: reading" in t for t in stages) and any(" 3/3: writing" in t for t in stages), stages
    assert max(f for f, _ in seen) == 2 / 3  # the last stage started: two of three done
    assert Path(job.log_path).read_text().count(C.VERB_PROJECT_FRAME) >= 1


def test_a_cancelled_job_says_the_edit_layers_are_as_they_were(tmp_path, monkeypatch):
    monkeypatch.setenv("FAKE_ENGINE_MODE", "hang")
    job = ProjectFrameJob(fake_python(tmp_path), str(tmp_path / "run" / "m.json"), 3, str(tmp_path / "p.png"))
    job.start()
    while job.step() and job.state.step < 2:
        time.sleep(0.01)
    job.cancel()
    assert job.status_text() == job.cancel_text
    while job.step():
        time.sleep(0.01)
    assert job.result is not None and job.result.status == EP.STATUS_CANCELLED
    assert job.result.message == "cancelled: the edit layers are as they were" and job.landed == {}
