"""A farm's export: ``export RUN --into vNNN`` and its stages (atlases once, passes in chunks with no lock, publish
once) give the very files a plain ``export`` of the same run gives; each stage run again is a no-op; a missing chunk,
a cancelled chunk and a plain export beside a staged one behave as docs/export.md says. Passes of two chunks run at
once as real ``python -m engine`` processes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from engine import contract as C
from engine.export import exporter, pass_writer
from engine.terms.cli import EXPORT_INTO_ARG, EXPORT_STAGE_ARG, EXPORT_STAGES
from engine.terms.export_names import EDITS_DIR, PASSES_DIR, pass_file_name
from tests.engine.export.tiny_run import ATLAS_SIZE, copy_root, export, make_run
from tests.engine_cli import run_cli
from tests.folders import tree_digest
from tests.paths import ROOT

INTO, STAGE = EXPORT_INTO_ARG, EXPORT_STAGE_ARG
ATLASES, PASSES, PUBLISH = EXPORT_STAGES
SIZE = ("--atlas-size", str(ATLAS_SIZE))


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A tiny fitted run (frames 0-3) under ``root``."""
    root = tmp_path_factory.mktemp("export_staged") / "root"
    make_run(root)
    return root


@pytest.fixture
def root(base, tmp_path):
    """A private copy of the base root with a plain export of it, v001 (the one a staged export must equal)."""
    root = copy_root(base, tmp_path / "root")
    export(root / "run")
    return root


def _engine(*args: str | Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "engine", *map(str, args)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _export(run: Path, *args: str) -> tuple[int, list[str]]:
    return run_cli("export", run, "--no-bar", *args)


def _same_export(plain: Path, staged: Path) -> None:
    """Every file byte for byte, but the manifest's creation time and what the manifest's paths say of the folder
    name (the Nuke script names no version)."""
    a, b = tree_digest(plain), tree_digest(staged)
    assert sorted(a) == sorted(b)
    differ = [name for name in a if a[name] != b[name]]
    assert set(differ) <= {C.MANIFEST_NAME}, differ
    ma = json.loads((plain / C.MANIFEST_NAME).read_text())
    mb = json.loads((staged / C.MANIFEST_NAME).read_text())
    ma.pop("created"), mb.pop("created")
    assert ma == mb


@pytest.mark.slow
def test_staged_export_in_three_chunks_equals_a_plain_export(root):
    run = root / "run"
    exports = run / C.EXPORTS_DIR
    chunks = exports / ".v002.chunks"
    before_edits = tree_digest(run / EDITS_DIR)
    code, err = _export(run, INTO, "v002", STAGE, ATLASES, *SIZE)
    assert (code, err) == (0, [])
    assert (chunks / exporter.STAGE_RECORD).is_file() and not (exports / "v002").exists()
    staged = tree_digest(chunks)
    assert _export(run, INTO, "v002", STAGE, ATLASES, *SIZE) == (0, [])  # again: a no-op
    assert tree_digest(chunks) == staged

    # two chunks at once, as two hosts would (no lock), then the last one
    procs = [_engine("export", run, INTO, "v002", STAGE, PASSES, "--frames", f, "--no-bar") for f in ("0-1", "2-2")]
    results = [(p.wait(timeout=300), p.communicate()) for p in procs]
    assert [code for code, _ in results] == [0, 0], [err for _, (_, err) in results]
    assert all(out.strip().splitlines()[-1] == str(chunks) for _, (out, _) in results)
    # publish refuses while a chunk is missing: one line naming the frame and the command
    code, err = _export(run, INTO, "v002", STAGE, PUBLISH)
    assert code == C.EXIT_BAD_INPUT and len(err) == 1
    assert "frame 3 has no pass" in err[0] and f"{STAGE} passes --frames 3-3" in err[0]
    assert not (exports / "v002").exists()
    assert _export(run, INTO, "v002", STAGE, PASSES, "--frames", "3-3") == (0, [])
    passes = tree_digest(chunks / PASSES_DIR)
    assert _export(run, INTO, "v002", STAGE, PASSES, "--frames", "2-3") == (0, [])  # a re-run chunk: a no-op
    assert tree_digest(chunks / PASSES_DIR) == passes

    assert _export(run, INTO, "v002", STAGE, PUBLISH) == (0, [])
    assert not chunks.exists() and tree_digest(run / EDITS_DIR) == before_edits
    _same_export(exports / "v001", exports / "v002")
    published = tree_digest(exports / "v002")
    # every part run again once published: exit 0, the manifest's path, nothing changed
    for args in ((STAGE, PUBLISH), (STAGE, ATLASES, *SIZE), (STAGE, PASSES, "--frames", "1-2"), SIZE):
        proc = _engine("export", run, INTO, "v002", "--no-bar", *args)
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err
        assert out.strip().splitlines()[-1] == str(exports / "v002" / C.MANIFEST_NAME)
    assert tree_digest(exports / "v002") == published
    # other parameters: one line
    code, err = _export(run, INTO, "v002", "--atlas-size", "64")
    assert code == C.EXIT_BAD_INPUT and len(err) == 1 and "already exported" in err[0]
    code, err = _export(run, INTO, "v002", *SIZE, "--frames", "1-2")
    assert code == C.EXIT_BAD_INPUT and len(err) == 1 and "already exported" in err[0]


def test_whole_export_into_a_version_equals_a_plain_one_and_is_idempotent(root):
    run = root / "run"
    exports = run / C.EXPORTS_DIR
    assert _export(run, INTO, "v007", *SIZE) == (0, [])
    assert sorted(p.name for p in exports.iterdir()) == ["v001", "v007"]
    _same_export(exports / "v001", exports / "v007")
    done = tree_digest(exports)
    assert _export(run, INTO, "v007", *SIZE) == (0, [])
    assert tree_digest(exports) == done
    for bad in ("7", "v7", "v0000", "v000", "../v001", "v001/x"):
        code, err = _export(run, INTO, bad)
        assert code == C.EXIT_BAD_INPUT and len(err) == 1 and "not an export version" in err[0], (bad, err)


def test_publish_and_passes_without_a_staged_export_are_one_line(root):
    run = root / "run"
    for stage in (PASSES, PUBLISH):
        code, err = _export(run, INTO, "v003", STAGE, stage)
        assert code == C.EXIT_BAD_INPUT and len(err) == 1 and f"{STAGE} atlases" in err[0]
    code, err = _export(run, STAGE, ATLASES)
    assert code == C.EXIT_BAD_INPUT and len(err) == 1 and INTO in err[0]
    assert _export(run, INTO, "v003", STAGE, ATLASES, *SIZE, "--frames", "1-2") == (0, [])
    code, err = _export(run, INTO, "v003", STAGE, PASSES, "--frames", "0-1")
    assert code == C.EXIT_BAD_INPUT and len(err) == 1 and "outside the staged frames 1-2" in err[0]
    code, err = _export(run, INTO, "v003", STAGE, ATLASES, *SIZE)
    assert code == C.EXIT_BAD_INPUT and len(err) == 1 and "staged with frames 1-2" in err[0]


def test_a_cancelled_chunk_keeps_its_finished_frames_and_its_retry_completes(root, monkeypatch):
    """SIGTERM once the chunk's first pass is written: exit 3, the passes written by then kept whole (the first,
    and the next where it was already being written: ``PASS_WRITE_AHEAD``), no temporary file; the same command
    again writes only the rest, and the published export is the plain one."""
    run = root / "run"
    chunks = run / C.EXPORTS_DIR / ".v002.chunks"
    names = [pass_file_name(n) for n in range(4)]
    assert _export(run, INTO, "v002", STAGE, ATLASES, *SIZE) == (0, [])
    write_exr = pass_writer.write_exr
    written: list[Path] = []

    def write_then_terminate(path, *args, **kwargs):  # type: ignore[no-untyped-def]
        written.append(write_exr(path, *args, **kwargs))
        if len(written) == 1:
            os.kill(os.getpid(), signal.SIGTERM)  # the farm preempts the task
        return written[-1]

    monkeypatch.setattr(pass_writer, "write_exr", write_then_terminate)
    code, err = _export(run, INTO, "v002", STAGE, PASSES, "--frames", "0-3")
    assert code == C.EXIT_CANCELLED and len(err) == 1 and "SIGTERM" in err[0]
    kept = sorted(p.name for p in (chunks / PASSES_DIR).iterdir())
    assert kept in (names[:1], names[:2]) and [p.name for p in written] == kept
    first = tree_digest(chunks / PASSES_DIR)
    retried: list[Path] = []
    monkeypatch.setattr(pass_writer, "write_exr", lambda p, *a, **k: retried.append(p) or write_exr(p, *a, **k))
    assert _export(run, INTO, "v002", STAGE, PASSES, "--frames", "0-3") == (0, [])
    assert [p.name for p in retried] == names[len(kept) :]
    assert {name: tree_digest(chunks / PASSES_DIR)[name] for name in kept} == first
    assert _export(run, INTO, "v002", STAGE, PUBLISH) == (0, [])
    _same_export(run / C.EXPORTS_DIR / "v001", run / C.EXPORTS_DIR / "v002")


def test_a_plain_export_skips_and_keeps_a_staged_version(root):
    run = root / "run"
    exports = run / C.EXPORTS_DIR
    (exports / "v001").rename(exports / "v003")
    assert _export(run, INTO, "v001", STAGE, ATLASES, *SIZE) == (0, [])
    staged = tree_digest(exports / ".v001.chunks")
    assert _export(run, *SIZE) == (0, [])
    assert sorted(p.name for p in exports.iterdir()) == [".v001.chunks", "v002", "v003"]
    assert tree_digest(exports / ".v001.chunks") == staged
    code, err = _export(run, INTO, "v001", *SIZE)  # a whole export into a staged version: one line
    assert code == C.EXIT_BAD_INPUT and len(err) == 1 and "staged export of v001" in err[0]
