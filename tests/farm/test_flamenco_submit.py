"""``farm flamenco``'s submission against a stub Flamenco Manager on 127.0.0.1.

The stub checks every request body against Flamenco's SubmittedJob (name, type, priority, settings,
submitter_platform) and compiles it with the real job type under Node, answering as Flamenco does: check 204,
submit 200 with the Job (its id), errors with ``{code, message}``.
"""

from __future__ import annotations

import argparse
import json
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from engine import contract as C
from engine.errors import InputError
from engine.farm import flamenco
from engine.terms.farm import FLAMENCO_API_CHECK, FLAMENCO_API_SUBMIT, FLAMENCO_JOB_TYPE
from tests.farm.flamenco_helpers import NODE, StubManager, two_shot_plan

pytestmark = pytest.mark.skipif(NODE is None, reason="node (v20) is not on PATH")

TYPE_PATH = flamenco.API_JOB_TYPE + FLAMENCO_JOB_TYPE
VARIABLES_PATH = flamenco.API_VARIABLES + "linux"


@pytest.fixture(autouse=True)
def _no_proxy(monkeypatch: pytest.MonkeyPatch) -> None:
    """The stub is on 127.0.0.1: a proxy from the environment must not take the requests elsewhere."""
    for name in ("http_proxy", "HTTP_PROXY", "https_proxy", "HTTPS_PROXY", "all_proxy", "ALL_PROXY"):
        monkeypatch.delenv(name, raising=False)


@pytest.fixture
def manager() -> Iterator[StubManager]:
    stub = StubManager()
    try:
        yield stub
    finally:
        stub.close()


def _submit(stub: StubManager, plan: object, **kwargs: object) -> tuple[list[str], list[dict[str, object]]]:
    lines: list[str] = []
    ids = flamenco.submit_plan(plan, stub.url, platform="linux", emit=lines.append, **kwargs)  # type: ignore[arg-type]
    return ids, [json.loads(line) for line in lines]


def test_each_shot_is_checked_then_submitted_as_one_job(manager: StubManager, tmp_path: Path) -> None:
    plan = two_shot_plan(tmp_path)
    ids, progress = _submit(manager, plan, priority=70)
    calls = [(c.method, c.path) for c in manager.calls]
    assert calls == [
        ("GET", TYPE_PATH),
        ("GET", VARIABLES_PATH),
        ("POST", FLAMENCO_API_CHECK),
        ("POST", FLAMENCO_API_CHECK),
        ("POST", FLAMENCO_API_SUBMIT),
        ("POST", FLAMENCO_API_SUBMIT),
    ]
    checked = [c.body["name"] for c in manager.calls if c.path == FLAMENCO_API_CHECK]
    submitted = [c.body for c in manager.calls if c.path == FLAMENCO_API_SUBMIT]
    assert checked == [b["name"] for b in submitted] == ["sh010", "sh020"]
    for body in submitted:
        assert isinstance(body, dict)
        assert body["type"] == FLAMENCO_JOB_TYPE
        assert body["priority"] == 70
        assert body["submitter_platform"] == "linux"
        assert body["type_etag"] == manager.etag
        assert body["settings"]["shot"] == body["name"]
    # the ids the Manager gave, in shot order, and the jobs it compiled hold the plan's tasks
    assert len(ids) == 2 and ids == list(manager.jobs)
    for job_id, shot in zip(ids, plan.shots, strict=True):
        compiled = manager.jobs[job_id]["tasks"]
        assert [t["name"] for t in compiled] == [t.id for t in plan.shot_tasks(shot)]
        assert [t["commands"][0]["parameters"]["args"][2:] for t in compiled] == [
            list(t.args) for t in plan.shot_tasks(shot)
        ]
    assert [(p["stage"], p["shot"]) for p in progress] == [
        ("flamenco-check", "sh010"),
        ("flamenco-check", "sh020"),
        ("flamenco-submit", "sh010"),
        ("flamenco-submit", "sh020"),
    ]
    assert [p["job"] for p in progress if p["stage"] == "flamenco-submit"] == ids


def test_check_only_submits_nothing(manager: StubManager, tmp_path: Path) -> None:
    ids, _ = _submit(manager, two_shot_plan(tmp_path), check_only=True)
    assert ids == []
    assert [c.path for c in manager.calls if c.method == "POST"] == [FLAMENCO_API_CHECK] * 2
    assert manager.jobs == {}


def test_paths_under_a_two_way_variable_are_sent_as_the_variable(manager: StubManager, tmp_path: Path) -> None:
    manager.variables["studio"] = {"value": str(tmp_path), "is_twoway": True}
    plan = two_shot_plan(tmp_path)
    _submit(manager, plan)
    body = next(c.body for c in manager.calls if c.path == FLAMENCO_API_SUBMIT)
    assert isinstance(body, dict)
    sent = json.loads(body["settings"]["plan"])["tasks"]
    planned = plan.shot_tasks("sh010")
    assert [t["id"] for t in sent] == [t.id for t in planned]
    for task, got in zip(planned, sent, strict=True):
        assert got["args"] == [
            "{studio}" + a[len(str(tmp_path)) :] if a.startswith(str(tmp_path)) else a for a in task.args
        ]
        assert any(a.startswith("{studio}/") for a in got["args"])


def _one_line(exc: pytest.ExceptionInfo[InputError]) -> str:
    text = str(exc.value)
    assert "\n" not in text
    return text


def test_connection_refused_is_one_line_naming_the_url(tmp_path: Path) -> None:
    with socket.socket() as sock:  # a port nothing listens on
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    url = f"http://127.0.0.1:{port}"
    with pytest.raises(InputError) as exc:
        flamenco.submit_plan(two_shot_plan(tmp_path), url, platform="linux", emit=lambda _l: None)
    text = _one_line(exc)
    assert text.startswith(url + TYPE_PATH + ": cannot reach the Flamenco Manager")
    assert "start the Manager" in text


def test_a_manager_without_the_job_type_says_how_to_install_it(manager: StubManager, tmp_path: Path) -> None:
    manager.job_type_installed = False
    with pytest.raises(InputError) as exc:
        _submit(manager, two_shot_plan(tmp_path))
    text = _one_line(exc)
    assert "has no neural-atlas job type" in text and "--job-type-out" in text and "scripts" in text
    assert not [c for c in manager.calls if c.method == "POST"]


@pytest.mark.parametrize("status", [400, 422])
def test_a_refused_check_gives_flamencos_message_and_submits_nothing(
    manager: StubManager, tmp_path: Path, status: int
) -> None:
    manager.fail[FLAMENCO_API_CHECK] = (status, "compiling job: something is off")
    with pytest.raises(InputError) as exc:
        _submit(manager, two_shot_plan(tmp_path))
    text = _one_line(exc)
    assert text.startswith(manager.url + FLAMENCO_API_CHECK + ": ")
    assert f"refused shot sh010 (HTTP {status}: compiling job: something is off)" in text
    assert [c.path for c in manager.calls if c.method == "POST"] == [FLAMENCO_API_CHECK]


def test_a_job_type_changed_since_its_etag_was_read_is_refused(manager: StubManager, tmp_path: Path) -> None:
    """The etag read first goes into every job: a Manager whose script changed meanwhile refuses it (412)."""
    plan = two_shot_plan(tmp_path)
    original = manager.get

    def newer_after_reading(path: str) -> tuple[int, object]:
        answer = original(path)
        if path == TYPE_PATH:
            manager.etag = "a-newer-script"
        return answer

    manager.get = newer_after_reading  # type: ignore[method-assign]
    with pytest.raises(InputError) as exc:
        _submit(manager, plan)
    text = _one_line(exc)
    assert "job type changed during the submission (HTTP 412" in text and text.endswith("submit again")
    assert manager.jobs == {}


def test_a_plan_the_job_type_refuses_comes_back_as_the_scripts_message(manager: StubManager, tmp_path: Path) -> None:
    """The stub Manager compiles with the real script: a job whose plan the script refuses gets its one line."""
    plan = two_shot_plan(tmp_path)
    bad = flamenco.submitted_job("sh010", plan.shot_tasks("sh010"), platform="linux")
    bad["settings"]["plan"] = "[]"
    with pytest.raises(InputError) as exc:
        flamenco.Manager(manager.url).request("POST", FLAMENCO_API_CHECK, bad, what="shot sh010")
    assert 'HTTP 400: neural-atlas job "sh010": the plan setting is not a JSON object' in _one_line(exc)


def test_a_failing_manager_and_a_second_shot_refused_say_what_is_queued(manager: StubManager, tmp_path: Path) -> None:
    plan = two_shot_plan(tmp_path)
    submits = 0
    post = manager.post

    def second_fails(path: str, body: object, content_type: str) -> tuple[int, object]:
        nonlocal submits
        if path == FLAMENCO_API_SUBMIT:
            submits += 1
            if submits == 2:
                return manager.error(500, "database is busy")
        return post(path, body, content_type)

    manager.post = second_fails  # type: ignore[method-assign]
    with pytest.raises(InputError) as exc:
        _submit(manager, plan)
    text = _one_line(exc)
    first = next(iter(manager.jobs))
    assert "failed shot sh020 (HTTP 500: database is busy)" in text
    assert f"already submitted: sh010 as job {first}" in text


def test_bad_manager_url_and_priority(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="is not a Flamenco Manager URL"):
        flamenco.submit_plan(two_shot_plan(tmp_path), "flamenco.local:8080", emit=lambda _l: None)
    with pytest.raises(InputError, match=r"outside 0\.\.100"):
        flamenco.submit_plan(two_shot_plan(tmp_path), "http://127.0.0.1:9", priority=101, emit=lambda _l: None)


def test_the_parser_and_job_type_out(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    flamenco.add_flamenco_parser(parser.add_subparsers(dest="farm_command"))
    args = parser.parse_args(["flamenco", "--job-type-out", str(tmp_path / "out")])
    assert flamenco.run_flamenco(args) == C.EXIT_OK
    written = tmp_path / "out" / flamenco.JOB_TYPE_SCRIPT
    assert capsys.readouterr().out.strip() == str(written)
    assert written.read_text(encoding="utf-8") == flamenco.job_type_script()
    args = parser.parse_args(["flamenco", "shots.toml"])
    with pytest.raises(InputError, match="needs SHOTS and --manager URL"):
        flamenco.run_flamenco(args)
    args = parser.parse_args(["flamenco", "s.json", "--manager", "http://m:8080", "--priority", "10", "--check-only"])
    assert (args.shots, args.manager, args.priority, args.check_only) == ("s.json", "http://m:8080", 10, True)


def test_a_manager_that_does_not_answer_times_out_in_one_line() -> None:
    with socket.socket() as sock:  # accepts connections (the backlog) and never answers
        sock.bind(("127.0.0.1", 0))
        sock.listen(4)
        url = f"http://127.0.0.1:{sock.getsockname()[1]}"
        with pytest.raises(InputError) as exc:
            flamenco.Manager(url, timeout=0.3).request("GET", TYPE_PATH)
    text = _one_line(exc)
    assert text.startswith(url + TYPE_PATH + ": the Flamenco Manager did not answer in 0.3 s")
    assert "--timeout" in text


def _cli_has_farm_flamenco() -> bool:
    from engine import cli

    try:
        cli.build_parser("python -m engine").parse_args([C.VERB_FARM, C.FARM_FLAMENCO, "--job-type-out", "x"])
    except SystemExit:
        return False
    return True


needs_cli = pytest.mark.skipif(not _cli_has_farm_flamenco(), reason="engine/cli.py has no `farm flamenco` yet")


@needs_cli
def test_the_cli_submits_a_shots_file_and_prints_the_job_ids(
    manager: StubManager, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from engine import cli
    from tests.farm.flamenco_helpers import write_shots

    shots = write_shots(tmp_path)
    code = cli.main([C.VERB_FARM, C.FARM_FLAMENCO, str(shots), "--manager", manager.url, "--priority", "60"])
    out = capsys.readouterr().out.splitlines()
    assert code == C.EXIT_OK
    assert out[-1].split() == list(manager.jobs)
    assert [c.body["priority"] for c in manager.calls if c.method == "POST"] == [60] * 4


@needs_cli
@pytest.mark.parametrize("status", [None, 400, 422])
def test_the_cli_says_one_line_and_exits_2(manager: StubManager, tmp_path: Path, status: int | None) -> None:
    from tests.engine_cli import run_cli
    from tests.farm.flamenco_helpers import write_shots

    shots = write_shots(tmp_path)
    url = manager.url
    if status is None:
        manager.close()  # connection refused
    else:
        manager.fail[FLAMENCO_API_CHECK] = (status, "compiling job: bad")
    code, lines = run_cli(C.VERB_FARM, C.FARM_FLAMENCO, shots, "--manager", url)
    assert code == C.EXIT_BAD_INPUT
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"error: {url}/api/v3/")
    expected = "cannot reach the Flamenco Manager" if status is None else f"HTTP {status}: compiling job: bad"
    assert expected in lines[0]
