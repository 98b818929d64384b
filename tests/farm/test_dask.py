"""``farm dask`` on a real Dask scheduler and two workers on 127.0.0.1: a worker killed in the middle of a fit.

Two tiny synthetic shots run through the plan; once shot ``a``'s fit has written a checkpoint past step 0, the
worker running it is killed by its PID (SIGKILL, no nanny to restart it: a lost host). Its engine child must get
SIGTERM from the kernel (it checkpoints and exits), Dask runs the task again on another worker, and the same
``fit --resume-if-started`` argv continues from that checkpoint. Both shots must end with their export published,
every frame's pass present once and no staging left behind.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from bench.farm import local_dask, stop_process
from engine import contract as C
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.errors import InputError
from engine.farm import dask_backend
from engine.farm.dask_backend import TaskFailed, parse_resources, run_task
from engine.farm.plan import load_plan
from engine.terms.cli import EXIT_FAILED, VERB_PREVIEW
from engine.terms.export_names import PASSES_DIR, pass_file_name
from engine.terms.farm import FARM_DASK
from engine.terms.lock import RUN_LOCK, RUN_LOCKED_FIX
from engine.terms.manifest import MANIFEST_TAG, MANIFEST_VERSION
from engine.terms.protocol import EVENT_CANCELLED, EVENT_CHECKPOINT
from engine.terms.run_folder import RUN_LOG
from tests.engine_cli import run_cli
from tests.paths import ROOT

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG and /proc are Linux's")

STEPS = 80
FIT_SETS = [
    f"steps={STEPS}",
    "batch=2000",
    "eval_every=10",
    "bootstrap_steps=50",
    "global_rigidity_steps=50",
    "checkpoint_seconds=0.3",
]
FRAMES = 8
#: Bounds of the waits: hang guards, not timings. The suite runs a test file per core, so another file's fits share
#: the machine; the whole plan took 280 s with the machine loaded five deep.
CHECKPOINT_WAIT = 300.0
CHILD_EXIT_WAIT = 60.0
PLAN_WAIT = 600.0


def write_shots(tmp: Path) -> Path:
    """Two tiny synthetic shots (different seeds), draft with a tiny schedule, exports in chunks of 6 frames."""
    shots = []
    for seed, name in enumerate(("a", "b")):
        frames, masks = write_scene(
            make_scene(SceneSpec(frames=FRAMES, width=128, height=72, fg_size=(28, 20), seed=seed)),
            tmp / "clips" / name,
        )
        shots.append({"name": name, "plate": str(frames), "masks": [str(masks)]})
    defaults = {"preset": "draft", "set": FIT_SETS, "device": "cpu", "export_chunk": 4, "preview": False}
    path = tmp / "shots.json"
    path.write_text(json.dumps({C.SHOTS_TAG: C.SHOTS_VERSION, C.SHOTS_DEFAULTS_KEY: defaults, "shots": shots}))
    return path


def fit_events(run: Path) -> list[dict[str, Any]]:
    """The progress events every attempt of the fit appended to RUN/fit.log, in order."""
    try:
        text = (run / RUN_LOG).read_text(encoding="utf-8")
    except FileNotFoundError:
        return []
    return [m for m in map(C.parse_progress_line, text.splitlines()) if m is not None]


def engine_fit(run: Path) -> tuple[int, int] | None:
    """(pid, parent pid) of the engine process fitting into ``run``, if one runs."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            argv = (entry / "cmdline").read_bytes().split(b"\0")
            status = (entry / "status").read_text()
        except OSError:
            continue
        if b"engine" in argv and b"fit" in argv and str(run).encode() in argv and "State:\tZ" not in status:
            ppid = int(next(line.split()[1] for line in status.splitlines() if line.startswith("PPid:")))
            return int(entry.name), ppid
    return None


def gone(pid: int) -> bool:
    """Whether ``pid`` has exited (a zombie left to a PID 1 that does not reap counts as exited)."""
    try:
        return "State:\tZ" in Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return True


def wait_for(what: str, check: Any, timeout: float, interval: float = 0.1) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = check()
        if value:
            return value
        time.sleep(interval)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")


def checkpoint_past_zero(run: Path) -> bool:
    events = fit_events(run)
    done = any(e["event"] == C.EVENT_DONE for e in events)
    return not done and any(e["event"] == EVENT_CHECKPOINT and e["step"] > 0 for e in events)


@pytest.mark.slow
def test_killed_worker_mid_fit_resumes_and_both_shots_finish(tmp_path: Path) -> None:
    shots_file = write_shots(tmp_path)
    plan = load_plan(shots_file)
    run_a, run_b = tmp_path / "runs" / "a", tmp_path / "runs" / "b"
    stdout, stderr = tmp_path / "farm.out", tmp_path / "farm.err"
    children: list[int] = []
    with local_dask(tmp_path / "cluster", 2, resources="GPU=1") as cluster:
        started = list(cluster.workers)
        argv = [sys.executable, "-m", C.CLI_MODULE, C.VERB_FARM, FARM_DASK, str(shots_file)]
        argv += ["--scheduler", cluster.address, "--fit-resource", "GPU=1", "--threads", "1", "--retries", "1"]
        with open(stdout, "wb") as out, open(stderr, "wb") as err:
            farm = subprocess.Popen(argv, cwd=ROOT, stdin=subprocess.DEVNULL, stdout=out, stderr=err)
        try:
            wait_for("a checkpoint of shot a's fit past step 0", lambda: checkpoint_past_zero(run_a), CHECKPOINT_WAIT)
            child, worker_pid = wait_for("shot a's engine fit", lambda: engine_fit(run_a), 10.0)
            children.append(child)
            assert worker_pid in [w.pid for w in started]  # no nanny: the engine is the worker's own child
            killed = next(w for w in started if w.pid == worker_pid)
            os.kill(killed.pid, signal.SIGKILL)
            killed.wait(10)
            # the kernel told the orphaned engine (PR_SET_PDEATHSIG): it checkpoints and exits on its own
            wait_for("the killed worker's engine to exit", lambda: gone(child), CHILD_EXIT_WAIT)
            cluster.add_worker()  # the host comes back
            returncode = farm.wait(PLAN_WAIT)
        finally:
            stop_process(farm)
            for pid in children:  # bounded clean-up of anything the test saw, by PID
                if not gone(pid):
                    os.kill(pid, signal.SIGKILL)
    for proc in [*cluster.workers, cluster.scheduler, farm]:
        assert proc is not None and proc.returncode is not None  # every process the test started is stopped

    assert returncode == C.EXIT_OK, stderr.read_text()
    lines = stdout.read_text().splitlines()
    assert lines[-1].startswith(f"farm dask: 2 shot(s), {len(plan.tasks)}/{len(plan.tasks)} tasks done in ")
    # the killed fit: a SIGTERM checkpoint mid-way, then the retry continued from it (no new step-0 start)
    events = fit_events(run_a)
    cancelled = [i for i, e in enumerate(events) if e["event"] == EVENT_CANCELLED]
    assert len(cancelled) == 1, [e["event"] for e in events]
    at = cancelled[0]
    step = events[at]["step"]
    assert 0 < step < STEPS
    assert events[at - 1] == {**events[at - 1], "event": EVENT_CHECKPOINT, "step": step}
    after = events[at + 1 :]
    assert [e["stage"] for e in after if e["event"] == C.EVENT_STAGE][:1] != []
    assert not [e for e in after if e["event"] == EVENT_CHECKPOINT and e["step"] <= step]
    first_progress = next(e for e in after if e["event"] == C.EVENT_PROGRESS)
    assert step < first_progress["step"] <= step + 10  # eval_every=10: the next report after the checkpoint
    assert [e["metrics"]["steps"] for e in after if e["event"] == C.EVENT_DONE] == [STEPS]
    assert json.loads((run_a / C.RUN_METRICS).read_text())["steps"] == STEPS
    # shot b was never interrupted: one attempt from step 0
    events_b = fit_events(run_b)
    assert not [e for e in events_b if e["event"] == EVENT_CANCELLED]
    assert next(e["step"] for e in events_b if e["event"] == EVENT_CHECKPOINT) == 0

    # nothing lost or duplicated: one published version per shot, every frame's pass once, no staging left
    for run in (run_a, run_b):
        exports = run / C.EXPORTS_DIR
        assert sorted(p.name for p in exports.iterdir()) == ["v001"]
        manifest = C.load_manifest(str(exports / "v001" / C.MANIFEST_NAME))
        assert manifest[MANIFEST_TAG] == MANIFEST_VERSION
        passes = sorted(p.name for p in (exports / "v001" / PASSES_DIR).iterdir())
        assert passes == [pass_file_name(n) for n in range(FRAMES)]
        leftovers = [p for p in run.rglob("*") if p.name.startswith(".") and p.name != RUN_LOCK]
        assert leftovers == []

    # progress: one line per task, then one done line per shot
    messages = [json.loads(line) for line in lines[:-1]]
    progress = [m for m in messages if m["event"] == C.EVENT_PROGRESS]
    assert sorted(m["task"] for m in progress) == sorted(t.id for t in plan.tasks)
    assert all(m["state"] == "done" for m in progress)
    assert sorted((m["shot"], m["ok"]) for m in messages if m["event"] == C.EVENT_DONE) == [("a", True), ("b", True)]
    for shot in plan.shots:
        mine = [m["done"] for m in progress if m["shot"] == shot]
        assert mine == list(range(1, len(plan.shot_tasks(shot)) + 1))


def test_run_task_does_not_retry_bad_input_and_raises_for_a_crash(tmp_path: Path, monkeypatch: Any) -> None:
    """Exit 2 returns a failed result (Dask retries only exceptions) and its dependents skip; any other failure
    raises ``TaskFailed`` naming the task and the engine's last stderr line, so Dask retries it."""
    missing = tmp_path / "nothing" / C.MANIFEST_NAME
    record = run_task("s.preview", (VERB_PREVIEW, str(missing)), 1, 0.0)
    assert record["state"] == "failed" and record["returncode"] == C.EXIT_BAD_INPUT
    assert str(missing) in record["error"]
    skipped = run_task("s.after", (VERB_PREVIEW, str(missing)), 1, 0.0, record)
    assert skipped["state"] == "skipped" and skipped["error"] == "s.preview did not finish"
    crash = "import sys; print('Traceback: boom', file=sys.stderr); sys.exit(1)"
    monkeypatch.setattr(dask_backend, "engine_argv", lambda args: [sys.executable, "-c", crash])
    with pytest.raises(TaskFailed, match=r"^s\.fit: exit 1: Traceback: boom$"):
        run_task("s.fit", ("fit",), 1, 0.0)


def test_run_task_waits_for_a_locked_run_folder(tmp_path: Path, monkeypatch: Any) -> None:
    """The attempt before still holds the run folder (it is checkpointing): the task runs again until it is free."""
    tries = tmp_path / "tries"
    script = (
        "import sys, pathlib; p = pathlib.Path(sys.argv[1]); n = len(p.read_text()) if p.exists() else 0; "
        "p.write_text('x' * (n + 1)); "
        f"sys.exit(0) if n >= 2 else (print('error: RUN: in use by fit — {RUN_LOCKED_FIX}', file=sys.stderr), "
        f"sys.exit({C.EXIT_BAD_INPUT}))"
    )
    monkeypatch.setattr(dask_backend, "engine_argv", lambda args: [sys.executable, "-c", script, str(tries)])
    monkeypatch.setattr(dask_backend, "LOCK_POLL_SECONDS", 0.05)
    record = run_task("s.fit", ("fit",), 1, 30.0)
    assert record["state"] == "done" and record["locked_waits"] == 2 and tries.read_text() == "xxx"
    tries.unlink()
    record = run_task("s.fit", ("fit",), 1, 0.0)  # no wait allowed: the refusal is the result (bad input)
    assert record["state"] == "failed" and RUN_LOCKED_FIX in record["error"] and tries.read_text() == "x"


def test_parse_resources() -> None:
    assert parse_resources(["GPU=1", "VRAM=24"]) == {"GPU": 1.0, "VRAM": 24.0}
    for bad in ("GPU", "GPU=", "=1", "GPU=0", "GPU=x"):
        with pytest.raises(InputError, match="--fit-resource"):
            parse_resources([bad])


def test_stop_process_is_bounded() -> None:
    """A child that ignores SIGTERM is killed after the grace period."""
    code = "import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); print('up', flush=True); time.sleep(60)"
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE)
    try:
        assert proc.stdout is not None and proc.stdout.readline() == b"up\n"
        start = time.monotonic()
        stop_process(proc, grace=0.5)
        assert proc.returncode == -signal.SIGKILL and time.monotonic() - start < 5
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)


def test_farm_dask_without_a_scheduler_is_one_line(tmp_path: Path) -> None:
    """No scheduler at the address: exit 2 and one line naming it (nothing is submitted)."""
    shots_file = write_shots(tmp_path)
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        address = f"tcp://127.0.0.1:{s.getsockname()[1]}"
    argv = [sys.executable, "-m", C.CLI_MODULE, C.VERB_FARM, FARM_DASK, str(shots_file), "--scheduler", address]
    argv += ["--connect-timeout", "1"]
    proc = subprocess.run(
        argv,
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "2s"},
    )
    assert proc.returncode == C.EXIT_BAD_INPUT, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        f"error: {address}: no Dask scheduler answers (OSError) — start `dask scheduler`, or fix --scheduler"
    ]


@pytest.mark.parametrize("address", ["tcp://host:notaport", "foo bar", "tcp://", "tcp://[::1:8786", "tcp://h:99999"])
def test_a_malformed_scheduler_address_is_one_line_at_once(tmp_path: Path, address: str) -> None:
    """Before: Dask tried to connect for its whole timeout, then a traceback. Now: one line before the plan is made."""
    shots_file = write_shots(tmp_path)
    code, lines = run_cli(C.VERB_FARM, FARM_DASK, shots_file, "--scheduler", address)
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1, lines
    assert lines[0].startswith(f"error: {address}: is not a Dask scheduler address ("), lines
    assert lines[0].endswith("— give --scheduler as tcp://HOST:PORT"), lines


@pytest.mark.slow
def test_farm_dask_bad_input_fails_the_task_and_skips_what_follows(tmp_path: Path) -> None:
    """A fit refused for bad input (exit 2) is not retried: its shot's later tasks are skipped, and `farm dask`
    exits 1 naming the task and the engine's one line."""
    frames, masks = write_scene(make_scene(SceneSpec(frames=4, width=64, height=48, seed=0)), tmp_path / "clip")
    few = tmp_path / "few_masks"
    few.mkdir()
    (few / "00000.png").write_bytes((masks / "00000.png").read_bytes())
    shots_file = tmp_path / "shots.json"
    shot = {"name": "a", "plate": str(frames), "masks": [str(few)]}
    shots_file.write_text(json.dumps({C.SHOTS_TAG: C.SHOTS_VERSION, "defaults": {"preview": False}, "shots": [shot]}))
    plan = load_plan(shots_file)
    with local_dask(tmp_path / "cluster", 1) as cluster:
        argv = [sys.executable, "-m", C.CLI_MODULE, C.VERB_FARM, FARM_DASK, str(shots_file)]
        argv += ["--scheduler", cluster.address, "--retries", "3"]
        proc = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == EXIT_FAILED, proc.stderr
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith(f"error: farm dask: 1 shot(s), 0/{len(plan.tasks)} tasks done in ")
    assert line.endswith(
        f"; task a.fit failed: error: {few}: 1 mask files for a clip of 4 selected frames — provide one mask per "
        "frame, named with the frame numbers (e.g. 00012.png for frame 00012) or exactly one per frame in the same "
        "order"
    )
    messages = [json.loads(m) for m in proc.stdout.splitlines()]
    states = {m["task"]: m["state"] for m in messages if m["event"] == C.EVENT_PROGRESS}
    assert states == {t.id: "failed" if t.kind == "fit" else "skipped" for t in plan.tasks}
    assert [(m["shot"], m["ok"]) for m in messages if m["event"] == C.EVENT_DONE] == [("a", False)]


def test_dask_runs_the_plans_command_lines(tmp_path: Path) -> None:
    """What a worker runs for each task is the plan's own command line, with the worker's Python."""
    plan = load_plan(write_shots(tmp_path))
    python = "/opt/engine/bin/python"
    for task in plan.tasks:
        assert dask_backend.engine_argv(task.args, python) == task.argv(python)
        assert dask_backend.engine_argv(task.args) == task.argv(sys.executable)
