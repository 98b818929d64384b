"""A fit on a really full disk (a tmpfs in a private mount namespace: tests/full_disk.py): torch.save raises
RuntimeError, not OSError, when the disk fills, and the fit must still say so in one line, exit 2, keep the
last checkpoint byte for byte and leave no temp file behind; with room again, ``--resume`` finishes."""

from __future__ import annotations

import hashlib
import shutil
import sys
from pathlib import Path

import pytest

from engine import contract as C
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.terms.export_names import EDITS_DIR
from engine.terms.lock import RUN_LOCK
from tests.engine_cli import run_cli
from tests.full_disk import PAGE_BYTES, run_on_full_disk
from tests.paths import ROOT

SPEC = SceneSpec(width=48, height=32, frames=4, fg_size=(16, 12), fg_start=(10.0, 8.0))
SETS = ["steps=40", "batch=256", "eval_every=10", "eval_pixels=500", "bootstrap_steps=10", "global_rigidity_steps=5"]
ENGINE = [sys.executable, "-m", "engine"]


def _sets(*extra: str) -> list[str]:
    return [a for s in [*SETS, *extra] for a in ("--set", s)]


def _pages(path: Path) -> int:
    """Bytes ``path``'s files take on a tmpfs (whole pages, plus a page per folder)."""
    files = [p for p in path.rglob("*") if p.is_file()]
    folders = [p for p in path.rglob("*") if p.is_dir()] + [path]
    return sum(-(-p.stat().st_size // PAGE_BYTES) * PAGE_BYTES for p in files) + PAGE_BYTES * len(folders)


def _is_temp(path: str) -> bool:
    """A hidden file other than the run folder's lock (which stays, empty of meaning, by design)."""
    name = Path(path).name
    return name.startswith(".") and name != RUN_LOCK


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    root = tmp_path_factory.mktemp("full_disk_fit")
    frames, masks = write_scene(make_scene(SPEC), root / "clip")
    run = root / "run"
    argv = ["fit", str(frames), "--mask", str(masks), "--out", str(run), "--preset", "draft", "--no-bar", *_sets()]
    assert run_cli(*argv)[0] == C.EXIT_OK
    return frames, masks, run


@pytest.mark.slow
def test_resume_on_a_full_disk_is_one_line_and_keeps_the_last_checkpoint(fitted, tmp_path):
    _, _, run = fitted
    checkpoint = run / C.RUN_CHECKPOINT
    before = hashlib.sha256(checkpoint.read_bytes()).hexdigest()
    disk = tmp_path / "disk"
    # room for the run as it is and half a checkpoint more: the next checkpoint's temp file cannot be written
    size_kb = (_pages(run) + checkpoint.stat().st_size // 2) // 1024
    script = (
        f'cp -a "{run}" "{disk}/run" && "{sys.executable}" -m engine fit --resume --out "{disk}/run" --no-bar '
        + " ".join(_sets("steps=80"))
        + f'; echo "exit=$?"; sha256sum "{disk}/run/{C.RUN_CHECKPOINT}"'
    )
    result = run_on_full_disk(["sh", "-c", script], mount=disk, size_kb=size_kb, cwd=ROOT)
    lines = result.stderr_lines
    assert f"exit={C.EXIT_BAD_INPUT}" in result.stdout, result.stderr
    assert len(lines) == 1 and lines[0].startswith("error: disk full: free "), lines
    assert f" MB at {disk}/run — " in lines[0], lines[0]
    assert result.stdout.split()[-2] == before, "the last good checkpoint changed"
    assert not [p for p in result.left if _is_temp(p)], result.left  # no temp file left
    # with room again the same folder resumes and finishes
    shutil.rmtree(disk)
    retry = tmp_path / "retry"
    shutil.copytree(run, retry)
    assert run_cli("fit", "--resume", "--out", str(retry), "--no-bar", *_sets("steps=80"))[0] == C.EXIT_OK


@pytest.mark.slow
def test_a_fit_on_a_disk_with_no_room_is_one_line_and_leaves_no_temp_file(fitted, tmp_path):
    frames, masks, _ = fitted
    disk = tmp_path / "disk"
    argv = [*ENGINE, "fit", str(frames), "--mask", str(masks), "--out", str(disk / "run"), "--preset", "draft",
            "--no-bar", *_sets()]  # fmt: skip
    result = run_on_full_disk(argv, mount=disk, size_kb=48, cwd=ROOT)
    lines = result.stderr_lines
    assert result.returncode == C.EXIT_BAD_INPUT, result.stderr
    assert len(lines) == 1 and lines[0].startswith("error: disk full: free "), lines
    assert not [p for p in result.left if _is_temp(p)], result.left


def test_an_export_on_a_full_disk_is_one_line_and_keeps_earlier_exports_and_edits(fitted, tmp_path):
    """A run exported once, then exported again on a disk with room for half of it: exit 2, one line, and the
    first export and the edit layers unchanged byte for byte; nothing of the second one is left."""
    _, _, run = fitted
    exported = tmp_path / "exported"
    shutil.copytree(run, exported)
    assert run_cli("export", str(exported), "--atlas-size", "64", "--no-bar")[0] == C.EXIT_OK
    export = exported / C.EXPORTS_DIR / "v001"
    before = [
        hashlib.sha256(path.read_bytes()).hexdigest()
        for folder in (exported / EDITS_DIR, export)
        for path in folder.rglob("*")
        if path.is_file()
    ]
    disk = tmp_path / "disk"
    size_kb = (_pages(exported) + _pages(export) // 2) // 1024
    sums = f'cd "{disk}/run" && find {EDITS_DIR} {C.EXPORTS_DIR}/v001 -type f | sort | xargs sha256sum'
    script = (
        f'cp -a "{exported}" "{disk}/run" && "{sys.executable}" -m engine export "{disk}/run" --atlas-size 64 '
        f'--no-bar; echo "exit=$?"; {sums}'
    )
    result = run_on_full_disk(["sh", "-c", script], mount=disk, size_kb=size_kb, cwd=ROOT)
    lines = result.stderr_lines
    assert f"exit={C.EXIT_BAD_INPUT}" in result.stdout, result.stderr
    assert len(lines) == 1 and lines[0].startswith("error: disk full: free "), lines
    after = sorted(line.split()[0] for line in result.stdout.splitlines() if len(line.split()) == 2)
    assert after == sorted(before), "the first export or an edit layer changed"
    prefix = f"run/{C.EXPORTS_DIR}/"
    exports = sorted(
        p for p in result.left if p.startswith(prefix) and p != prefix and "/" not in p[len(prefix) :].rstrip("/")
    )
    assert exports == [f"run/{C.EXPORTS_DIR}/v001/"], exports  # no second export, finished or not
