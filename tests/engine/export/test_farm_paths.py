"""A run folder opened from another mount point: clip.json records the plate, its frames and the masks both as given
(absolute) and relative to the run folder, and reads whichever is there. Moved (its parent renamed) together with
its plate, the run exports, renders the same bytes and is found fitted by the same farm task naming the new paths;
moved away from its plate, it still exports (the plate only chooses how far each layer follows the flow: one warning
line, and the few-frames reach), and render and fit --resume name the missing plate and how to remap it in one
line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from engine import contract as C
from engine.terms.cli import FIT_RESUME_IF_STARTED_FLAG
from engine.terms.run_folder import RUN_CLIP
from tests.engine.export.tiny_run import ATLAS_SIZE, TINY, make_run
from tests.engine_cli import run_cli
from tests.folders import tree_digest, visible_digest, visible_names


def _export(run) -> tuple[int, list[str]]:  # type: ignore[no-untyped-def]
    return run_cli("export", run, "--no-bar", "--atlas-size", str(ATLAS_SIZE))


def _latest(run) -> str:  # type: ignore[no-untyped-def]
    versions = sorted(p for p in (run / C.EXPORTS_DIR).iterdir() if not p.name.startswith("."))
    return str(versions[-1] / C.MANIFEST_NAME)


def _render(run, out) -> tuple[int, list[str]]:  # type: ignore[no-untyped-def]
    return run_cli("render", _latest(run), "--out", out, "--no-bar")


def test_a_run_moved_with_its_plate_and_without_it(tmp_path):
    first = tmp_path / "a"
    make_run(first)
    record = json.loads((first / "run" / RUN_CLIP).read_text())
    assert record["source"] == str(first / "clip" / "frames")
    assert record["source_relative"] == "../clip/frames"
    assert record["masks_relative"] == ["../clip/masks"]
    assert record["frame_files_relative"] == [f"../clip/frames/{n:05d}.png" for n in range(4)]
    assert _export(first / "run") == (0, [])
    assert _render(first / "run", tmp_path / "before") == (0, [])

    # the parent holding plate and run renamed (another mount point): the recorded absolute paths are gone
    moved = tmp_path / "b"
    first.rename(moved)
    assert _export(moved / "run") == (0, [])
    manifest = json.loads((moved / "run" / C.EXPORTS_DIR / "v002" / C.MANIFEST_NAME).read_text())
    assert manifest["clip"]["source"] == "../../../clip/frames"
    assert _render(moved / "run", tmp_path / "after") == (0, [])
    assert visible_digest(tmp_path / "after") == visible_digest(tmp_path / "before") != {}
    # the farm's retried fit task, naming the plate where it now is: found finished, nothing changed
    sets = [a for k, v in TINY.items() for a in ("--set", f"{k}={v}")]
    argv = ["fit", moved / "clip" / "frames", "--mask", moved / "clip" / "masks", "--out", moved / "run",
            "--preset", "draft", *sets, "--no-bar", FIT_RESUME_IF_STARTED_FLAG]  # fmt: skip
    before = tree_digest(moved / "run")
    code, lines = run_cli(*argv)
    assert code == C.EXIT_OK and lines[0].startswith("already fitted"), lines
    assert tree_digest(moved / "run") == before

    # the run folder alone moved elsewhere: neither path reaches the plate
    alone = tmp_path / "c" / "run"
    alone.parent.mkdir()
    shutil.move(moved / "run", alone)
    plate = str(first / "clip" / "frames")
    code, lines = _export(alone)
    assert code == C.EXIT_OK and len(lines) == 1, lines
    assert lines[0].startswith(f"warning: {plate}: the plate cannot be read (does not exist): "), lines
    assert lines[0].endswith("the layers follow the flow over a few frames, not along whole trajectories "
                             "(which needs the plate to choose)")  # fmt: skip
    code, lines = _render(alone, tmp_path / "lost")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and lines[0].startswith(f"error: {plate}: "), lines
    assert not (tmp_path / "lost").exists()
    code, lines = run_cli("fit", "--resume", "--out", alone, "--no-bar", "--set", "steps=14")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and lines[0].startswith(f"error: {plate}: "), lines
    assert "move the plate to this path" in lines[0] and "../clip/frames" in lines[0]


def test_a_shot_folder_copied_whole_keeps_to_its_own_plate(tmp_path):
    """Copied whole (run, plate, masks) and refined there, the shot's export names its own plate, so it still
    renders once the original is gone; a run copied alone beside ANOTHER plate at the same relative place keeps to
    the plate it was fitted on."""
    first = tmp_path / "a"
    make_run(first)
    copy = tmp_path / "copy"
    shutil.copytree(first, copy)
    record = json.loads((copy / "run" / RUN_CLIP).read_text())
    assert record["source"] == str(first / "clip" / "frames")  # the copy's clip.json names the original
    code, lines = run_cli("fit", C.FIT_REFINE_FLAG, "2", "--out", copy / "run", "--no-bar")
    assert code == C.EXIT_OK, lines
    assert _export(copy / "run") == (0, [])
    manifest = json.loads(Path(_latest(copy / "run")).read_text())
    assert manifest["clip"]["source"] == "../../../clip/frames"
    assert [f.split("/clip/")[0] for f in manifest["clip"]["frame_files"]] == ["../../.."] * 4

    # the original run alone, copied beside another shot whose plate has the same layout but other pixels
    other = tmp_path / "other"
    shutil.copytree(first / "clip", other / "clip")
    frame0 = other / "clip" / "frames" / "00000.png"
    frame0.write_bytes(frame0.read_bytes()[:-16] + bytes(16))  # another plate's first frame (same name, size)
    shutil.copytree(first / "run", other / "run")
    assert _export(other / "run") == (0, [])
    manifest = json.loads(Path(_latest(other / "run")).read_text())
    assert manifest["clip"]["source"] == "../../../../a/clip/frames"  # the plate it was fitted on

    shutil.rmtree(first)
    assert _render(copy / "run", tmp_path / "rendered") == (0, [])
    assert len(visible_names(tmp_path / "rendered")) == 4


def test_a_run_moved_alone_renders_from_the_plate_it_left_where_it_was(tmp_path):
    """The manifest also keeps the plate's paths as they were at export: the run folder moved on its own (its
    relative plate paths now name nothing) still renders the same bytes from the plate that stayed; an older
    manifest without them names the missing plate in one line."""
    first = tmp_path / "a"
    make_run(first)
    assert _export(first / "run") == (0, [])
    manifest = json.loads(Path(_latest(first / "run")).read_text())
    frames = first / "clip" / "frames"
    assert manifest["clip"]["source_absolute"] == str(frames)
    assert manifest["clip"]["frame_files_absolute"] == [str(frames / f"{n:05d}.png") for n in range(4)]
    assert _render(first / "run", tmp_path / "before") == (0, [])

    alone = tmp_path / "elsewhere" / "run"
    alone.parent.mkdir()
    shutil.move(first / "run", alone)
    assert _render(alone, tmp_path / "after") == (0, [])
    assert tree_digest(tmp_path / "after") == tree_digest(tmp_path / "before") != {}

    path = Path(_latest(alone))
    older = json.loads(path.read_text())
    del older["clip"]["source_absolute"], older["clip"]["frame_files_absolute"]
    path.write_text(json.dumps(older))
    code, lines = _render(alone, tmp_path / "lost")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1, lines
    assert lines[0].startswith(f"error: {tmp_path / 'elsewhere' / 'clip' / 'frames'}"), lines
