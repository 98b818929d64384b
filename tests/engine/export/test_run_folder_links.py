"""Links in a run folder: what the user links on purpose is written through, what the engine writes never is.

The run folder, ``exports/`` and ``edits/`` may be symbolic links to folders elsewhere (another disk): the user made
them, and the engine writes into them as into the folders themselves. A FILE the engine writes is never written
through a link: the run files, the checkpoint, the edit layers and layout, the export's files and the previews are
written to a temp file and renamed over the name, which replaces a link itself and never touches its target; the
two files written in place, the lock and ``fit.log``, refuse a link in one line. The engine's own hidden staging
folders (``exports/.vNNN.partial``, ``.vNNN.chunks``) are removed or refused when they are links. Every test hashes
the whole tree around the run (the links' targets included) before and after.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from engine import contract as C
from engine.export.manifest import Manifest
from engine.io.atomic import append_text
from engine.terms.cli import EXPORT_STAGES
from engine.terms.export_names import (
    EDIT_LAYER_EXT,
    EDITS_DIR,
    EDITS_LAYOUT,
    EXPORT_CHUNKS_SUFFIX,
    PASSES_DIR,
    layer_name,
    pass_file_name,
)
from engine.terms.lock import IN_PLACE_UNSAFE_FIX, RUN_LOCK
from engine.terms.run_folder import RUN_CLIP, RUN_CONFIG, RUN_LOG, SCENE_FILE
from tests.engine.export.tiny_run import copy_root, export, make_run
from tests.engine_cli import run_cli
from tests.untouched import digest_outside

#: The run files a refine reads, and those of them it writes again (each atomically).
RUN_FILES = (RUN_CONFIG, RUN_CLIP, SCENE_FILE, C.RUN_METRICS, C.RUN_CHECKPOINT)
REFINE_WRITES = (RUN_CONFIG, C.RUN_METRICS, C.RUN_CHECKPOINT)


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A tiny fitted run with one export (v001) and its previews, under ``root``."""
    root = tmp_path_factory.mktemp("run_folder_links") / "root"
    _, _, run = make_run(root)
    manifest = export(run)
    code, err = run_cli("preview", manifest)
    assert code == 0, err
    return root


@pytest.fixture
def root(base, tmp_path):
    return copy_root(base, tmp_path / "root")


def _link_out(name: Path, elsewhere: Path) -> Path:
    """Move the file ``name`` to ``elsewhere`` (outside the run folder) and leave a symbolic link to it in its place."""
    target = elsewhere / name.name
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.move(name, target)
    name.symlink_to(target)
    return target


def _plain(path: Path) -> bool:
    return path.is_file() and not path.is_symlink()


def test_an_exports_folder_linked_to_another_disk_takes_the_export(root):
    """The allowed link: ``exports/`` moved to another disk and linked back. The new version lands there, whole, and
    reads back through the link; nothing else outside the run changes."""
    run = root / "run"
    disk = root.parent / "other_disk" / "sh010_exports"
    disk.parent.mkdir()
    shutil.move(run / C.EXPORTS_DIR, disk)
    (run / C.EXPORTS_DIR).symlink_to(disk, target_is_directory=True)
    before = digest_outside(root.parent, run, disk)
    manifest_path = export(run)
    assert manifest_path == run.resolve() / C.EXPORTS_DIR / "v002" / C.MANIFEST_NAME
    assert (disk / "v002" / C.MANIFEST_NAME).is_file() and not list(disk.glob(".*"))
    manifest = Manifest(run / C.EXPORTS_DIR / "v002")
    frames = manifest.data["passes"]["frames"]
    assert frames == [0, 1, 2, 3]
    assert all((disk / "v002" / PASSES_DIR / pass_file_name(n)).is_file() for n in frames)
    assert all(manifest.resolve(layer["atlas_exr"]).is_file() for layer in manifest.data["layers"])
    assert digest_outside(root.parent, run, disk) == before


def _project_paint(manifest_path: Path, folder: Path) -> tuple[int, list[str], Path]:
    """project-frame of a red rectangle on frame 1 through ``manifest_path``: (exit code, stderr lines, paint file)."""
    import numpy as np

    from engine.io.images import write_png

    width, height = Manifest(manifest_path).data["clip"]["resolution"]
    paint = np.zeros((height, width, 4), np.float32)
    paint[1:-1, 1:-1] = (1.0, 0.2, 0.1, 1.0)
    paint_file = write_png(folder / "paint.png", paint, 8)
    code, err = run_cli(C.VERB_PROJECT_FRAME, manifest_path, "--frame", "1", "--edit", paint_file)
    return code, err, paint_file


def test_paint_lands_in_a_run_folder_that_is_a_link_to_another_disk(root):
    """The whole run folder moved to another disk and linked back: painting through the link writes its ``edits/``
    (a changed layer, its history copy) and nothing else outside the run changes."""
    run = root / "run"
    disk = root.parent / "other_disk" / "sh010_run"
    disk.parent.mkdir()
    shutil.move(run, disk)
    run.symlink_to(disk, target_is_directory=True)
    edits_before = {p.name: p.read_bytes() for p in (disk / EDITS_DIR).glob("*.png")}
    before = digest_outside(root.parent, disk / EDITS_DIR, disk / RUN_LOCK, root.parent / "paint.png")
    code, err, _ = _project_paint(run / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME, root.parent)
    assert code == C.EXIT_OK, err
    changed = {p.name for p in (disk / EDITS_DIR).glob("*.png") if p.read_bytes() != edits_before.get(p.name)}
    assert changed, "the paint reached no edit layer of the run"
    assert digest_outside(root.parent, disk / EDITS_DIR, disk / RUN_LOCK, root.parent / "paint.png") == before


def test_painting_through_an_exports_folder_linked_elsewhere_is_one_line_and_writes_nothing(root):
    """``exports/`` linked to another disk: export, preview and render read through it, but the export found there
    is not under its run folder, so its edit paths lead out of the folders a manifest may write (the run's
    ``edits/`` is found from where the manifest really is): project-frame refuses in one line, nothing changes."""
    run = root / "run"
    disk = root.parent / "other_disk" / "sh010_exports"
    disk.parent.mkdir()
    shutil.move(run / C.EXPORTS_DIR, disk)
    (run / C.EXPORTS_DIR).symlink_to(disk, target_is_directory=True)
    lock = disk / "v001" / RUN_LOCK  # the export is taken for its own run, and locked as one
    before = digest_outside(root.parent, root.parent / "paint.png", lock)
    code, err, _ = _project_paint(run / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME, root.parent)
    assert code == C.EXIT_BAD_INPUT and len(err) == 1, err
    assert "leaves the run folder's edits/ and this export" in err[0]
    assert digest_outside(root.parent, root.parent / "paint.png", lock) == before


def test_run_files_linked_out_are_replaced_by_a_refine_and_their_targets_are_untouched(root):
    """config, clip record, scene analysis, metrics and checkpoint, each a link to a file outside: the refine reads
    them through the links and writes its own config, metrics and checkpoint in their place (temp file + rename):
    those links become plain files, the ones it only read stay links, and every file they pointed to keeps every
    byte."""
    run = root / "run"
    elsewhere = root.parent / "elsewhere"
    targets = {name: _link_out(run / name, elsewhere) for name in RUN_FILES}
    before = digest_outside(root.parent, run)
    code, err = run_cli("fit", "--out", run, "--refine", "2", "--no-bar")
    assert code == 0, err
    assert all(_plain(run / name) for name in REFINE_WRITES)
    assert all((run / name).is_symlink() for name in RUN_FILES if name not in REFINE_WRITES)
    assert (run / C.RUN_CHECKPOINT).read_bytes() != targets[C.RUN_CHECKPOINT].read_bytes()  # the refined fit's
    assert digest_outside(root.parent, run) == before


def test_a_fit_log_linked_out_is_refused_in_one_line_and_its_target_is_untouched(root):
    """The log is appended to, the one write in place: a link there stops the fit in one line (exit 2) before it
    writes a line through it."""
    run = root / "run"
    log = run / RUN_LOG
    if not log.exists():
        log.write_text("", encoding="utf-8")
    target = _link_out(log, root.parent / "elsewhere")
    before = digest_outside(root.parent, run)
    code, err = run_cli("fit", "--out", run, "--refine", "2", "--no-bar")
    assert (code, err) == (C.EXIT_BAD_INPUT, [f"error: {log}: is a symbolic link — {IN_PLACE_UNSAFE_FIX}"])
    assert digest_outside(root.parent, run) == before and log.is_symlink() and target.exists()


def test_an_append_refuses_a_hard_link_and_writes_a_plain_file(tmp_path):
    outside, log = tmp_path / "outside.txt", tmp_path / "run" / RUN_LOG
    outside.write_text("kept\n", encoding="utf-8")
    log.parent.mkdir()
    os.link(outside, log)
    with pytest.raises(Exception, match=f"^{log}: is a hard link \\(2 names for one file\\) — "):
        append_text(log, "line\n")
    assert outside.read_text(encoding="utf-8") == "kept\n"
    os.unlink(log)
    append_text(log, "a\n")
    append_text(log, "b\n")
    assert log.read_text(encoding="utf-8") == "a\nb\n" and outside.read_text(encoding="utf-8") == "kept\n"


def test_edit_layer_and_layout_links_are_replaced_by_an_export_never_written_through(root):
    """A dangling link where export creates a new edit layer, and the layout a link to a copy outside that does not
    record that layer yet: export writes both in place of the links; the dangling target is not created, the copy
    keeps its bytes."""
    run = root / "run"
    edits = run / EDITS_DIR
    layer = edits / f"{layer_name(1, 2)}{EDIT_LAYER_EXT}"
    layer.unlink()
    missing = root.parent / "elsewhere" / "never.png"
    layer.symlink_to(missing)
    layout = _link_out(edits / EDITS_LAYOUT, root.parent / "elsewhere")
    recorded = json.loads(layout.read_text(encoding="utf-8"))
    del recorded["layers"][layer.stem]
    layout.write_text(json.dumps(recorded), encoding="utf-8")
    before = digest_outside(root.parent, run)
    export(run)
    assert _plain(layer) and _plain(edits / EDITS_LAYOUT) and not missing.exists()
    assert layout.exists() and digest_outside(root.parent, run) == before


def test_a_staging_name_planted_as_a_link_is_removed_not_followed(root):
    """``exports/.v002.partial`` a link to a folder outside (where a killed export's leftover would be): the export
    removes the link, not the folder's files, and publishes v002."""
    run = root / "run"
    outside = root.parent / "elsewhere" / "shots"
    outside.mkdir(parents=True)
    (outside / "plate.0001.exr").write_bytes(b"not an export")
    (run / C.EXPORTS_DIR / ".v002.partial").symlink_to(outside, target_is_directory=True)
    before = digest_outside(root.parent, run)
    assert export(run).parent.name == "v002"
    assert not os.path.lexists(run / C.EXPORTS_DIR / ".v002.partial")
    assert digest_outside(root.parent, run) == before


@pytest.mark.parametrize("stage", EXPORT_STAGES)
def test_a_staged_export_folder_planted_as_a_link_is_refused_in_one_line(root, stage):
    run = root / "run"
    outside = root.parent / "elsewhere" / "chunks"
    (outside / PASSES_DIR).mkdir(parents=True)
    chunks = run / C.EXPORTS_DIR / f".v002{EXPORT_CHUNKS_SUFFIX}"
    chunks.symlink_to(outside, target_is_directory=True)
    before, inside = digest_outside(root.parent, run), digest_outside(run, run / RUN_LOCK)
    code, err = run_cli("export", run, "--no-bar", "--into", "v002", "--stage", stage, "--atlas-size", "32")
    assert code == C.EXIT_BAD_INPUT and len(err) == 1
    assert err[0].startswith(f"error: {chunks}: is a symbolic link, and a staged export's folders are the engine's own")
    assert digest_outside(root.parent, run) == before and digest_outside(run, run / RUN_LOCK) == inside


def test_a_preview_file_linked_out_is_replaced_and_its_target_untouched(root):
    run = root / "run"
    preview = run / C.EXPORTS_DIR / "v001" / "preview"
    sheet = sorted(p for p in preview.iterdir() if p.suffix == ".png")[0]
    target = _link_out(sheet, root.parent / "elsewhere")
    before = digest_outside(root.parent, run)
    code, err = run_cli("preview", run / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME)
    assert code == 0 and err == [], err  # the files written are said once, on stdout
    assert _plain(sheet) and target.exists() and digest_outside(root.parent, run) == before
