"""Helpers of the Flamenco tests: a two-shot shots file and its plan, the job compiler run under Node, and a stub
Flamenco Manager.

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
from engine.farm.plan import Plan, load_plan
from engine.terms.farm import FLAMENCO_API_CHECK, FLAMENCO_API_SUBMIT, FLAMENCO_JOB_TYPE, FLAMENCO_PYTHON_VARIABLE

HERE = Path(__file__).resolve().parent
AUTHOR_STUB = HERE / "flamenco_author_stub.js"
NODE = shutil.which("node")
#: SubmittedJob's required properties (flamenco-openapi.yaml).
SUBMITTED_JOB_REQUIRED = ("name", "type", "priority", "submitter_platform")
PLATFORMS = ("linux", "windows", "darwin")


def write_shots(root: Path) -> Path:
    """A shots file of two shots over tiny 10-frame PNG plates (plate.1001.png ..): sh010 finds its masks, both
    are exported in chunks of 5 frames and rendered."""
    import cv2
    import numpy as np

    for shot in ("sh010", "sh020"):
        folder = root / "plates" / shot
        folder.mkdir(parents=True, exist_ok=True)
        for n in range(1001, 1011):
            cv2.imwrite(str(folder / f"plate.{n}.png"), np.full((8, 8, 3), n % 256, np.uint8))
    shots = {
        C.SHOTS_TAG: C.SHOTS_VERSION,
        "defaults": {"preset": "draft", "export_chunk": 5, "render_chunk": 10},
        "shots": [
            {"name": "sh010", "plate": "plates/sh010", "auto_masks": True, "render": "renders/sh010"},
            {"name": "sh020", "plate": "plates/sh020", "frames": "1003-1010", "render": "renders/sh020"},
        ],
    }
    path = root / "shots.json"
    path.write_text(json.dumps(shots, indent=2), encoding="utf-8")
    return path


def two_shot_plan(root: Path) -> Plan:
    """The plan of ``write_shots(root)``, as ``farm flamenco`` makes it."""
    return load_plan(write_shots(root))


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
        default_factory=lambda: {FLAMENCO_PYTHON_VARIABLE: {"value": "/opt/na/bin/python", "is_twoway": False}}
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

    def __enter__(self) -> StubManager:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def requests(self) -> list[tuple[str, str, Any]]:
        """(method, path, body) of every call, in order."""
        return [(c.method, c.path, c.body) for c in self.calls]

    @staticmethod
    def error(status: int, message: str) -> tuple[int, dict[str, Any]]:
        return status, {"code": status, "message": message}

    def get(self, path: str) -> tuple[int, Any]:
        if path in self.fail:
            return self.error(*self.fail[path])
        if path == flamenco.API_JOB_TYPE + FLAMENCO_JOB_TYPE:
            if not self.job_type_installed:
                return self.error(404, "no such job type known")
            return 200, {"name": FLAMENCO_JOB_TYPE, "label": "Neural Atlas", "settings": [], "etag": self.etag}
        if path.startswith(flamenco.API_VARIABLES):
            return 200, self.variables
        return self.error(404, "not found")

    def post(self, path: str, body: Any, content_type: str) -> tuple[int, Any]:
        if path in self.fail:
            return self.error(*self.fail[path])
        if path not in (FLAMENCO_API_CHECK, FLAMENCO_API_SUBMIT):
            return self.error(404, "not found")
        problem = self.schema_problem(body, content_type)
        if problem:
            return self.error(400, problem)
        if body.get("type_etag") not in (None, "", self.etag):
            return self.error(412, "rejecting job because its settings are outdated, refresh the job type")
        code, compiled, stderr = compile_job(body)
        if code != 0 or compiled is None:
            return self.error(400, stderr.strip().splitlines()[-1] if stderr.strip() else "compile failed")
        if path == FLAMENCO_API_CHECK:
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
        if body["type"] != FLAMENCO_JOB_TYPE:
            return "job type unknown"
        if not isinstance(body.get("settings"), dict):
            return "invalid format (settings)"
        meta = body.get("metadata", {})
        if not isinstance(meta, dict) or not all(isinstance(v, str) for v in meta.values()):
            return "invalid format (metadata values are strings)"
        return ""
