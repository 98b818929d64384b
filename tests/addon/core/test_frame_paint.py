"""Paint on a plate frame without Blender (``core.frame_paint``, ``core.project_job``): where the paint of frame N
lives and where it is kept once landed, which frames are refused and how, the buttons' needs, the engine command,
and the job run with the real engine (its stage lines move the bar; the edit layer file on disk changes) and with a
stand-in engine cancelled (the line says the edit layers are as they were)."""

from __future__ import annotations

import datetime
import os
import re
import time
from pathlib import Path
from types import SimpleNamespace

import fake_export as X
import numpy as np
import pytest
from helpers import engine_python, fake_python
from neural_atlas.addon.core import engine_process as EP
from neural_atlas.addon.core import frame_paint as FP
from neural_atlas.addon.core import progress
from neural_atlas.addon.core.needs import NO_IMPORT
from neural_atlas.addon.core.project_job import ProjectFrameJob

from engine import contract as C
from engine.terms.export_names import EDITS_DIR


def test_the_paint_of_frame_n_lives_beside_the_edit_layers(tmp_path):
    manifest = X.make_export(tmp_path, frames=(1001, 1002))
    folder = FP.frames_dir(str(manifest), C.load_manifest(str(manifest)))
    assert folder == str(tmp_path / "run" / EDITS_DIR / "frames")
    assert FP.paint_file(folder, 1002) == str(tmp_path / "run" / "edits" / "frames" / "frame.01002.png")
    assert FP.paint_file(folder, 7) == os.path.join(folder, "frame.00007.png")


def test_a_manifest_cannot_send_the_paint_outside_its_run_folder(tmp_path):
    manifest = X.make_export(tmp_path)
    data = C.load_manifest(str(manifest))
    data["layers"][0]["edit_layer"] = "/etc/edits/Background.png"
    with pytest.raises(ValueError, match=re.escape("write path '/etc/edits/Background.png' is absolute")) as exc:
        FP.frames_dir(str(manifest), data)
    assert "\n" not in str(exc.value)


def test_a_landed_paint_is_kept_under_a_new_name_each_time(monkeypatch):
    path = "/run/edits/frames/frame.01002.png"
    assert FP.landed_file(path, "20261125-021500-000001") == (
        "/run/edits/frames/landed/frame.01002.20261125-021500-000001.png"
    )
    # the stamp is the clock's, to the microsecond: a clock that ticks 1 us between two landings (not a sleep,
    # whose new timestamp a coarse or stepped clock would not guarantee) gives two names
    ticks = iter([datetime.datetime(2026, 11, 25, 2, 15, 0, 7), datetime.datetime(2026, 11, 25, 2, 15, 0, 8)])
    monkeypatch.setattr(FP, "datetime", SimpleNamespace(datetime=SimpleNamespace(now=lambda: next(ticks))))
    assert [FP.landed_file(path), FP.landed_file(path)] == [
        "/run/edits/frames/landed/frame.01002.20261125-021500-000007.png",
        "/run/edits/frames/landed/frame.01002.20261125-021500-000008.png",
    ]


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


#: Seconds a job may take before the test gives up on it: a guard against a hang only (the real engine starts in
#: seconds; a loaded 2-core machine can take ten times as long), never a measure of speed.
HANG_SECONDS = 300.0


def _drive(job) -> list[dict]:
    """Start and step the job to its end as the modal timer does; every progress message it read, in order."""
    job.start()
    read = []
    deadline = time.monotonic() + HANG_SECONDS
    while time.monotonic() < deadline:
        more = job.step()
        read += job.process.messages
        if not more:
            return read
        time.sleep(0.01)
    raise AssertionError(f"the job did not finish in {HANG_SECONDS:.0f} s")


def _panel(job: ProjectFrameJob, messages: list[dict]) -> list[tuple[float, str]]:
    """The bar and the line the panel shows once each stage is said (its stage line, then its progress line),
    replayed on a job like ``job``: a timer tick sees only the latest of the messages that came since the last
    tick, and how many came between two ticks depends on how loaded the machine is."""
    replay = ProjectFrameJob("py", job.manifest, job.frame, job.paint)
    replay.process = SimpleNamespace(state=progress.JobState())
    shown = []
    for msg in messages:
        replay.state.apply(msg)
        if msg["event"] == C.EVENT_PROGRESS:
            shown.append((replay.fraction, replay.status_text()))
    return shown


def test_the_job_lands_paint_with_the_real_engine_and_shows_its_stages(tmp_path):
    python = engine_python(C.VERB_PROJECT_FRAME, "cv2, scipy")
    manifest = X.make_export(tmp_path)
    paint = np.zeros((X.H, X.W, 4), np.uint8)
    paint[8:16, 14:22] = (255, 40, 0, 255)  # over the foreground disc at frame 3
    X.write_png(tmp_path / "paint.png", paint)
    edit = tmp_path / "run" / "edits" / "Foreground.png"
    before = edit.read_bytes()
    job = ProjectFrameJob(python, str(manifest), 3, str(tmp_path / "paint.png"))
    shown = _panel(job, _drive(job))
    assert job.result is not None and job.result.status == EP.STATUS_OK, job.result
    assert job.landed["Foreground"] == str(edit) and edit.read_bytes() != before
    assert len(list((edit.parent / "history").glob("Foreground.*.png"))) == 1
    assert shown == [
        (0.0, f"{FP.LAND_LABEL} 1/3: reading the paint and the passes of frame 3"),
        (1 / 3, f"{FP.LAND_LABEL} 2/3: projecting the paint into the atlases of the layers that own it"),
        (2 / 3, f"{FP.LAND_LABEL} 3/3: writing {len(job.landed)} edit layer(s), the previous ones kept in history/"),
    ]  # the last stage started: two of three done
    assert (job.fraction, job.status_text()) == shown[-1]  # what the panel shows once the job has ended
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
