"""``render MANIFEST --out DIR --frames A-B``: chunks of one render, run by several farm tasks into one folder (two of
them at once, as real ``python -m engine`` processes), give the files one whole render gives; a chunk run again
writes the same files; a range outside the export is one line; ``--movie`` with ``--frames`` is a movie of that
range. ``preview`` run again with the same arguments succeeds with the same files."""

from __future__ import annotations

import subprocess
import sys

import av
import pytest

from engine import contract as C
from tests.engine.export.tiny_run import export, make_run
from tests.engine_cli import run_cli
from tests.folders import tree_digest
from tests.paths import ROOT


@pytest.fixture(scope="module")
def manifest(tmp_path_factory):
    root = tmp_path_factory.mktemp("render_chunks") / "root"
    make_run(root)
    return export(root / "run")


def _render(manifest, out, *args: str) -> tuple[int, list[str]]:  # type: ignore[no-untyped-def]
    return run_cli("render", manifest, "--out", out, "--no-bar", *args)


@pytest.mark.slow
def test_chunks_into_one_folder_equal_a_whole_render(manifest, tmp_path):
    whole, chunked = tmp_path / "whole", tmp_path / "chunked"
    assert _render(manifest, whole) == (0, [])
    expected = tree_digest(whole)
    assert sorted(expected) == [f"edit.{n:05d}.exr" for n in range(4)]

    argv = [sys.executable, "-m", "engine", "render", str(manifest), "--out", str(chunked), "--no-bar", "--frames"]
    procs = [
        subprocess.Popen(
            [*argv, frames],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for frames in ("0-1", "2-2")
    ]
    outs = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], [err for _, err in outs]
    assert sorted(tree_digest(chunked)) == [f"edit.{n:05d}.exr" for n in range(3)]
    assert _render(manifest, chunked, "--frames", "3-3") == (0, [])
    assert tree_digest(chunked) == expected  # nothing else there: no staging left behind
    assert _render(manifest, chunked, "--frames", "1-2") == (0, [])  # a chunk run again
    assert tree_digest(chunked) == expected

    code, lines = _render(manifest, tmp_path / "none", "--frames", "2-9")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and "not inside the exported frames 0-3" in lines[0]
    assert not (tmp_path / "none").exists()


def test_a_chunks_movie_is_of_its_frames(manifest, tmp_path):
    movie = tmp_path / "chunk.mp4"
    assert _render(manifest, tmp_path / "frames", "--frames", "1-2", "--movie", movie) == (0, [])
    with av.open(str(movie)) as container:
        assert sum(1 for _ in container.decode(video=0)) == 2
    assert sorted(tree_digest(tmp_path / "frames")) == ["edit.00001.exr", "edit.00002.exr"]


def test_preview_run_again_succeeds_with_the_same_files(manifest, tmp_path):
    out = tmp_path / "preview"
    code, lines = run_cli("preview", manifest, "--out", out, "--no-movies")
    assert code == 0, lines
    first = tree_digest(out)
    assert sorted(first) == ["atlases.png", "frames.png"]
    code, lines = run_cli("preview", manifest, "--out", out, "--no-movies")
    assert code == 0, lines
    assert tree_digest(out) == first
