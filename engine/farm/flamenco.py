"""Flamenco back end: one Flamenco job per shot, submitted to a Flamenco Manager over its HTTP API.

Flamenco (Blender's own render farm manager) turns a job into tasks with a job compiler script that runs inside
the Manager; ours is ``engine/farm/flamenco/neural-atlas.js`` (``farm flamenco --job-type-out DIR`` writes it for
installing). The plan is computed here, in Python, at submit time and travels in the job's ``plan`` setting, so
the script only maps it: every Flamenco task runs ``{neural_atlas_python} -m engine ARGS`` with exactly the
plan's arguments, the same command lines the OpenJD and Dask back ends run.

Submitting (stdlib ``urllib`` only, so Blender's Python can do it too):

1. ``GET /api/v3/jobs/type/neural-atlas``: the job type is installed (else one line saying how to install it),
   and its etag goes into each job as ``type_etag``, so a Manager whose script changed meanwhile refuses the job
   instead of compiling it with other settings.
2. ``GET /api/v3/configuration/variables/workers/PLATFORM``: the Manager's two-way variables for this machine's
   platform. Flamenco maps paths by prefix: an argument that starts with a two-way variable's value on the
   submitter's platform is sent as ``{variable}/rest``, and the Manager expands ``{variable}`` to each worker's
   own value when it hands out a task (Flamenco does the first half itself only for whole job settings, and the
   plan is one JSON setting, so it is done here, argument by argument).
3. ``POST /api/v3/jobs/check`` for every shot, then ``POST /api/v3/jobs`` for every shot: the Manager compiles
   each job in the check without storing it, so a shot it refuses stops the submission before any job exists.

Workers pick tasks by task type (``task_types`` in flamenco-worker.yaml): ``neural-atlas`` for tasks that run on
any host, ``neural-atlas-gpu`` for the ones that want an accelerator (the plan's ``accelerator``: fit, atlases,
passes). A GPU worker lists both; a CPU-only worker lists ``neural-atlas``.
"""

from __future__ import annotations

import argparse
import getpass
import json
import re
import sys
import urllib.error
import urllib.request
from collections.abc import Callable, Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import quote, urlsplit

from .. import contract as C
from ..errors import InputError
from ..terms.farm import FLAMENCO_API_CHECK, FLAMENCO_API_SUBMIT, FLAMENCO_JOB_TYPE, FLAMENCO_PYTHON_VARIABLE
from ..terms.protocol import progress_line

#: The job compiler script's file name: Flamenco names a job type after its script's file (minus ``.js``).
JOB_TYPE_SCRIPT = f"{FLAMENCO_JOB_TYPE}.js"
#: The plan setting's tag and version; the script refuses any other (an engine and a job type that differ).
PLAN_TAG = "neural_atlas_flamenco_plan"
PLAN_VERSION = 1
#: The job settings the script reads (its JOB_TYPE).
PLAN_SETTING = "plan"
SHOT_SETTING = "shot"
#: Flamenco task types: any host, and hosts with an accelerator.
TASK_TYPE = "neural-atlas"
TASK_TYPE_GPU = "neural-atlas-gpu"
#: The Manager's API beyond the contract's check and submit.
API_JOB_TYPE = "/api/v3/jobs/type/"
API_VARIABLES = "/api/v3/configuration/variables/workers/"
#: Flamenco's default job priority (0..100, higher first).
DEFAULT_PRIORITY = 50
#: Seconds to wait for the Manager's answer to one request.
DEFAULT_TIMEOUT = 30.0
#: How to put the job type on a Manager: said in every error that means it is missing or outdated.
INSTALL_FIX = (
    f"write it with `python -m {C.CLI_MODULE} farm flamenco --job-type-out DIR`, copy {JOB_TYPE_SCRIPT} into the "
    "`scripts` folder beside the flamenco-manager executable and restart the Manager"
)


class PlanTask(Protocol):
    """A task of the farm plan (engine/farm/plan.py's ``Task``), as far as this back end reads it."""

    @property
    def id(self) -> str: ...
    @property
    def shot(self) -> str: ...
    @property
    def kind(self) -> str: ...
    @property
    def args(self) -> tuple[str, ...]: ...
    @property
    def depends(self) -> tuple[str, ...]: ...
    @property
    def accelerator(self) -> bool: ...


class ShotsPlan(Protocol):
    """The farm plan of a shots file (engine/farm/plan.py's ``Plan``)."""

    @property
    def shots(self) -> tuple[str, ...]: ...
    def shot_tasks(self, shot: str) -> Sequence[PlanTask]: ...


# --- the job type script ------------------------------------------------------------------------------------


def job_type_script() -> str:
    """The job compiler script's text, from the package (it ships with the engine, so both always agree)."""
    # this package by its own name: "engine.farm" in a checkout, "neural_atlas.farm" in the installed wheel
    return (resources.files(__package__ or "engine.farm") / "flamenco" / JOB_TYPE_SCRIPT).read_text(encoding="utf-8")


def write_job_type(out_dir: str | Path) -> Path:
    """Write ``neural-atlas.js`` into OUT_DIR (created) for copying into a Manager's ``scripts`` folder."""
    from ..io.atomic import atomic_write_text

    folder = Path(out_dir)
    if folder.exists() and not folder.is_dir():
        raise InputError(folder, "is a file, not a folder", "give --job-type-out a folder")
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / JOB_TYPE_SCRIPT
    atomic_write_text(path, job_type_script())
    return path


# --- the submitted jobs -------------------------------------------------------------------------------------


def submitter_platform(platform: str = sys.platform) -> str:
    """This machine's platform as Flamenco names it (Go's GOOS: linux, windows, darwin): it selects which value of
    each two-way variable the submitted paths are recognised by."""
    if platform.startswith("win"):
        return "windows"
    if platform.startswith("linux"):
        return "linux"
    return platform


#: Platforms whose file systems ignore case (NTFS, APFS by default): a path there matches a two-way variable's
#: value in any case. Linux's do not: ``/mnt/Shots`` is not under ``/mnt/shots``.
CASE_INSENSITIVE_PLATFORMS: frozenset[str] = frozenset({"windows", "darwin"})
#: What the Manager replaces in a task's arguments when it hands the task out: ``{name}`` of any of its variables.
#: Flamenco has no escape for it, so a plan argument holding one is refused.
_VARIABLE_REFERENCE = re.compile(r"\{[^{}]*\}")


def _norm_path(text: str, fold_case: bool) -> str:
    text = text.replace("\\", "/")
    return text.lower() if fold_case else text


def to_variables(arg: str, two_way: Mapping[str, str], platform: str | None = None) -> str:
    """ARG with a leading two-way variable value replaced by ``{name}``; unchanged when none matches.

    As Flamenco: Windows values also matched with forward slashes; the longest value wins, and only a whole path
    component matches (``/mnt/a`` is not a prefix of ``/mnt/ab``). Case is ignored only where the submitting
    PLATFORM's file systems ignore it (``CASE_INSENSITIVE_PLATFORMS``; default: this machine's)."""
    fold = (platform or submitter_platform()) in CASE_INSENSITIVE_PLATFORMS
    norm = _norm_path(arg, fold)
    for name, value in sorted(two_way.items(), key=lambda item: -len(item[1])):
        prefix = _norm_path(value, fold).rstrip("/")
        if prefix and (norm == prefix or norm.startswith(prefix + "/")):
            return "{" + name + "}" + arg[len(prefix) :]
    return arg


def _check_literal(shot: str, task_id: str, arg: str) -> None:
    """Refuse an argument the Manager would rewrite: ``{name}`` in it is replaced by the variable ``name`` (when
    the Manager or a later configuration defines one) and cannot be escaped."""
    found = _VARIABLE_REFERENCE.search(arg)
    if found:
        raise InputError(
            None,
            f"shot {shot}: task {task_id}: the argument {arg!r} holds {found.group(0)}, which a Flamenco Manager "
            "replaces with its variable of that name (Flamenco has no escape for it)",
            "rename that file or folder without {...}, or submit with `farm openjd` or `farm dask`",
        )


def plan_setting(
    shot: str, tasks: Sequence[PlanTask], two_way: Mapping[str, str] | None = None, platform: str | None = None
) -> str:
    """The ``plan`` setting of SHOT's job: its tasks as JSON, paths mapped to two-way variables (as PLATFORM's
    paths; default: this machine's)."""
    ids = {task.id for task in tasks}
    for task in tasks:
        for arg in task.args:
            _check_literal(shot, task.id, arg)
    for task in tasks:
        outside = [dep for dep in task.depends if dep not in ids]
        if outside:
            raise InputError(
                None,
                f"task {task.id} of shot {shot} depends on {outside[0]} of another shot",
                "a Flamenco job holds one shot: keep each shot's tasks to its own shot",
            )
    mapping = two_way or {}
    plan = {
        PLAN_TAG: PLAN_VERSION,
        "shot": shot,
        "module": C.CLI_MODULE,
        "tasks": [
            {
                "id": task.id,
                "kind": task.kind,
                "args": [to_variables(arg, mapping, platform) for arg in task.args],
                "depends": list(task.depends),
                "accelerator": bool(task.accelerator),
            }
            for task in tasks
        ],
    }
    return json.dumps(plan, separators=(",", ":"))


def _user_name() -> str:
    try:
        return getpass.getuser()
    except (OSError, KeyError):  # no login name (some containers): the metadata is informative only
        return "unknown"


def submitted_job(
    shot: str,
    tasks: Sequence[PlanTask],
    *,
    priority: int = DEFAULT_PRIORITY,
    platform: str | None = None,
    type_etag: str | None = None,
    two_way: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """Flamenco's ``SubmittedJob`` for one shot (name, type, priority, settings, metadata, submitter_platform,
    type_etag when known)."""
    platform = platform or submitter_platform()
    job: dict[str, Any] = {
        "name": shot,
        "type": FLAMENCO_JOB_TYPE,
        "priority": int(priority),
        "submitter_platform": platform,
        "settings": {SHOT_SETTING: shot, PLAN_SETTING: plan_setting(shot, tasks, two_way, platform)},
        "metadata": {"user.name": _user_name(), "neural_atlas.shot": shot, "neural_atlas.tasks": str(len(tasks))},
    }
    if type_etag:
        job["type_etag"] = type_etag
    return job


# --- the Manager's HTTP API ---------------------------------------------------------------------------------


class ManagerError(InputError):
    """The Manager answered with an HTTP error: ``status`` says which (the message is Flamenco's own)."""

    def __init__(self, url: str, status: int, problem: str, fix: str) -> None:
        super().__init__(url, problem, fix)
        self.status = status


class Manager:
    """A Flamenco Manager at URL: JSON requests with a timeout, every failure one line naming the URL and the fix."""

    def __init__(self, url: str, timeout: float = DEFAULT_TIMEOUT) -> None:
        parts = urlsplit(url.strip())
        if parts.scheme not in ("http", "https") or not parts.netloc:
            raise InputError(url, "is not a Flamenco Manager URL", "give --manager http://HOST:PORT (e.g. :8080)")
        self.base = f"{parts.scheme}://{parts.netloc}{parts.path.rstrip('/')}"
        self.timeout = timeout

    def request(self, method: str, path: str, body: Any = None, *, what: str = "") -> tuple[int, Any]:
        """(status, decoded JSON or None) of a 2xx answer; anything else raises ``InputError``."""
        url = self.base + path
        data = None if body is None else json.dumps(body).encode("utf-8")
        req = urllib.request.Request(url, data=data, method=method, headers={"Accept": "application/json"})
        if data is not None:
            req.add_header("Content-Type", "application/json")
        try:
            with urllib.request.urlopen(req, timeout=self.timeout) as answer:
                return answer.status, _decode(answer.read())
        except urllib.error.HTTPError as exc:
            raise _http_error(url, exc, what) from None
        except (urllib.error.URLError, OSError) as exc:
            reason = exc.reason if isinstance(exc, urllib.error.URLError) else exc
            if isinstance(reason, TimeoutError):
                raise InputError(
                    url,
                    f"the Flamenco Manager did not answer in {self.timeout:g} s",
                    "check that the Manager is running and reachable, or give a longer --timeout",
                ) from None
            raise InputError(
                url,
                f"cannot reach the Flamenco Manager ({reason})",
                "start the Manager, or give --manager the URL its web interface has (http://HOST:PORT)",
            ) from None


def _decode(raw: bytes) -> Any:
    if not raw.strip():
        return None
    try:
        return json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        return None


def _error_message(exc: urllib.error.HTTPError) -> str:
    """Flamenco's ``Error.message`` of an error answer, else the start of its text, on one line."""
    try:
        raw = exc.read()
    except OSError:
        raw = b""
    body = _decode(raw)
    if isinstance(body, dict) and isinstance(body.get("message"), str):
        text = body["message"]
    else:
        text = raw.decode("utf-8", "replace")[:300] or (exc.reason if isinstance(exc.reason, str) else "")
    return " ".join(text.split()) or "no message"


def _http_error(url: str, exc: urllib.error.HTTPError, what: str) -> ManagerError:
    code = exc.code
    message = _error_message(exc)
    subject = f" {what}" if what else ""
    if code == 412:
        return ManagerError(
            url,
            code,
            f"the Manager's {FLAMENCO_JOB_TYPE} job type changed during the submission (HTTP 412: {message})",
            "submit again",
        )
    if code >= 500:
        return ManagerError(
            url,
            code,
            f"the Flamenco Manager failed{subject} (HTTP {code}: {message})",
            "see the Manager's log, then submit again",
        )
    if code in (400, 422):
        return ManagerError(
            url,
            code,
            f"the Flamenco Manager refused{subject} (HTTP {code}: {message})",
            f"fix the shots file, or install this engine's job type on the Manager: {INSTALL_FIX}",
        )
    return ManagerError(
        url,
        code,
        f"the Flamenco Manager refused{subject} (HTTP {code}: {message})",
        "check --manager (the Manager's own URL, http://HOST:PORT) and the Manager's log",
    )


def fetch_job_type(manager: Manager) -> dict[str, Any]:
    """The Manager's ``neural-atlas`` job type (its settings and etag); one line saying how to install it when the
    Manager has none."""
    try:
        _status, body = manager.request("GET", API_JOB_TYPE + quote(FLAMENCO_JOB_TYPE), what="the job type")
    except ManagerError as exc:
        if exc.status == 404:
            raise InputError(
                manager.base + API_JOB_TYPE + FLAMENCO_JOB_TYPE,
                f"the Flamenco Manager has no {FLAMENCO_JOB_TYPE} job type",
                INSTALL_FIX,
            ) from None
        raise
    if not isinstance(body, dict):
        raise InputError(
            manager.base + API_JOB_TYPE + FLAMENCO_JOB_TYPE,
            "answered without a job type",
            "check that --manager is a Flamenco 3 Manager",
        )
    return body


def fetch_two_way_variables(manager: Manager, platform: str) -> tuple[dict[str, str], bool]:
    """({name: value} of the Manager's two-way variables on PLATFORM, whether the engine's Python variable is
    defined there)."""
    _status, body = manager.request("GET", API_VARIABLES + quote(platform), what="the variables")
    variables = body if isinstance(body, dict) else {}
    two_way = {
        str(name): str(entry.get("value", ""))
        for name, entry in variables.items()
        if isinstance(entry, dict) and entry.get("is_twoway") and entry.get("value")
    }
    return two_way, FLAMENCO_PYTHON_VARIABLE in variables


def submit_plan(
    plan: ShotsPlan,
    manager_url: str,
    *,
    priority: int = DEFAULT_PRIORITY,
    check_only: bool = False,
    timeout: float = DEFAULT_TIMEOUT,
    platform: str | None = None,
    emit: Callable[[str], None] = print,
) -> list[str]:
    """Check every shot's job on the Manager, then submit them; the job ids in shot order ([] with CHECK_ONLY).
    One progress line per shot and step through EMIT."""
    if not 0 <= priority <= 100:
        raise InputError(None, f"--priority {priority} is outside 0..100", "give a Flamenco priority from 0 to 100")
    for shot in plan.shots:  # before the Manager is asked anything: a refused name submits nothing
        for task in plan.shot_tasks(shot):
            for arg in task.args:
                _check_literal(shot, task.id, arg)
    manager = Manager(manager_url, timeout)
    platform = platform or submitter_platform()
    job_type = fetch_job_type(manager)
    etag = job_type.get("etag") if isinstance(job_type.get("etag"), str) else None
    two_way, has_python = fetch_two_way_variables(manager, platform)
    if not has_python:
        print(
            f"warning: {manager.base}: the Manager has no `{FLAMENCO_PYTHON_VARIABLE}` variable for {platform}: "
            "workers without it fail every task — add it to flamenco-manager.yaml `variables:` (each platform's "
            f"Python that runs `python -m {C.CLI_MODULE}`) and restart the Manager",
            file=sys.stderr,
        )
    jobs = {
        shot: submitted_job(
            shot, plan.shot_tasks(shot), priority=priority, platform=platform, type_etag=etag, two_way=two_way
        )
        for shot in plan.shots
    }
    for shot, job in jobs.items():
        manager.request("POST", FLAMENCO_API_CHECK, job, what=f"shot {shot}")
        emit(progress_line(C.EVENT_STAGE, stage="flamenco-check", shot=shot, message=f"{shot}: the Manager accepts it"))
    if check_only:
        return []
    ids: list[str] = []
    for shot, job in jobs.items():
        done = ", ".join(f"{s} as job {i}" for s, i in zip(jobs, ids, strict=False))
        try:
            _status, answer = manager.request("POST", FLAMENCO_API_SUBMIT, job, what=f"shot {shot}")
        except InputError as exc:
            if ids:  # say what is on the farm already, so a second try does not queue those shots twice
                fix = f"{exc.fix}; already submitted: {done} (submit only the other shots)"
                raise InputError(exc.path, exc.problem, fix) from None
            raise
        job_id = answer.get("id") if isinstance(answer, dict) else None
        if not isinstance(job_id, str) or not job_id:
            raise InputError(
                manager.base + FLAMENCO_API_SUBMIT,
                f"the Manager answered shot {shot}'s submission without a job id",
                "check that --manager is a Flamenco 3 Manager",
            )
        ids.append(job_id)
        emit(
            progress_line(
                C.EVENT_STAGE,
                stage="flamenco-submit",
                shot=shot,
                job=job_id,
                message=f"{shot}: job {job_id} ({len(plan.shot_tasks(shot))} tasks)",
            )
        )
    return ids


# --- command line (wired into `python -m engine farm` by engine/cli.py) ------------------------------------

FLAMENCO_HELP = """\
Submit one Flamenco job per shot of SHOTS to a Flamenco Manager (its `neural-atlas` job type must be installed:
--job-type-out DIR writes it). The Manager's variable `neural_atlas_python` names, per worker platform, the Python
that runs `python -m engine`; workers run task types `neural-atlas` (any host) and `neural-atlas-gpu` (fit,
atlases and passes). Last stdout line: the job ids, in shot order.
"""


def add_flamenco_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """``farm flamenco SHOTS --manager URL [--priority N] [--check-only]`` and ``farm flamenco --job-type-out DIR``."""
    p = sub.add_parser(
        C.FARM_FLAMENCO,
        help="submit the shots as Flamenco jobs, or write the Flamenco job type",
        description=FLAMENCO_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("shots", nargs="?", metavar="SHOTS", help="the shots file (TOML or JSON; docs/farm.md)")
    p.add_argument("--manager", metavar="URL", help="the Flamenco Manager, e.g. http://flamenco.local:8080")
    p.add_argument(
        "--priority", type=int, default=DEFAULT_PRIORITY, help=f"job priority 0..100 (default {DEFAULT_PRIORITY})"
    )
    p.add_argument("--check-only", action="store_true", help="have the Manager check every job, submit none")
    p.add_argument(
        "--timeout", type=float, default=DEFAULT_TIMEOUT, help=f"seconds per request (default {DEFAULT_TIMEOUT:g})"
    )
    p.add_argument(
        "--job-type-out", metavar="DIR", help=f"write the job type script {JOB_TYPE_SCRIPT} into DIR and stop"
    )
    return p


def run_flamenco(args: argparse.Namespace) -> int:
    """Run ``farm flamenco``; bad input raises ``InputError`` (the CLI prints its one line, exit 2)."""
    if args.job_type_out:
        print(write_job_type(args.job_type_out))
        return C.EXIT_OK
    if not args.shots or not args.manager:
        raise InputError(
            None,
            "farm flamenco needs SHOTS and --manager URL",
            f"run `python -m {C.CLI_MODULE} farm flamenco SHOTS --manager http://HOST:PORT`, or --job-type-out DIR",
        )
    from .plan import load_plan

    plan = load_plan(args.shots)
    ids = submit_plan(plan, args.manager, priority=args.priority, check_only=args.check_only, timeout=args.timeout)
    print(" ".join(ids) if not args.check_only else f"checked {len(plan.shots)} jobs: {' '.join(plan.shots)}")
    return C.EXIT_OK
