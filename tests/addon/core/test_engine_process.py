"""One engine process (``core.engine_process``) with a stand-in engine: progress lines followed, noise ignored,
cancel, timeout, crashes and bad input as results; the blocking loop every job shares."""

from __future__ import annotations

import sys
import time

import pytest
from helpers import HERE, fake_python
from neural_atlas.addon.core import engine_commands as EC
from neural_atlas.addon.core import engine_process as EP
from neural_atlas.addon.core import progress

from engine import contract as C
from engine.terms.protocol import EVENT_CANCELLED

FAKE = [sys.executable, str(HERE / "fake_engine.py")]


def _job(tmp_path, *verb_args: str) -> EP.EngineJob:
    """The stand-in engine running ``verb_args`` (FAKE_ENGINE_MODE picks its behaviour), started."""
    return EP.EngineJob([*FAKE, *verb_args], str(tmp_path / "log")).start()


def _hanging_fit(tmp_path, monkeypatch, until_step: int) -> EP.EngineJob:
    """A fit that never ends by itself, polled until it has reported ``until_step`` steps."""
    monkeypatch.setenv("FAKE_ENGINE_MODE", "hang")
    job = _job(tmp_path, "fit", "clip", "--out", str(tmp_path / "run"))
    while job.state.step < until_step:
        job.poll()
        time.sleep(0.02)
    return job


def test_job_reads_progress_and_ignores_noise(tmp_path):
    seen = []
    result = _job(tmp_path, "fit", "clip", "--out", str(tmp_path / "run")).wait(on_message=seen.append)
    assert result.status == EP.STATUS_OK and result.returncode == 0
    steps = [m["step"] for m in seen if m["event"] == C.EVENT_PROGRESS]
    assert steps == list(range(1, 11))
    assert result.metrics == {"psnr": 30.0, "steps": 10}
    log = (tmp_path / "log").read_text()
    assert "tqdm-like noise" in log and "[exit code 0]" in log


def test_job_state_summary_has_step_psnr_eta():
    st = progress.JobState()
    st.apply({"event": C.EVENT_PROGRESS, "step": 30, "total": 120, "psnr": 24.56, "eta": 95.0})
    assert st.fraction == 0.25
    assert st.summary() == "step 30/120 · 24.6 dB · ETA 1m35s"


def test_job_cancel_sends_sigterm_and_reports_cancelled(tmp_path, monkeypatch):
    """The engine stops on the SIGTERM itself, with a checkpoint: its own exit code, not the -9 of the kill that
    ends an engine still running after ``CANCEL_GRACE_SECONDS`` (what a time limit here would stand for, without
    depending on how loaded the machine is)."""
    job = _hanging_fit(tmp_path, monkeypatch, 3)
    job.cancel()
    seen = []
    result = job.wait(on_message=seen.append)
    assert result.status == EP.STATUS_CANCELLED and result.returncode == C.EXIT_CANCELLED
    cancelled = [m for m in seen if m["event"] == EVENT_CANCELLED]
    assert len(cancelled) == 1 and cancelled[0]["step"] >= 3
    assert result.message == f"cancelled at step {cancelled[0]['step']}; Resume continues from the checkpoint"
    assert (tmp_path / "run" / C.RUN_CHECKPOINT).read_text() == "fake"


def test_jobs_still_running_at_exit_are_cancelled(tmp_path, monkeypatch):
    """Engines run in their own session; when Blender quits, atexit asks them to stop (checkpoint)."""
    job = _hanging_fit(tmp_path, monkeypatch, 1)
    EP._stop_live_jobs()
    assert job.wait(timeout=10).status == EP.STATUS_CANCELLED


def test_job_timeout_cancels(tmp_path, monkeypatch):
    monkeypatch.setenv("FAKE_ENGINE_MODE", "hang")
    result = _job(tmp_path, "fit", "c", "--out", str(tmp_path / "r")).wait(0.5)
    assert result.status == EP.STATUS_CANCELLED


@pytest.mark.parametrize(
    ("mode", "status", "words"),
    [
        ("crash", EP.STATUS_FAILED, "killed by signal 9"),
        ("traceback", EP.STATUS_FAILED, "RuntimeError: simulated engine bug"),
        ("bad_input", EP.STATUS_BAD_INPUT, "mask folder does not exist"),
    ],
)
def test_job_failures_become_results(tmp_path, monkeypatch, mode, status, words):
    monkeypatch.setenv("FAKE_ENGINE_MODE", mode)
    result = _job(tmp_path, "fit", "c", "--out", str(tmp_path / "r")).wait()
    assert result.status == status
    assert words in result.message
    assert result.log_path == str(tmp_path / "log")


def test_job_missing_interpreter_is_a_result_not_an_exception(tmp_path):
    result = EP.EngineJob([str(tmp_path / "no_python"), "-m", "engine"], str(tmp_path / "log")).start().wait()
    assert result.status == EP.STATUS_FAILED and result.returncode is None
    assert "cannot start the engine" in result.message


def test_job_refuses_a_shell_string(tmp_path):
    with pytest.raises(TypeError):
        EP.EngineJob("python -m engine fit", str(tmp_path / "log"))


def test_export_manifest_from_last_stdout_line(tmp_path):
    result = _job(tmp_path, "export", str(tmp_path / "run")).wait()
    assert result.status == EP.STATUS_OK
    assert result.manifest and result.manifest.endswith(C.MANIFEST_NAME)
    C.load_manifest(result.manifest)


def test_fake_python_wrapper_speaks_version(tmp_path):
    job = EP.EngineJob(EC.version_argv(fake_python(tmp_path)), str(tmp_path / "log")).start()
    assert job.wait().status == EP.STATUS_OK
    assert job.state.last_stdout.startswith("neural-atlas engine")


def test_step_drains_everything_once_the_process_is_done(tmp_path):
    """``step()`` is what the modal timer and the blocking loop call: False only once all output is read."""
    job = _job(tmp_path, "fit", "clip", "--out", str(tmp_path / "run"))
    steps = []
    while job.step():
        steps += [m["step"] for m in job.messages if m["event"] == C.EVENT_PROGRESS]
        time.sleep(0.01)
    steps += [m["step"] for m in job.messages if m["event"] == C.EVENT_PROGRESS]
    assert steps == list(range(1, 11)) and job.result().status == EP.STATUS_OK
    assert not job.step()  # done stays done


class _Countdown:
    """A job that needs ``n`` steps, or runs until cancelled (n None); records what the loop did."""

    def __init__(self, n: int | None):
        self.n, self.steps, self.cancels = n, 0, 0

    def step(self) -> bool:
        self.steps += 1
        return self.cancels == 0 if self.n is None else self.steps < self.n

    def cancel(self) -> None:
        self.cancels += 1


def test_run_blocking_steps_to_the_end_and_reports_every_step():
    job, seen = _Countdown(3), []
    EP.run_blocking(job, on_step=lambda: seen.append(job.steps), interval=0)
    assert seen == [1, 2, 3] and job.cancels == 0


class _Clock:
    """``time`` for ``engine_process`` that moves only when slept: the timeout falls on a known step, however
    slowly a loaded machine runs the loop."""

    def __init__(self) -> None:
        self.now = 0.0

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds


def test_run_blocking_cancels_once_past_the_timeout_and_still_steps_to_the_end(monkeypatch):
    monkeypatch.setattr(EP, "time", _Clock())
    job = _Countdown(None)
    EP.run_blocking(job, timeout=2.5, interval=1.0)
    # steps at t = 0, 1, 2, 3: past 2.5 s after the 4th, cancelled once; the 5th step sees the job end
    assert (job.steps, job.cancels) == (5, 1)


def test_cancel_is_logged(tmp_path, monkeypatch):
    job = _hanging_fit(tmp_path, monkeypatch, 1)
    job.cancel()
    job.wait()
    assert "cancel requested: SIGTERM" in (tmp_path / "log").read_text()
