"""render, preview and project-frame never leave a partial result and never write over what they read: a failure,
a full disk (patched, and a real one where a tmpfs can be mounted) or SIGTERM leaves the output folder as it was
(or not there), the edit layers byte-identical; a run folder held by another process is one line. Hand-made
exports (``tests.engine.fake_export``), no fit."""

from __future__ import annotations

import errno
import math
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from engine import contract as C
from engine.edit.render_record import RECORD_NAME
from engine.errors import MB, InputError
from engine.io.images import write_png
from engine.terms.export_names import EDITS_DIR, PASSES_DIR, pass_file_name
from engine.terms.lock import RUN_LOCKED_FIX
from tests.engine.fake_export import make_fake_export
from tests.engine_cli import run_cli
from tests.folders import hold_lock, tree_digest
from tests.full_disk import run_on_full_disk
from tests.paths import ROOT


def _export(folder: Path, frames: int = 4, size: tuple[int, int] = (32, 24), layers: int = 1) -> Path:
    """A fake export of a smooth moving plate (``folder/clip``, ``folder/run``); its manifest."""
    w, h = size
    yy, xx = np.mgrid[0:h, 0:w]
    plate = np.stack([np.stack([(xx / w + 0.01 * t) % 1, yy / h, 0.5 + 0 * xx], -1) for t in range(frames)])
    half = (lambda xs: (xs < w / 2).astype(np.float64)) if layers == 2 else (lambda xs: np.ones(xs.shape))
    bg = (lambda t, xs, ys: (xs / w, 1.0 - ys / h, half(xs) if layers == 1 else 1.0 - half(xs)), (w, h))
    fg = (lambda t, xs, ys: (xs / w, 1.0 - ys / h, half(xs)), (w, h))
    return make_fake_export(folder, plate.astype(np.float32), [bg, fg][:layers])


def _earlier_render(manifest: Path, out: Path) -> dict[str, str]:
    """A finished render in ``out`` plus a file of the artist's there; their hashes."""
    assert run_cli("render", manifest, "--out", out, "--no-bar")[0] == C.EXIT_OK
    (out / "notes.txt").write_text("the artist's")
    return tree_digest(out)


def test_a_failing_render_leaves_no_partial_frames(tmp_path):
    """A pass file missing for the third frame: one line, exit 2; an --out the render created is gone again, an
    existing one (an earlier render and the artist's file in it) is byte-identical."""
    manifest = _export(tmp_path)
    earlier = _earlier_render(manifest, tmp_path / "earlier")
    (manifest.parent / PASSES_DIR / pass_file_name(2)).unlink()
    for out in (tmp_path / "earlier", tmp_path / "new" / "frames"):
        code, lines = run_cli("render", manifest, "--out", out, "--no-bar", "--movie", out.parent / "edit.mp4")
        assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and "atlas.00002.exr" in lines[0], lines
    assert tree_digest(tmp_path / "earlier") == earlier
    assert not (tmp_path / "new").exists() and not (tmp_path / "edit.mp4").exists()


def _free_nothing(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """0 bytes free: a disk-full message's N MB is then everything the output needs."""
    import engine.io.atomic as atomic

    monkeypatch.setattr(atomic, "free_bytes", lambda folder: 0)


def _enospc_after(monkeypatch, module, name: str, calls: int) -> None:  # type: ignore[no-untyped-def]
    """``module.name`` fails with ENOSPC from its ``calls + 1``-th call on."""
    real, count = getattr(module, name), {"n": 0}

    def full(path, *args, **kw):  # type: ignore[no-untyped-def]
        count["n"] += 1
        if count["n"] > calls:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(path, *args, **kw)

    monkeypatch.setattr(module, name, full)


@pytest.mark.slow
def test_disk_full_during_a_render_is_one_line_naming_what_it_needs(tmp_path, monkeypatch):
    """ENOSPC on the 6th of 24 frames: one line "disk full: free N MB at OUT", N within a factor 2 of the whole
    render's size (0 bytes free); the earlier render in --out byte-identical, no staging left."""
    import engine.edit.render as render

    manifest = _export(tmp_path, frames=24, size=(640, 480))
    earlier = _earlier_render(manifest, tmp_path / "out")
    size = sum(p.stat().st_size for p in (tmp_path / "out").glob("edit.*.exr"))
    _free_nothing(monkeypatch)
    _enospc_after(monkeypatch, render, "write_rgba_exr", 5)
    code, lines = run_cli("render", manifest, "--out", tmp_path / "out", "--no-bar")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1, lines
    assert lines[0].startswith("error: disk full: free ") and f" MB at {tmp_path / 'out'} — " in lines[0], lines
    free_mb = int(lines[0].split("free ")[1].split(" MB")[0])
    print(f"\nrender needs {size / MB:.2f} MB; the message says free {free_mb} MB")
    assert math.ceil(size / 2 / MB) <= free_mb <= math.ceil(2 * size / MB), (size, free_mb)
    assert tree_digest(tmp_path / "out") == earlier


def test_disk_full_in_the_movie_is_one_line_and_leaves_nothing(tmp_path, monkeypatch):
    """The movie encoder's ENOSPC (PyAV's OSError): one line, no frames, no movie, no temporary file."""
    import engine.edit.render as render

    manifest = _export(tmp_path, frames=6)
    _enospc_after(monkeypatch, render.MovieWriter, "write", 3)
    code, lines = run_cli(
        "render", manifest, "--out", tmp_path / "new", "--movie", tmp_path / "m" / "edit.mp4", "--no-bar"
    )
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and "disk full" in lines[0], lines
    assert not (tmp_path / "new").exists() and not (tmp_path / "m").exists()


@pytest.mark.slow
@pytest.mark.parametrize("size_kb", [512, 1288], ids=["frames", "movie"])
def test_render_on_a_really_full_disk_leaves_nothing(tmp_path, size_kb):
    """A real child render onto a tmpfs that fills up while the frames are written (512 KB) or while the movie is
    (1288 KB: every frame fits, the movie does not): exit 2, one line "disk full", nothing left on the disk."""
    manifest = _export(tmp_path, frames=40, size=(320, 240))
    disk = tmp_path / "disk"
    argv = [sys.executable, "-m", "engine", "render", manifest, "--out", disk / "frames", "--movie", disk / "edit.mp4"]
    result = run_on_full_disk([*argv, "--no-bar"], mount=disk, size_kb=size_kb, cwd=ROOT)
    assert result.returncode == C.EXIT_BAD_INPUT, result.stderr
    assert len(result.stderr_lines) == 1 and result.stderr_lines[0].startswith("error: disk full: free "), result.stderr
    assert result.left == {}


#: A real render (``engine.cli.main`` on argv[2:]) that stops once argv[1] frames are in its staging folder, says
#: so on stdout and waits there for the test's SIGTERM: the signal lands in the middle of the frames at the same
#: point on every machine, however loaded (a render left to run on could end before a racing signal). It waits in
#: the render's own thread, before the next frame, once the frames handed to the writer thread are written.
_RENDER_PAUSED = """
import sys, time
import engine.edit.render as R
from engine.cli import main

real_png, real_frames, written, stop = R.write_png, R.render_plate_frames, [], int(sys.argv[1])

def write_png(path, *args, **kwargs):
    done = real_png(path, *args, **kwargs)
    written.append(path)
    return done

def render_plate_frames(*args, **kwargs):
    for k, frame in enumerate(real_frames(*args, **kwargs)):
        if k == stop:
            while len(written) < stop:
                time.sleep(0.01)
            print("paused", flush=True)
            time.sleep(600)  # the SIGTERM handler raises out of the sleep
        yield frame

R.write_png, R.render_plate_frames = write_png, render_plate_frames
sys.exit(main(sys.argv[2:]))
"""


def test_sigterm_during_a_render_exits_3_and_leaves_the_output_as_it_was(tmp_path):
    """SIGTERM to a real render with 3 of its 8 frames staged: exit 3, one line, no staging, the earlier render in
    --out byte-identical; the same command again writes every frame."""
    manifest = _export(tmp_path, frames=8, size=(64, 48))
    out = tmp_path / "out"
    earlier = _earlier_render(manifest, out)
    args = ["render", str(manifest), "--out", str(out), "--format", "png", "--no-bar"]
    paused = [sys.executable, "-c", _RENDER_PAUSED, "3", *args]
    proc = subprocess.Popen(paused, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    try:
        for line in proc.stdout:
            if line.strip() == "paused":
                break
        else:
            pytest.fail(f"the render ended before its third frame: {proc.communicate(timeout=300)}")
        staged = sorted(p.name for p in out.glob(".edit.partial-*/*.png"))
        assert staged == ["edit.00000.png", "edit.00001.png", "edit.00002.png"], staged
    finally:
        proc.send_signal(signal.SIGTERM)  # on a failed assertion too: the child never sits out its sleep
    _, err = proc.communicate(timeout=300)
    lines = [line for line in err.splitlines() if line.strip()]
    assert proc.returncode == C.EXIT_CANCELLED and len(lines) == 1, err
    assert lines[0].startswith("cancelled: render stopped by SIGTERM"), lines
    assert tree_digest(out) == earlier
    again = subprocess.run([sys.executable, "-m", "engine", *args], cwd=ROOT, capture_output=True, text=True,
                           timeout=300)  # fmt: skip
    assert again.returncode == C.EXIT_OK, again.stderr
    assert len(list(out.glob("edit.*.png"))) == 8 and [p.name for p in out.glob(".*")] == [RECORD_NAME]


def test_preview_failing_at_its_last_file_leaves_no_preview(tmp_path, monkeypatch):
    """Preview's frame sheet fails on a full disk after its atlas sheet and movies were written: one line, the
    export's preview/ folder is not created, nothing else in the run changed."""
    import engine.edit.preview as preview

    manifest = _export(tmp_path)
    run = tmp_path / "run"
    before = tree_digest(run)
    _enospc_after(monkeypatch, preview, "write_png_u8", 1)
    code, lines = run_cli("preview", manifest)
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and "disk full" in lines[0], lines
    assert not (manifest.parent / "preview").exists() and tree_digest(run) == before
    monkeypatch.undo()
    assert run_cli("preview", manifest)[0] == C.EXIT_OK
    names = sorted(p.name for p in (manifest.parent / "preview").iterdir())
    assert names == ["atlases.png", "checkerboard.mp4", "frames.png", "propagation.mp4"]


def _paint(folder: Path, size: tuple[int, int] = (32, 24)) -> Path:
    w, h = size
    paint = np.zeros((h, w, 4), np.float32)
    paint[4:20, 4:28] = (1.0, 0.2, 0.1, 1.0)  # across both halves: both layers change
    return write_png(folder / "paint.png", paint, 8)


def test_project_frame_on_a_full_disk_keeps_every_edit_layer(tmp_path, monkeypatch):
    """Two layers change; the second's new file hits ENOSPC: one line, every edit layer and history/ as before
    (the first layer's backup is removed again), and the same command afterwards lands the paint in both."""
    import engine.edit.project_frame as pf

    manifest = _export(tmp_path, layers=2)
    edits = tmp_path / "run" / EDITS_DIR
    before = tree_digest(edits)
    _enospc_after(monkeypatch, pf, "write_png", 1)
    code, lines = run_cli("project-frame", manifest, "--frame", "1", "--edit", _paint(tmp_path))
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and "disk full" in lines[0], lines
    assert tree_digest(edits) == before and not list((tmp_path / "run").glob(".*partial*"))
    monkeypatch.undo()
    assert run_cli("project-frame", manifest, "--frame", "1", "--edit", _paint(tmp_path))[0] == C.EXIT_OK
    after = tree_digest(edits)
    assert {n for n in after if not n.startswith("history")} == set(before)
    assert all(after[n] != d for n, d in before.items()), "both layers got the paint"
    assert sorted(n.split("/")[1].split(".")[0] for n in after if n.startswith("history")) == [
        "Background",
        "Foreground",
    ]


def test_project_frame_and_preview_refuse_a_run_folder_another_process_holds(tmp_path):
    """A child holding the run folder's lock: project-frame and preview (into the export) are one line naming it,
    exit 2, and the run folder is unchanged."""
    manifest = _export(tmp_path)
    run = tmp_path / "run"
    before = tree_digest(run)
    holder = hold_lock(run)
    try:
        for argv in (("project-frame", manifest, "--frame", "1", "--edit", _paint(tmp_path)), ("preview", manifest)):
            code, lines = run_cli(*argv)
            assert code == C.EXIT_BAD_INPUT and len(lines) == 1, lines
            assert f"in use by fit (pid {holder.pid} on " in lines[0] and RUN_LOCKED_FIX in lines[0], lines
    finally:
        holder.kill()
        holder.wait()
    assert tree_digest(run) == before


def test_movie_sizes_ffmpeg_writes_and_the_one_it_does_not():
    from engine.edit.movie import movie_size_problem

    for size in ((64, 36), (8192, 4320), (16384, 8640), (16383, 8639)):
        assert movie_size_problem(size) is None, size
    assert "16384x16384 movie is larger than FFmpeg encodes" in (movie_size_problem((16384, 16384)) or "")
    assert movie_size_problem((16383, 16383)) is not None  # padded to even sides, as the writer pads them


def test_a_movie_larger_than_ffmpeg_writes_is_one_line_before_any_frame(tmp_path, monkeypatch):
    """The limit lowered below the fake export's 32x24 stands for a 16384x16384 plate: render --movie and preview
    (whose movies are on by default) refuse in one line naming the fix, and write nothing; preview --no-movies runs."""
    import engine.edit.movie as movie

    manifest = _export(tmp_path)
    run = tmp_path / "run"
    before = tree_digest(run)
    monkeypatch.setattr(movie, "MOVIE_MAX_PADDED_PIXELS", 100 * 100)
    code, lines = run_cli("render", manifest, "--out", tmp_path / "out", "--movie", tmp_path / "e.mp4", "--no-bar")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1, lines
    assert "32x24 movie is larger than FFmpeg encodes" in lines[0] and "without --movie" in lines[0]
    code, lines = run_cli("preview", manifest)
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and "--no-movies" in lines[0], lines
    assert not (tmp_path / "out").exists() and not (tmp_path / "e.mp4").exists() and tree_digest(run) == before
    with pytest.raises(InputError, match="larger than FFmpeg encodes"):
        movie.MovieWriter(tmp_path / "w.mp4", 25.0, (32, 24))
    assert not list(tmp_path.glob("*.mp4")) and not list(tmp_path.glob(".w*"))
    assert run_cli("preview", manifest, "--no-movies")[0] == C.EXIT_OK
