"""The add-on's files beside a Run Folder (``core.run_files``)."""

from __future__ import annotations

import pytest
from fake_export import make_export
from neural_atlas.addon.core.run_files import (
    SAVE_EDITS_HOLDER,
    RunFiles,
    clear_numbered_pngs,
    edits_lock,
    fresh_dir,
    png_files,
)

from engine import contract as C


def test_the_files_beside_a_run_folder(tmp_path):
    files = RunFiles(str(tmp_path / "run"))
    assert (files.fit_log, files.masks_log, files.estimate_log, files.scribbles) == tuple(
        str(tmp_path / f"run.{name}") for name in ("blender.log", "masks.log", "estimate.log", "scribbles")
    )
    assert files.layer_masks(2) == str(tmp_path / "run.masks" / "layer2")
    assert not files.has_fit()
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / C.RUN_CHECKPOINT).write_text("x")
    assert files.has_fit() and files.fresh_auto_masks() == str(tmp_path / "run" / C.AUTO_MASKS_DIR)


def test_fresh_dir_never_reuses_a_folder_with_files(tmp_path):
    base = tmp_path / "auto_masks"
    assert fresh_dir(str(base)) == str(base)
    base.mkdir()
    assert fresh_dir(str(base)) == str(base)  # empty: reused
    (base / "00000.png").write_bytes(b"")
    (tmp_path / "auto_masks_2").write_text("a file, not a folder")
    assert fresh_dir(str(base)) == str(tmp_path / "auto_masks_3")


def test_clear_numbered_pngs_touches_only_those(tmp_path):
    for name in ("00003.png", "00004.PNG", "notes.png", "00005.txt"):
        (tmp_path / name).write_bytes(b"")
    clear_numbered_pngs(str(tmp_path))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["00005.txt", "notes.png"]
    assert png_files(str(tmp_path)) == [str(tmp_path / "notes.png")]
    assert png_files(str(tmp_path / "missing")) == []
    clear_numbered_pngs(str(tmp_path / "missing"))


def test_the_addon_writes_edit_layers_only_under_the_run_folder_lock(tmp_path):
    """``edits_lock`` is the run folder's lock of the export a manifest belongs to: while a real engine process
    holds it (a fit), the add-on's Save Edits is refused with one line naming that process; once it is gone, the
    add-on holds it and a preview into the export run meanwhile is refused naming Blender."""
    import subprocess

    from tests.addon.helpers import engine_python
    from tests.folders import hold_lock
    from tests.paths import ROOT

    python = engine_python("preview", "numpy")

    manifest = make_export(tmp_path)
    run = tmp_path / "run"
    holder = hold_lock(run)
    try:
        with pytest.raises(Exception) as refused, edits_lock(str(manifest), SAVE_EDITS_HOLDER):
            pass
        assert type(refused.value).__name__ == "RunLocked"
        assert f"in use by fit (pid {holder.pid} on " in str(refused.value) and "\n" not in str(refused.value)
    finally:
        holder.kill()
        holder.wait()
    with edits_lock(str(manifest), SAVE_EDITS_HOLDER):
        out = subprocess.run(
            [python, "-m", "engine", "preview", str(manifest), "--no-movies"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=300,
        )
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert out.returncode == C.EXIT_BAD_INPUT and len(lines) == 1 and "Blender Save Edits" in lines[0], out.stderr
