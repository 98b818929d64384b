"""What the engine's progress lines say (``core.progress``): the progress bar's state, durations, the log."""

from __future__ import annotations

from neural_atlas.addon.core import progress

from engine import contract as C
from engine.terms.protocol import EVENT_CHECKPOINT, progress_line


def _apply(state: progress.JobState, event: str, **fields) -> None:
    msg = C.parse_progress_line(progress_line(event, **fields))
    assert msg is not None
    state.apply(msg)


def test_state_follows_each_event():
    st = progress.JobState()
    assert st.summary() == "starting…" and st.fraction == 0.0
    _apply(st, C.EVENT_STAGE, stage="flow", message="optical flow")
    assert st.summary() == "optical flow"
    _apply(st, C.EVENT_PROGRESS, step=5, total=10, psnr=21.04, eta=3725.0)
    assert st.fraction == 0.5 and st.summary() == "step 5/10 · 21.0 dB · ETA 1h02m"
    _apply(st, EVENT_CHECKPOINT, step=5, path="/run/checkpoint.pt")
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
        + progress_line(C.EVENT_STAGE, stage="flow")
        + "\n"
        + progress_line(C.EVENT_MASKS, found=True, message="6/6")
        + "\n[exit code 0]\n"
    )
    assert [m["message"] for m in progress.logged_events(str(log), C.EVENT_MASKS)] == ["6/6"]
    assert progress.logged_events(str(tmp_path / "missing.log"), C.EVENT_MASKS) == []
    assert progress.read_log(str(tmp_path / "missing.log")) == ""


def _job(state: progress.JobState, stage: str, done: int, total: int, stage_eta, fraction, eta) -> None:
    _apply(state, C.EVENT_JOB, stage=stage, done=done, total=total, stage_eta=stage_eta, job_fraction=fraction,
           job_eta=eta)  # fmt: skip


def test_whole_job_progress_through_every_stage():
    """A fit's messages as the engine sends them: the flow's pairs, training (between the live-PSNR steps too),
    the evaluation; the bar is the whole job's fraction and the ETA says that it is the whole fit's."""
    st = progress.JobState()
    _job(st, "flow", 2, 4, 3.0, 0.025, None)
    assert st.fraction == 0.025 and st.summary("fit") == "optical flow 2/4 · ETA 3s for the flow"
    _job(st, "train", 0, 2000, None, 0.05, None)
    assert st.summary("fit") == "step 0/2000" and st.fraction == 0.05
    _apply(st, C.EVENT_PROGRESS, step=100, total=2000, psnr=24.13, eta=150.0, job_fraction=0.1, job_eta=190.0)
    assert st.summary("fit") == "step 100/2000 · 24.1 dB · ETA 3m10s for the whole fit" and st.fraction == 0.1
    _job(st, "train", 140, 2000, 140.0, 0.12, 178.0)  # a step between two live-PSNR steps: the count moves
    assert st.summary("fit") == "step 140/2000 · 24.1 dB · ETA 2m58s for the whole fit" and st.step == 140
    _job(st, "train", 150, 2000, 139.0, 0.11, 177.0)  # a fraction lower than shown: the bar does not go back
    assert st.fraction == 0.12
    _job(st, "evaluate", 0, 1, 4.0, 0.9, 30.0)
    assert st.summary("fit") == "evaluating every pixel · ETA 30s for the whole fit"
    _job(st, "export", 3, 6, 1.0, 0.5, 1.0)
    assert st.summary("fit") == "exporting passes 3/6 · ETA 1s for the whole fit"


def test_estimate_progress_lines_are_shown():
    """Estimate Time's progress (the engine's ``estimate --json`` prints ``job`` lines before its result): the bar
    moves preset by preset and the line says how many are timed."""
    st = progress.JobState()
    _job(st, "estimate", 0, 4, None, 0.05, None)
    assert st.summary("estimate") == "timing the presets 0/4" and st.fraction == 0.05
    _job(st, "estimate", 1, 4, 36.0, 0.2875, 36.0)
    assert st.summary("estimate") == "timing the presets 1/4 · ETA 36s for the whole estimate"
    assert st.fraction == 0.2875


def test_an_engine_without_whole_job_messages_reads_as_before():
    st = progress.JobState()
    _apply(st, C.EVENT_PROGRESS, step=5, total=10, psnr=21.04, eta=65.0)
    assert st.fraction == 0.5 and st.summary("fit") == "step 5/10 · 21.0 dB · ETA 1m05s"
