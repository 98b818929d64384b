"""`engine relink`: a shot moved whole and then its run folder moved alone names its plate nowhere (neither the
manifest's relative paths nor the absolute ones of the export reach it); told where the plate is, the export renders
the same bytes as before the moves, and its Nuke script reads the plate there. A script the artist saved over the
export's is left as it is; a folder that is not the export's plate is refused in one line, the manifest untouched."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from engine import contract as C
from engine.terms.export_names import NUKE_SCRIPT_NAME
from tests.engine.export import nk_script as NK
from tests.engine.export.test_farm_paths import _export, _latest, _render
from tests.engine.export.tiny_run import make_run
from tests.engine_cli import run_cli
from tests.folders import tree_digest, visible_digest


def _plate_read(script: Path) -> Path:
    nk = NK.parse(script.read_text(encoding="utf-8"))
    (plate,) = [n for n in nk.nodes if n.cls == "Read" and n.name == "NA_Plate"]
    return Path(os.path.normpath(NK.file_for(plate, script.parent, 0)))


def test_a_shot_moved_and_then_its_run_moved_alone_reads_its_plate_again_once_told_where(tmp_path):
    shot = tmp_path / "a"
    make_run(shot)
    assert _export(shot / "run") == (0, [])
    assert _render(shot / "run", tmp_path / "before") == (0, [])
    shot.rename(tmp_path / "b")  # the shot moved whole: the manifest's relative paths still hold
    alone = tmp_path / "c" / "run"
    alone.parent.mkdir()
    shutil.move(tmp_path / "b" / "run", alone)  # then the run alone: neither path reaches the plate
    manifest = Path(_latest(alone))
    script = manifest.parent / NUKE_SCRIPT_NAME
    assert not _plate_read(script).exists()
    code, lines = _render(alone, tmp_path / "lost")
    assert code == C.EXIT_BAD_INPUT and f"{C.VERB_RELINK} MANIFEST {C.RELINK_PLATE_ARG} PLATE" in lines[0], lines

    plate = tmp_path / "b" / "clip" / "frames"
    untouched = tree_digest(tmp_path / "b")
    code, lines = run_cli(C.VERB_RELINK, manifest, C.RELINK_PLATE_ARG, plate)
    assert code == C.EXIT_OK, lines
    assert lines == [f"{manifest}: reads the plate at {plate}", f"{script}: reads the plate at {plate}"]
    assert tree_digest(tmp_path / "b") == untouched  # the plate is read, never written
    data = json.loads(manifest.read_text())
    assert data["clip"]["source"] == "../../../../b/clip/frames" and data["clip"]["source_absolute"] == str(plate)
    assert data["clip"]["frame_files_absolute"] == [str(plate / f"{n:05d}.png") for n in range(4)]
    assert _render(alone, tmp_path / "after") == (0, [])
    assert visible_digest(tmp_path / "after") == visible_digest(tmp_path / "before") != {}
    assert _plate_read(script) == plate / "00000.png"

    # once more, naming a frame file of the same plate: nothing to do
    code, lines = run_cli(C.VERB_RELINK, manifest, C.RELINK_PLATE_ARG, plate / "00002.png")
    assert code == C.EXIT_OK and lines == [f"{manifest}: already reads the plate at {plate}"], lines


def test_relink_leaves_a_script_saved_over_the_exports_and_refuses_another_plate(tmp_path):
    shot = tmp_path / "a"
    make_run(shot)
    assert _export(shot / "run") == (0, [])
    manifest = Path(_latest(shot / "run"))
    script = manifest.parent / NUKE_SCRIPT_NAME
    before = manifest.read_bytes()

    other = tmp_path / "other"
    shutil.copytree(shot / "clip" / "frames", other)
    (other / "00003.png").unlink()
    code, lines = run_cli(C.VERB_RELINK, manifest, C.RELINK_PLATE_ARG, other)
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1, lines
    assert lines[0].startswith(f"error: {other}: has no plate frame 00003.png (the export's)"), lines
    assert manifest.read_bytes() == before

    shutil.copytree(shot / "clip" / "frames", tmp_path / "moved")
    saved = script.read_text() + "# the artist's comp\n"
    script.write_text(saved)
    code, lines = run_cli(C.VERB_RELINK, manifest, C.RELINK_PLATE_ARG, tmp_path / "moved")
    assert code == C.EXIT_OK and len(lines) == 2, lines
    assert lines[1].startswith(f"{script}: left as it is (saved since the export); write a new script with "), lines
    assert script.read_text() == saved
    assert json.loads(manifest.read_text())["clip"]["source_absolute"] == str(tmp_path / "moved")
