"""``render MANIFEST --out DIR --frames A-B``: chunks of one render, run by several farm tasks into one folder (two of
them at once, as real ``python -m engine`` processes), give the files one whole render gives; a chunk run again
writes the same files; a range outside the export is one line; ``--movie`` with ``--frames`` is a movie of that
range. ``preview`` run again with the same arguments succeeds with the same files."""

from __future__ import annotations

import json
import subprocess
import sys

import av
import numpy as np
import pytest

from engine import contract as C
from engine.edit.render_record import RECORD_FIX, RECORD_NAME
from tests.engine.export.tiny_run import ATLAS_SIZE, export, make_run
from tests.engine_cli import run_cli
from tests.folders import tree_digest
from tests.media_files import write_image
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
    assert sorted(expected) == [RECORD_NAME, *(f"edit.{n:05d}.exr" for n in range(4))]

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
    assert sorted(tree_digest(chunked)) == [RECORD_NAME, *(f"edit.{n:05d}.exr" for n in range(3))]
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
    assert sorted(tree_digest(tmp_path / "frames")) == [RECORD_NAME, "edit.00001.exr", "edit.00002.exr"]


def test_chunks_of_another_export_other_paint_or_other_settings_never_mix_in_one_folder(manifest, tmp_path):
    """The folder records what its first chunk rendered from and how (``render_record``): a chunk of another export
    of the same run, with other paint (``--edit``), another format or other names is one line before it writes a
    frame; the same render's chunks join, and a chunk that failed before its first frame leaves no record."""
    out = tmp_path / "chunked"
    assert _render(manifest, out, "--frames", "0-1") == (0, [])
    before = tree_digest(out)
    # another export that differs in content (an export of the same run with the same settings in the same second
    # is the same file, and its frames are these frames)
    other_export = export(manifest.parent.parent.parent, atlas_size=ATLAS_SIZE * 2)
    layer = json.loads(manifest.read_text())["layers"][1]["name"]
    paint = tmp_path / "paint.png"
    write_image(paint, np.full((32, 32, 4), 255, np.uint8))
    for argv, said in (
        ([other_export, "--out", out], "another export"),
        ([manifest, "--out", out, "--edit", f"{layer}={paint}"], "other paint in the edit layers"),
        ([manifest, "--out", out, "--format", "png"], "another format ('exr')"),
        ([manifest, "--out", out, "--name", "shot.####.exr"], "another names ('edit.{frame:05d}.exr')"),
    ):
        code, lines = run_cli("render", *argv, "--no-bar", "--frames", "2-3")
        assert code == C.EXIT_BAD_INPUT and len(lines) == 1, lines
        assert lines[0] == f"error: {out}: holds frames rendered from {said} — {RECORD_FIX}", lines
        assert tree_digest(out) == before
    assert _render(manifest, out, "--frames", "2-3") == (0, [])
    assert sorted(tree_digest(out)) == [RECORD_NAME, *(f"edit.{n:05d}.exr" for n in range(4))]


def test_a_whole_render_replaces_the_record_with_its_frames(manifest, tmp_path):
    """Rendering every frame again after painting more (``--edit``) is the artist's everyday work: allowed, and its
    record replaces the folder's, so a chunk of the earlier paint is then refused there."""
    out = tmp_path / "out"
    assert _render(manifest, out) == (0, [])
    layer = json.loads(manifest.read_text())["layers"][1]["name"]
    paint = tmp_path / "paint.png"
    write_image(paint, np.full((32, 32, 4), 255, np.uint8))
    assert _render(manifest, out, "--edit", f"{layer}={paint}") == (0, [])
    code, lines = _render(manifest, out, "--frames", "0-0")
    assert code == C.EXIT_BAD_INPUT and "holds frames rendered from other paint in the edit layers" in lines[0], lines


def test_render_and_preview_never_write_among_another_plates_frames(manifest, tmp_path):
    """An --out that holds a numbered image sequence no render of these names wrote (another shot's plate): one
    line, nothing added; the same render's own earlier frames (a folder rendered before renders recorded
    themselves) are rendered over as before."""
    other = tmp_path / "other_plate"
    other.mkdir()
    for n in range(1001, 1004):
        write_image(other / f"plate.{n}.png", np.zeros((8, 8, 3), np.uint8))
    before = tree_digest(other)
    for verb, extra in (("render", ["--no-bar"]), ("preview", ["--no-movies"])):
        code, lines = run_cli(verb, manifest, "--out", other, *extra)
        assert code == C.EXIT_BAD_INPUT and len(lines) == 1, lines
        assert lines[0].startswith(f"error: {other}: holds the frames plate.####.png (1001..1003)"), lines
        assert tree_digest(other) == before
    earlier = tmp_path / "earlier"
    assert _render(manifest, earlier) == (0, [])
    (earlier / RECORD_NAME).unlink()  # rendered before renders recorded themselves
    assert _render(manifest, earlier) == (0, [])
