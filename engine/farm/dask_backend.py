"""The plan's tasks on a Dask cluster: ``python -m engine farm dask SHOTS --scheduler tcp://HOST:PORT``.

Each task of the plan (``engine.farm.plan``) becomes one Dask future whose function runs the task's engine
command, ``[python, "-m", "engine", *task.args]`` with the worker's own Python, as a subprocess on the worker.
Dask carries the graph: a task's dependencies are passed to it as futures, so it starts only when they have
finished; accelerator tasks ask for a worker resource (``--fit-resource GPU=1``); ``--retries`` re-runs a task
whose engine failed. The engine's commands are made for this: a retried task runs the same argv and resumes
(``fit --resume-if-started`` continues its checkpoint, an export chunk skips the frames it already wrote).

Why the engine child dies with its worker: a worker that is killed (preempted host, OOM killer, ``kill -9``)
cannot stop its children, and an orphaned fit would keep the run folder locked and keep training while Dask
re-runs the task elsewhere. On Linux the child therefore asks the kernel for SIGTERM when its parent goes
(``prctl(PR_SET_PDEATHSIG)``, set between fork and exec): the fit then checkpoints and exits 3, and the retry
resumes from that checkpoint. The kernel sends it when the *thread* that forked the child exits, not only the
process. Dask runs a task in a thread of its pool; that thread can leave the pool later (a thread that
"rejoins" after ``secede``), but never while it is still running our function. So the invariant that makes
it safe is that the forking thread is the waiting thread: ``_run_child`` forks, waits for the child and, in a
``finally``, terminates and reaps it before it returns or raises. The thread can therefore not exit while
the child runs, and the signal fires exactly when the worker process dies. (A long-lived launcher thread
would give the same guarantee, with a queue and a second thread to get wrong.) A worker that dies between
the fork and the ``prctl`` is caught by comparing the parent's pid right after it. The engine's output goes to
unnamed temporary files, not pipes, so a dead worker leaves no broken pipe under the checkpointing engine.
Elsewhere (macOS, Windows) there is no such signal: a killed worker's engine runs on to its end, and the retry
waits for its lock.

Stopping ``farm dask`` (Ctrl-C) releases the tasks that have not started; a task already running finishes on
its worker (Dask cannot interrupt a running task); running the command again continues each fit from its
checkpoint.

A task whose engine exits 2 (bad input) or 4 (the fit diverged) fails at once: the same argv would fail the
same way, and Dask retries every exception, so such a task returns a failed result instead of raising, and
its dependents skip. A retry that finds the run folder still locked by the dying engine of the attempt
before (it is writing its checkpoint) waits for the lock, up to ``--lock-wait`` seconds.
"""

from __future__ import annotations

import argparse
import ctypes
import os
import signal
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, TextIO

from .. import contract as C
from ..errors import InputError
from ..terms.cli import EXIT_DIVERGED, EXIT_FAILED
from ..terms.farm import FARM_DASK
from ..terms.lock import RUN_LOCKED_FIX
from ..terms.protocol import progress_line

if TYPE_CHECKING:
    from .plan import Plan

#: Engine exits a retry cannot fix: the input is wrong, or the fit diverged (the same argv diverges again; the
#: fix, ``fit --resume --set lr=...``, is the artist's).
NO_RETRY_EXITS: tuple[int, ...] = (C.EXIT_BAD_INPUT, EXIT_DIVERGED)
#: How long a task waits for a run folder locked by another engine (the killed attempt checkpointing).
LOCK_WAIT_SECONDS = 120.0
LOCK_POLL_SECONDS = 1.0
#: A child whose waiting thread is interrupted gets SIGTERM, this long to checkpoint, then SIGKILL.
TERM_GRACE_SECONDS = 60.0
#: Dask retries of a task whose engine failed (a killed worker's tasks are re-run by Dask without counting).
DEFAULT_RETRIES = 2
#: Seconds to reach the scheduler.
CONNECT_SECONDS = 15.0
#: The lines of a task's stdout/stderr kept in its result.
TAIL_LINES = 20

PR_SET_PDEATHSIG = 1  # linux/prctl.h
STATE_DONE = "done"
STATE_FAILED = "failed"
STATE_SKIPPED = "skipped"


def engine_argv(args: tuple[str, ...] | list[str], python: str | None = None) -> list[str]:
    """The command line a task runs: ``[python, "-m", "engine", *args]`` (python: this interpreter)."""
    return [python or sys.executable, "-m", C.CLI_MODULE, *args]


def _engine_root() -> str:
    """The folder that holds the ``engine`` package this Python imported: the child imports the same one."""
    return str(Path(__file__).resolve().parents[2])


def _child_env(threads: int | None) -> dict[str, str]:
    env = dict(os.environ)
    root = _engine_root()
    env["PYTHONPATH"] = os.pathsep.join([root, *[p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]])
    if threads:
        for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # torch's CPU threads, read when it starts
            env[name] = str(threads)
    return env


def _die_with_parent_fn() -> Callable[[], None] | None:
    """The ``preexec_fn`` that asks for SIGTERM when the forking thread's process dies (Linux), else None.

    prctl is looked up here, before the fork: between fork and exec the child should run as little as possible."""
    if not sys.platform.startswith("linux"):
        return None
    prctl = ctypes.CDLL(None, use_errno=True).prctl
    parent = os.getpid()
    term = int(signal.SIGTERM)

    def die_with_parent() -> None:
        prctl(PR_SET_PDEATHSIG, term, 0, 0, 0)
        if os.getppid() != parent:  # the worker died before the prctl: it will never send the signal
            os.kill(os.getpid(), term)

    return die_with_parent


@dataclass
class ChildResult:
    """One engine run: its exit code, the tails of its output and its parsed progress messages."""

    returncode: int
    stdout_tail: list[str]
    stderr_tail: list[str]
    messages: list[dict[str, Any]]
    seconds: float


def _tail(f: IO[bytes]) -> list[str]:
    f.seek(0)
    return f.read().decode("utf-8", "replace").splitlines()


def _run_child(argv: list[str], env: dict[str, str]) -> ChildResult:
    """Run one engine command and wait for it. Its output goes to unnamed temporary files, not pipes: a worker
    killed mid-fit closes no pipe under the engine's feet (its checkpoint message would meet a broken pipe)."""
    start = time.monotonic()
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = subprocess.Popen(
            argv, stdin=subprocess.DEVNULL, stdout=out, stderr=err, env=env, preexec_fn=_die_with_parent_fn()
        )
        try:
            returncode = proc.wait()
        finally:  # this thread must not leave before its child: the child's death signal is tied to it
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(TERM_GRACE_SECONDS)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
        lines, errors = _tail(out), _tail(err)
    messages = [m for m in map(C.parse_progress_line, lines) if m is not None]
    seconds = time.monotonic() - start
    return ChildResult(returncode, lines[-TAIL_LINES:], errors[-TAIL_LINES:], messages[-TAIL_LINES:], seconds)


def _locked(result: ChildResult) -> bool:
    """Whether the engine refused because another process holds the run folder (``contract.RunLocked``)."""
    return result.returncode == C.EXIT_BAD_INPUT and any(RUN_LOCKED_FIX in line for line in result.stderr_tail)


class TaskFailed(RuntimeError):
    """A task's engine failed in a way a retry may fix (Dask retries it); the message is one line."""


def _worker_address() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):
        return ""


def run_task(
    task_id: str,
    args: tuple[str, ...],
    threads: int | None,
    lock_wait: float,
    *dependencies: dict[str, Any],
) -> dict[str, Any]:
    """A task's function on a Dask worker: run its engine command once its dependencies' results arrive.

    Returns ``{"id", "state", "returncode", "last_line", "error", "seconds", "worker", "locked_waits"}``; a
    dependency that did not finish makes it ``skipped``. Raises ``TaskFailed`` for an engine failure a retry
    may fix, so Dask retries it."""
    failed = [d["id"] for d in dependencies if d.get("state") != STATE_DONE]
    record: dict[str, Any] = {"id": task_id, "worker": _worker_address(), "locked_waits": 0}
    if failed:
        return {**record, "state": STATE_SKIPPED, "returncode": None, "error": f"{failed[0]} did not finish"}
    argv, env = engine_argv(args), _child_env(threads)
    deadline = time.monotonic() + lock_wait
    while True:
        result = _run_child(argv, env)
        if not _locked(result) or time.monotonic() > deadline:
            break
        record["locked_waits"] += 1  # the attempt before is still checkpointing: its lock goes when it exits
        time.sleep(LOCK_POLL_SECONDS)
    last_error = result.stderr_tail[-1] if result.stderr_tail else ""
    record.update(
        returncode=result.returncode,
        seconds=round(result.seconds, 3),
        last_line=result.stdout_tail[-1] if result.stdout_tail else "",
        messages=result.messages,
    )
    if result.returncode == C.EXIT_OK:
        return {**record, "state": STATE_DONE, "error": ""}
    if result.returncode in NO_RETRY_EXITS:
        return {**record, "state": STATE_FAILED, "error": last_error}
    raise TaskFailed(f"{task_id}: exit {result.returncode}: {last_error or '(no message)'}")


@dataclass
class FarmResult:
    """What ``run_plan`` saw: each task's result record (``run_task``) by id, and the wall time."""

    results: dict[str, dict[str, Any]] = field(default_factory=dict)
    seconds: float = 0.0

    @property
    def failed(self) -> list[dict[str, Any]]:
        """The tasks that failed themselves (not those skipped after a failed dependency), in finishing order."""
        return [r for r in self.results.values() if r["state"] == STATE_FAILED]

    @property
    def ok(self) -> bool:
        return all(r["state"] == STATE_DONE for r in self.results.values())


def parse_resources(items: list[str]) -> dict[str, float]:
    """``["GPU=1"]`` -> ``{"GPU": 1.0}``: the worker resources each accelerator task asks for."""
    resources: dict[str, float] = {}
    for item in items:
        name, sep, amount = item.partition("=")
        try:
            value = float(amount)
        except ValueError:
            value = -1.0
        if not sep or not name.strip() or value <= 0:
            raise InputError(None, f"--fit-resource {item!r} is not NAME=N", "write e.g. --fit-resource GPU=1")
        resources[name.strip()] = value
    return resources


def _check_resources(client: Any, address: str, resources: dict[str, float]) -> None:
    """Accelerator tasks would wait forever for a resource no worker offers: say so when workers are there."""
    workers = client.scheduler_info().get("workers", {})
    if not resources or not workers:
        return
    for name, amount in resources.items():
        if not any(w.get("resources", {}).get(name, 0) >= amount for w in workers.values()):
            raise InputError(
                address,
                f"no worker offers the resource {name}={amount:g} that --fit-resource asks for",
                f"start the accelerator workers with --resources {name}={amount:g}, or drop --fit-resource",
            )


def check_address(address: str) -> None:
    """A scheduler address Dask can parse (``tcp://HOST:PORT``, a port 1-65535), else one line at once: Dask itself
    would try to connect for the whole timeout and end in a traceback."""
    from distributed.comm import parse_address
    from distributed.comm.addressing import parse_host_port

    problem: str | None = None
    try:
        scheme, location = parse_address(address)
        port = parse_host_port(location)[1] if scheme in ("tcp", "tls") else 1
    except (ValueError, TypeError) as exc:
        problem = str(exc)
    else:
        if not 0 < int(port) < 65536:
            problem = f"port {port} is not 1-65535"
    if problem is not None:
        raise InputError(
            address, f"is not a Dask scheduler address ({problem[:120]})", "give --scheduler as tcp://HOST:PORT"
        )


def _connect(address: str, timeout: float) -> Any:
    from distributed import Client

    try:
        return Client(address, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError) as exc:
        raise InputError(
            address,
            f"no Dask scheduler answers ({type(exc).__name__})",
            "start `dask scheduler`, or fix --scheduler",
        ) from None


#: The fix for a scheduler or worker whose Python cannot import the engine (Dask unpickles each task's function,
#: ``engine.farm.dask_backend.run_task``, on the scheduler and on the worker that runs it, under the name the
#: submitter imported it by: ``engine`` from a checkout, ``neural_atlas`` from the wheel).
ENGINE_IMPORT_FIX = (
    "install the engine into the Python of the Dask scheduler and of every worker as the submitter has it (pip install "
    '"neural-atlas[farm]" on all of them, or PYTHONPATH set to the folder holding engine/ on all: docs/farm.md, Dask)'
)


def _exception_text(exc: BaseException) -> str:
    """The whole message of ``exc`` and of what caused it, on one line (Dask's own messages span lines)."""
    parts: list[str] = []
    seen: BaseException | None = exc
    while seen is not None and len(parts) < 3:
        text = " ".join(str(seen).split()) or type(seen).__name__
        parts.append(text if text.startswith(type(seen).__name__) else f"{type(seen).__name__}: {text}")
        seen = seen.__cause__ or seen.__context__
    return "; caused by ".join(parts)


def _failure(task_id: str, key: Any, exc: BaseException, dependencies_done: bool) -> dict[str, Any]:
    """A task's outcome from the exception Dask handed its future: its own failure, or a dependency's.
    ``dependencies_done``: every task it waits for finished (so the exception can only be its own)."""
    from distributed.scheduler import KilledWorker

    if isinstance(exc, KilledWorker):
        if exc.task != key:
            return {"state": STATE_SKIPPED, "error": f"a task before it lost {exc.allowed_failures + 1} workers"}
        error = f"{exc.allowed_failures + 1} workers died while running it (the engine's log: its run folder)"
        return {"state": STATE_FAILED, "error": error}
    text = _exception_text(exc)
    if isinstance(exc, TaskFailed):
        own = str(exc).startswith(f"{task_id}: ")
        if own:  # its own engine failed and the retries are spent: "exit N: <the engine's last stderr line>"
            return {"state": STATE_FAILED, "error": " ".join(str(exc).split())[len(task_id) + 2 :]}
        return {"state": STATE_SKIPPED, "error": text}  # a dependency's failure, handed on by Dask
    if not dependencies_done:
        return {"state": STATE_SKIPPED, "error": text}
    if "deserializ" in text.lower() or isinstance(exc, ImportError):
        text = f"{text} — {ENGINE_IMPORT_FIX}"
    return {"state": STATE_FAILED, "error": text}


def _check_environment(client: Any, address: str) -> None:
    """The scheduler and the connected workers can import the engine (Dask unpickles ``run_task`` on both): else
    every task would fail at once with Dask's own words. One line naming the process and the fix instead."""
    probe = f"import {__name__}"  # the submitter's own name for it: engine (a checkout) or neural_atlas (the wheel)
    try:
        client.run_on_scheduler(exec, probe, {})
    except Exception as exc:
        raise InputError(
            address, f"the Dask scheduler cannot import the engine ({_exception_text(exc)})", ENGINE_IMPORT_FIX
        ) from None
    answers = client.run(exec, probe, {}, on_error="return")
    for worker, answer in sorted(answers.items()):
        if isinstance(answer, BaseException):
            raise InputError(
                address,
                f"the Dask worker {worker} cannot import the engine ({_exception_text(answer)})",
                ENGINE_IMPORT_FIX,
            )


def _emit(stream: TextIO, event: str, **fields: Any) -> None:
    print(progress_line(event, **fields), file=stream, flush=True)


def run_plan(
    plan: Plan,
    scheduler_address: str,
    fit_resources: dict[str, float] | None = None,
    retries: int = DEFAULT_RETRIES,
    threads: int | None = None,
    lock_wait: float = LOCK_WAIT_SECONDS,
    stream: TextIO | None = None,
    connect_timeout: float = CONNECT_SECONDS,
) -> FarmResult:
    """Run every task of ``plan`` on the Dask scheduler at ``scheduler_address`` and wait for them all.

    Prints one progress line per finished task (``event: progress``: shot, task, kind, state, done, total, ...)
    and one ``done`` line per shot whose tasks all finished. ``threads``: torch CPU threads of each engine."""
    from distributed import as_completed

    stream = stream or sys.stdout
    token = uuid.uuid4().hex[:12]  # unique keys: a plan submitted twice runs twice
    start = time.monotonic()
    result = FarmResult()
    client = _connect(scheduler_address, connect_timeout)
    try:
        _check_environment(client, scheduler_address)
        _check_resources(client, scheduler_address, fit_resources or {})
        futures: dict[str, Any] = {}
        tasks = {t.id: t for t in plan.tasks}
        for task in plan.tasks:
            futures[task.id] = client.submit(
                run_task,
                task.id,
                tuple(task.args),
                threads,
                lock_wait,
                *[futures[d] for d in task.depends],
                key=f"neural-atlas-{token}-{task.id}",
                pure=False,
                retries=retries,
                resources=fit_resources if task.accelerator and fit_resources else None,
            )
        by_future = {f.key: task_id for task_id, f in futures.items()}
        finished: dict[str, int] = {shot: 0 for shot in plan.shots}
        for future in as_completed(list(futures.values()), loop=client.loop):
            task = tasks[by_future[future.key]]
            try:
                record = future.result()
            except Exception as exc:  # retries spent, or a dependency's failure: Dask hands on the exception
                done = all(result.results.get(d, {}).get("state") == STATE_DONE for d in task.depends)
                record = {"id": task.id, **_failure(task.id, future.key, exc, done)}
            result.results[task.id] = record
            finished[task.shot] += 1
            total = len(plan.shot_tasks(task.shot))
            _emit(
                stream,
                C.EVENT_PROGRESS,
                shot=task.shot,
                task=task.id,
                kind=task.kind,
                state=record["state"],
                done=finished[task.shot],
                total=total,
                seconds=record.get("seconds"),
                worker=record.get("worker"),
                error=record.get("error") or None,
            )
            if finished[task.shot] == total:
                states = [result.results[t.id]["state"] for t in plan.shot_tasks(task.shot)]
                _emit(stream, C.EVENT_DONE, shot=task.shot, ok=all(s == STATE_DONE for s in states), tasks=total)
    finally:
        client.close()
    result.seconds = time.monotonic() - start
    return result


def summary_line(plan: Plan, result: FarmResult) -> str:
    """The last line of ``farm dask``: what finished, and the first failure with its engine's last line."""
    done = sum(r["state"] == STATE_DONE for r in result.results.values())
    line = f"farm dask: {len(plan.shots)} shot(s), {done}/{len(plan.tasks)} tasks done in {result.seconds:.1f} s"
    if result.failed:
        first = result.failed[0]
        line += f"; task {first['id']} failed: {first.get('error') or 'exit ' + str(first.get('returncode'))}"
    return line


def add_dask_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """The ``dask`` sub-command of ``farm``."""
    d: argparse.ArgumentParser = sub.add_parser(
        FARM_DASK,
        help="run the plan's tasks on a Dask cluster",
        description="Submit every task of the shots file to a Dask scheduler and wait: each task runs "
        "`python -m engine ...` as a subprocess on a worker (the worker's Python), after its dependencies. A killed "
        "worker's task runs again elsewhere and resumes (a fit from its checkpoint). Prints a progress line per "
        "finished task and a summary; exits non-zero naming the first failed task.",
    )
    d.add_argument("shots", metavar="SHOTS", help="the shots file (TOML or JSON)")
    d.add_argument("--scheduler", required=True, metavar="tcp://HOST:PORT", help="the Dask scheduler's address")
    d.add_argument(
        "--fit-resource",
        action="append",
        default=[],
        metavar="NAME=N",
        help="worker resource each accelerator task (fit, atlases, passes) needs, e.g. GPU=1 (workers started with "
        "--resources GPU=1); default: any worker",
    )
    d.add_argument(
        "--retries",
        type=int,
        default=DEFAULT_RETRIES,
        help=f"re-runs of a task whose engine failed (default: {DEFAULT_RETRIES}; bad input is not retried)",
    )
    d.add_argument("--threads", type=int, default=None, help="torch CPU threads of each engine (default: torch's)")
    d.add_argument(
        "--lock-wait",
        type=float,
        default=LOCK_WAIT_SECONDS,
        metavar="SECONDS",
        help="how long a task waits for a run folder another engine still holds (default: %(default)s)",
    )
    d.add_argument(
        "--connect-timeout",
        type=float,
        default=CONNECT_SECONDS,
        metavar="SECONDS",
        help="how long to try reaching the scheduler (default: %(default)s)",
    )
    return d


def run_dask(args: argparse.Namespace) -> int:
    """``farm dask``: the exit code (0: every task done; 1: a task failed, named on stderr)."""
    from .plan import load_plan

    if args.retries < 0:
        raise InputError(None, f"--retries {args.retries} is negative", "pass 0 or more")
    check_address(args.scheduler)  # before the plan is made
    plan = load_plan(args.shots)
    result = run_plan(
        plan,
        args.scheduler,
        fit_resources=parse_resources(args.fit_resource),
        retries=args.retries,
        threads=args.threads,
        lock_wait=args.lock_wait,
        connect_timeout=args.connect_timeout,
    )
    line = summary_line(plan, result)
    if result.ok:
        print(line)
        return C.EXIT_OK
    print(f"error: {line}", file=sys.stderr)
    return EXIT_FAILED


__all__ = [
    "FarmResult",
    "TaskFailed",
    "add_dask_parser",
    "check_address",
    "engine_argv",
    "parse_resources",
    "run_dask",
    "run_plan",
    "run_task",
    "summary_line",
]
