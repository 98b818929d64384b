"""What the engine's progress lines say (``core.progress``): the progress bar's state, durations, the log."""

from __future__ import annotations

from neural_atlas.addon.core import progress

from engine import contract as C


def _apply(state: progress.JobState, event: str, **fields) -> None:
    msg = C.parse_progress_line(C.progress_line(event, **fields))
    assert msg is not None
    state.apply(msg)


def test_state_follows_each_event():
    st = progress.JobState()
    assert st.summary() == "starting…" and st.fraction == 0.0
    _apply(st, C.EVENT_STAGE, stage="flow", message="optical flow")
    assert st.summary() == "optical flow"
    _apply(st, C.EVENT_PROGRESS, step=5, total=10, psnr=21.04, eta=3725.0)
    assert st.fraction == 0.5 and st.summary() == "step 5/10 · 21.0 dB · ETA 1h02m"
    _apply(st, C.EVENT_CHECKPOINT, step=5, path="/run/checkpoint.pt")
    _apply(st, C.EVENT_DONE, metrics={"psnr": 30.0})
    _apply(st, C.EVENT_EXPORTED, manifest="/run/exports/v001/manifest.json")
    _apply(st, C.EVENT_ERROR, message="out of memory")
    assert (st.metrics, st.manifest, st.error) == (
        {"psnr": 30.0},
        "/run/exports/v001/manifest.json",
        "out of memory",
    )
    _apply(st, C.EVENT_PROGRESS, step=20, total=10)
    assert st.fraction == 1.0


def test_stderr_tail_keeps_the_last_lines_and_skips_bar_redraws():
    st = progress.JobState()
    for i in range(progress.STDERR_TAIL_LINES + 5):
        st.note_stderr(f"line {i}\n")
    st.note_stderr(" 40%|####\r 41%|####")
    st.note_stderr("   ")
    assert len(st.stderr_tail) == progress.STDERR_TAIL_LINES
    assert st.stderr_tail[-1] == f"line {progress.STDERR_TAIL_LINES + 4}"


def test_format_seconds():
    assert [progress.format_seconds(s) for s in (0, 42.4, 95, 3725, -3)] == ["0s", "42s", "1m35s", "1h02m", "0s"]


def test_logged_events_of_one_kind(tmp_path):
    log = tmp_path / "x.log"
    log.write_text(
        "$ python -m engine masks\n"
        + C.progress_line(C.EVENT_STAGE, stage="flow")
        + "\n"
        + C.progress_line(C.EVENT_MASKS, found=True, message="6/6")
        + "\n[exit code 0]\n"
    )
    assert [m["message"] for m in progress.logged_events(str(log), C.EVENT_MASKS)] == ["6/6"]
    assert progress.logged_events(str(tmp_path / "missing.log"), C.EVENT_MASKS) == []
    assert progress.read_log(str(tmp_path / "missing.log")) == ""
