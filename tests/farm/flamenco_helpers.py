"""Helpers of the Flamenco tests: a two-shot plan, the job compiler run under Node, and a stub Flamenco Manager.

The stub Manager answers the API calls ``farm flamenco`` makes the way Flamenco 3.x does (pkg/api/flamenco-
openapi.yaml): it checks each SubmittedJob's required fields and compiles the job with the real job type script
under Node (``flamenco_author_stub.js``), answering a check with 204, a submission with 200 and the Job (with its
``id``), and errors with Flamenco's ``Error`` body ``{code, message}``.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
import threading
import uuid
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from engine import contract as C
from engine.farm import flamenco

HERE = Path(__file__).resolve().parent
AUTHOR_STUB = HERE / "flamenco_author_stub.js"
NODE = shutil.which("node")
#: SubmittedJob's required properties (flamenco-openapi.yaml).
SUBMITTED_JOB_REQUIRED = ("name", "type", "priority", "submitter_platform")
PLATFORMS = ("linux", "windows", "darwin")


@dataclass(frozen=True)
class Task:
    """engine/farm/plan.py's Task, as the brief's interface has it."""

    id: str
    shot: str
    kind: str
    args: tuple[str, ...]
    depends: tuple[str, ...]
    accelerator: bool
    frames: tuple[int, int] | None = None


@dataclass(frozen=True)
class Plan:
    tasks: tuple[Task, ...]
    shots: tuple[str, ...]

    def shot_tasks(self, shot: str) -> tuple[Task, ...]:
        return tuple(t for t in self.tasks if t.shot == shot)


def shot_tasks(root: Path, shot: str) -> list[Task]:
    """One shot's tasks as the plan makes them: masks -> fit -> atlases -> two passes chunks -> publish ->
    render -> preview, with absolute paths."""
    plate = str(root / "plates" / shot / "plate.####.exr")
    run = str(root / "runs" / shot)
    masks = str(root / "runs" / shot / "masks")
    manifest = str(root / "runs" / shot / "exports" / "v001" / "manifest.json")
    render = str(root / "renders" / shot)
    into = ["--into", "v001"]

    def t(name: str, kind: str, args: list[str], depends: list[str], gpu: bool, frames: Any = None) -> Task:
        return Task(f"{shot}.{name}", shot, kind, tuple(args), tuple(f"{shot}.{d}" for d in depends), gpu, frames)

    return [
        t("masks", "masks", ["masks", plate, "--out", masks], [], False),
        t(
            "fit",
            "fit",
            ["fit", plate, "--mask", masks, "--out", run, "--preset", "draft", "--resume-if-started"],
            ["masks"],
            True,
        ),
        t("atlases", "atlases", ["export", run, *into, "--stage", "atlases", "--frames", "1001-1010"], ["fit"], True),
        t(
            "passes.1001-1005",
            "passes",
            ["export", run, *into, "--stage", "passes", "--frames", "1001-1005"],
            ["atlases"],
            True,
            (1001, 1005),
        ),
        t(
            "passes.1006-1010",
            "passes",
            ["export", run, *into, "--stage", "passes", "--frames", "1006-1010"],
            ["atlases"],
            True,
            (1006, 1010),
        ),
        t(
            "publish",
            "publish",
            ["export", run, *into, "--stage", "publish"],
            ["passes.1001-1005", "passes.1006-1010"],
            False,
        ),
        t(
            "render.1001-1010",
            "render",
            ["render", manifest, "--out", render, "--frames", "1001-1010"],
            ["publish"],
            False,
            (1001, 1010),
        ),
        t("preview", "preview", ["preview", manifest], ["publish"], False),
    ]


def two_shot_plan(root: Path) -> Plan:
    shots = ("sh010", "sh020")
    return Plan(tuple(t for s in shots for t in shot_tasks(root, s)), shots)


def compile_job(job: dict[str, Any], script: Path | None = None) -> tuple[int, dict[str, Any] | None, str]:
    """Run the job compiler on JOB under Node as the Manager would: (exit code, compiled job or None, stderr)."""
    assert NODE, "node (v20) is needed for the Flamenco contract test"
    script = script or HERE.parents[1] / "engine" / "farm" / "flamenco" / flamenco.JOB_TYPE_SCRIPT
    with tempfile.TemporaryDirectory() as tmp:
        job_file = Path(tmp) / "job.json"
        job_file.write_text(json.dumps(job), encoding="utf-8")
        done = subprocess.run(
            [NODE, str(AUTHOR_STUB), str(script), str(job_file)], capture_output=True, text=True, timeout=60
        )
    compiled = json.loads(done.stdout) if done.returncode == 0 else None
    return done.returncode, compiled, done.stderr


@dataclass
class Call:
    method: str
    path: str
    body: Any


@dataclass
class StubManager:
    """A Flamenco Manager stand-in on 127.0.0.1; set ``fail`` to {path: (status, message)} to make it refuse."""

    calls: list[Call] = field(default_factory=list)
    fail: dict[str, tuple[int, str]] = field(default_factory=dict)
    etag: str = "0f1e2d3c"
    variables: dict[str, dict[str, Any]] = field(
        default_factory=lambda: {C.FLAMENCO_PYTHON_VARIABLE: {"value": "/opt/na/bin/python", "is_twoway": False}}
    )
    job_type_installed: bool = True
    jobs: dict[str, dict[str, Any]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        manager = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *_args: Any) -> None:
                pass

            def do_GET(self) -> None:
                manager.calls.append(Call("GET", self.path, None))
                self._answer(*manager.get(self.path))

            def do_POST(self) -> None:
                size = int(self.headers.get("Content-Length") or 0)
                raw = self.rfile.read(size)
                try:
                    body = json.loads(raw)
                except json.JSONDecodeError:
                    body = None
                manager.calls.append(Call("POST", self.path, body))
                self._answer(*manager.post(self.path, body, self.headers.get("Content-Type", "")))

            def _answer(self, status: int, body: Any) -> None:
                data = b"" if body is None else json.dumps(body).encode()
                self.send_response(status)
                if body is not None:
                    self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.server.server_address[1]}"

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
        self.thread.join(timeout=10)

    @staticmethod
    def error(status: int, message: str) -> tuple[int, dict[str, Any]]:
        return status, {"code": status, "message": message}

    def get(self, path: str) -> tuple[int, Any]:
        if path in self.fail:
            return self.error(*self.fail[path])
        if path == flamenco.API_JOB_TYPE + C.FLAMENCO_JOB_TYPE:
            if not self.job_type_installed:
                return self.error(404, "no such job type known")
            return 200, {"name": C.FLAMENCO_JOB_TYPE, "label": "Neural Atlas", "settings": [], "etag": self.etag}
        if path.startswith(flamenco.API_VARIABLES):
            return 200, self.variables
        return self.error(404, "not found")

    def post(self, path: str, body: Any, content_type: str) -> tuple[int, Any]:
        if path in self.fail:
            return self.error(*self.fail[path])
        if path not in (C.FLAMENCO_API_CHECK, C.FLAMENCO_API_SUBMIT):
            return self.error(404, "not found")
        problem = self.schema_problem(body, content_type)
        if problem:
            return self.error(400, problem)
        if body.get("type_etag") not in (None, "", self.etag):
            return self.error(412, "rejecting job because its settings are outdated, refresh the job type")
        code, compiled, stderr = compile_job(body)
        if code != 0 or compiled is None:
            return self.error(400, stderr.strip().splitlines()[-1] if stderr.strip() else "compile failed")
        if path == C.FLAMENCO_API_CHECK:
            return 204, None
        job_id = str(uuid.uuid4())
        self.jobs[job_id] = compiled
        now = "2026-11-24T23:00:00Z"
        return 200, {**body, "id": job_id, "created": now, "updated": now, "status": "queued", "activity": ""}

    @staticmethod
    def schema_problem(body: Any, content_type: str) -> str:
        """What makes BODY no SubmittedJob, or ''."""
        if not content_type.startswith("application/json"):
            return f"invalid format (Content-Type {content_type!r})"
        if not isinstance(body, dict):
            return "invalid format"
        for key in SUBMITTED_JOB_REQUIRED:
            if key not in body:
                return f"invalid format (no {key})"
        if not isinstance(body["name"], str) or not body["name"]:
            return "invalid format (name)"
        if not isinstance(body["priority"], int) or isinstance(body["priority"], bool):
            return "invalid format (priority)"
        if body["submitter_platform"] not in PLATFORMS:
            return f"unknown platform {body['submitter_platform']!r}"
        if body["type"] != C.FLAMENCO_JOB_TYPE:
            return "job type unknown"
        if not isinstance(body.get("settings"), dict):
            return "invalid format (settings)"
        meta = body.get("metadata", {})
        if not isinstance(meta, dict) or not all(isinstance(v, str) for v in meta.values()):
            return "invalid format (metadata values are strings)"
        return ""
