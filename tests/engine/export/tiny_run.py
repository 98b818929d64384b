"""A tiny fitted run (48x32, 4 frames, 12 steps: seconds on a CPU) and its export, for tests of what export,
render, project-frame and preview do with the run folder, not of how good the fit is."""

from __future__ import annotations

import io
import shutil
from pathlib import Path

from engine.config import apply_overrides, preset_config
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.export.exporter import export_run
from engine.fit.fit_inputs import FitInputs
from tests.engine.fit_helpers import quiet_fit

SPEC = SceneSpec(width=48, height=32, frames=4, fg_size=(16, 12), fg_start=(10.0, 8.0))
TINY = {"steps": "12", "batch": "256", "eval_every": "12", "eval_pixels": "500", "bootstrap_steps": "6",
        "global_rigidity_steps": "3"}  # fmt: skip
ATLAS_SIZE = 32


#: A child process that holds a run folder's lock (``contract.run_lock``) as ``fit``, says so, and waits.
def make_run(root: Path) -> tuple[Path, Path, Path]:
    """The clip (frames, masks) under ``root/clip`` and its tiny fit in ``root/run``."""
    frames, masks = write_scene(make_scene(SPEC), root / "clip")
    cfg = apply_overrides(preset_config("draft"), TINY)
    run = root / "run"
    quiet_fit(run, cfg, FitInputs(frames, [masks]))
    return frames, masks, run


def export(run: Path, **kw) -> Path:  # type: ignore[no-untyped-def]
    """Export quietly (or into ``stream``); the manifest's path."""
    size, stream = kw.pop("atlas_size", ATLAS_SIZE), kw.pop("stream", None) or io.StringIO()
    return export_run(run, atlas_size=size, progress_bar=False, stream=stream, **kw)


def copy_root(src: Path, dest: Path) -> Path:
    """A copy of a test root (clip and run side by side), as a run folder moved with its plate would be."""
    shutil.copytree(src, dest, symlinks=True)
    return dest


def fail_exr_writes_after(monkeypatch, files: int) -> None:  # type: ignore[no-untyped-def]
    """Every EXR the export writes (atlases and passes) fails with ENOSPC, naming the file, once ``files`` were
    written: a disk that fills during the export."""
    import errno

    import engine.export.exporter as ex
    import engine.export.pass_writer as pass_writer

    calls = {"n": 0}
    real = ex.write_exr

    def full(path, channels, **kw):  # type: ignore[no-untyped-def]
        calls["n"] += 1
        if calls["n"] > files:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real(path, channels, **kw)

    monkeypatch.setattr(ex, "write_exr", full)
    monkeypatch.setattr(pass_writer, "write_exr", full)
