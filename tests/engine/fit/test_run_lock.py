"""Two processes, one run folder: ``fit`` holds the folder's lock (``contract.run_lock`` through
``RunFolder.lock``) for its whole write, so a second ``fit``, ``fit --resume`` or ``fit --refit`` into it is
refused at once with one line naming the holder, exit 2, and changes nothing; the first fit finishes and the
folder then resumes and exports as any other.

The processes are real children (``python -m engine fit ...``); the first is paused with SIGSTOP while the
others try, so the folder is provably unchanged by them (a running fit keeps writing its log and checkpoints).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from engine import contract as C
from engine.config import apply_overrides, preset_config
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.errors import InputError
from engine.fit import trainer
from engine.fit.fit_inputs import FitInputs
from engine.fit.run_folder import RunFolder
from engine.terms.lock import RUN_LOCK
from tests.engine.fit_helpers import quiet_fit
from tests.folders import tree_digest
from tests.paths import ROOT

SPEC = SceneSpec(width=48, height=32, frames=4, fg_size=(16, 12), fg_start=(10.0, 8.0))
#: Long enough that the first fit is still training when it is paused (it is paused at step PAUSE_AT).
STEPS = 300
PAUSE_AT = 5
SETS = [f"steps={STEPS}", "batch=256", "eval_every=1", "eval_pixels=500", "checkpoint_seconds=0.2"]
#: Seconds any one child may take (they take a few; this only stops a hung test).
TIMEOUT_S = 600


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> tuple[Path, Path]:
    return write_scene(make_scene(SPEC), tmp_path_factory.mktemp("lock") / "clip")


def _fit_argv(clip: tuple[Path, Path], run: Path, *extra: str) -> list[str]:
    frames, masks = clip
    sets = [a for s in SETS for a in ("--set", s)]
    return ["fit", str(frames), "--mask", str(masks), "--out", str(run), "--preset", "draft", "--no-bar", *sets, *extra]


def _engine(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "engine", *argv], cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT_S
    )


def _one_line(out: subprocess.CompletedProcess) -> str:
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), out.stderr
    return lines[0]


def _start_and_pause(argv: list[str]) -> subprocess.Popen:
    """Start ``python -m engine ARGV`` and stop it (SIGSTOP) once it has trained PAUSE_AT steps: it holds the
    run folder's lock and writes nothing while paused."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "engine", *argv], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None
    for line in proc.stdout:
        msg = C.parse_progress_line(line)
        if msg and msg["event"] == C.EVENT_PROGRESS and msg["step"] >= PAUSE_AT:
            break
    else:
        pytest.fail(f"the first fit ended before step {PAUSE_AT}: {proc.communicate()[1]}")
    os.kill(proc.pid, signal.SIGSTOP)
    return proc


@pytest.mark.slow
def test_a_second_fit_into_a_folder_in_use_is_refused_and_the_first_finishes(tmp_path, clip):
    run = tmp_path / "run"
    first = _start_and_pause(_fit_argv(clip, run))
    try:
        before = tree_digest(run)
        for extra in ([], ["--refit"]):
            line = _one_line(refused := _engine(*_fit_argv(clip, run, *extra)))
            assert refused.returncode == C.EXIT_BAD_INPUT
            assert f"in use by fit (pid {first.pid} on " in line and "wait for it to finish" in line, line
        resumed = _engine("fit", "--resume", "--out", str(run), "--no-bar")
        assert resumed.returncode == C.EXIT_BAD_INPUT and f"pid {first.pid}" in _one_line(resumed)
        assert tree_digest(run) == before, "a refused fit changed the folder in use"
    finally:
        os.kill(first.pid, signal.SIGCONT)
    _, err = first.communicate(timeout=TIMEOUT_S)
    assert first.returncode == C.EXIT_OK, err
    assert RunFolder(run).read_metrics()["steps"] == STEPS

    # the lock went with the first process: the folder resumes (nothing left to do) and exports
    again = _engine("fit", "--resume", "--out", str(run), "--no-bar")
    assert again.returncode == C.EXIT_OK, again.stderr
    exported = _engine("export", str(run), "--no-bar", "--atlas-size", "64")
    assert exported.returncode == C.EXIT_OK, exported.stderr
    assert Path(exported.stdout.strip().splitlines()[-1]).is_file()


@pytest.mark.slow
def test_a_fit_is_refused_while_another_verb_holds_the_folder(tmp_path, clip):
    """``RunFolder(path).lock(what)`` is how the other writers (export, project-frame) hold a run folder: a fit
    meanwhile is one line naming that verb."""
    run = tmp_path / "run"
    code = "import sys, time; from engine.fit.run_folder import RunFolder\n"
    code += "with RunFolder(sys.argv[1]).lock('export'):\n    print('held', flush=True); time.sleep(600)"
    holder = subprocess.Popen([sys.executable, "-c", code, str(run)], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        out = _engine(*_fit_argv(clip, run))
        assert out.returncode == C.EXIT_BAD_INPUT
        assert f"in use by export (pid {holder.pid} on " in _one_line(out)
        assert tree_digest(run) == {}
    finally:
        holder.kill()
        holder.wait(timeout=TIMEOUT_S)


def test_the_refit_rule_is_checked_again_under_the_lock(tmp_path, clip, monkeypatch):
    """Two fits started into the same new folder: the one that takes the lock second finds the other's fit
    there (its checkpoint, written between this fit's reading of the clip and its lock) and is refused."""
    frames, masks = clip
    run = tmp_path / "run"
    real_prepare = trainer.prepare_clip

    def prepare(*args, before_writing, **kwargs):  # type: ignore[no-untyped-def]
        def meanwhile() -> None:
            run.mkdir()
            (run / C.RUN_CHECKPOINT).write_bytes(b"the other fit's checkpoint")
            before_writing()

        return real_prepare(*args, before_writing=meanwhile, **kwargs)

    monkeypatch.setattr(trainer, "prepare_clip", prepare)
    cfg = apply_overrides(preset_config("draft"), {"steps": "2", "batch": "64"})
    with pytest.raises(InputError, match="already holds a fit") as err:
        quiet_fit(run, cfg, FitInputs(frames, [masks]))
    assert "\n" not in str(err.value)
    assert (run / C.RUN_CHECKPOINT).read_bytes() == b"the other fit's checkpoint"
    assert sorted(p.name for p in run.iterdir()) == sorted([C.RUN_CHECKPOINT, RUN_LOCK])
