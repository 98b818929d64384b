"""``fit --auto-masks`` in one pass over the clip: opened once, decoded once, its flow computed once when the motion
analysis runs at the fit's working size (and cached either way), the masks handed to the fit in memory; the
masks written for the artist are exactly what the ``masks`` verb writes, and exactly what the fit used."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

import engine.fit.prepare
import engine.io.clip
from engine import contract as C
from engine.config import apply_overrides, preset_config
from engine.data.auto_masks import mask_iou, write_auto_masks
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.errors import InputError
from engine.fit.fit_inputs import FitInputs
from engine.fit.prepare import prepare_clip
from engine.io.clip import open_clip, read_masks
from engine.io.images import read_image
from engine.terms.lock import RUN_LOCK
from engine.terms.run_folder import FLOW_CACHE_DIR, SCENE_LAYERS_AUTO
from tests.engine_cli import run_cli
from tests.folders import tree_digest
from tests.stability.bad_inputs import TINY_FIT

SMALL = SceneSpec(width=96, height=64, frames=6, fg_size=(28, 20), fg_start=(20.0, 20.0))


def _count(monkeypatch, module, name: str, calls: dict[str, int]) -> None:
    real = getattr(module, name)

    def counted(*args, **kwargs):  # type: ignore[no-untyped-def]
        calls[name] = calls.get(name, 0) + 1
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, counted)


@pytest.mark.parametrize(
    ("long_edge", "flows"),
    [("512", 1), ("48", 2)],  # working size 96x64 = the analysis size; 48x32: the analysis keeps 96x64
)
def test_one_pass_over_the_clip(tmp_path, monkeypatch, long_edge, flows):
    frames_dir, masks_dir = write_scene(make_scene(SMALL), tmp_path / "clip")
    cfg = apply_overrides(preset_config("draft"), {"long_edge": long_edge})
    calls: dict[str, int] = {}
    _count(monkeypatch, engine.fit.prepare, "open_clip", calls)
    _count(monkeypatch, engine.fit.prepare, "compute_flow", calls)
    _count(monkeypatch, engine.fit.prepare, "read_masks", calls)
    _count(monkeypatch, engine.io.clip, "iter_frames", calls)  # every decoding pass over the frames goes through it
    run = tmp_path / "run"
    prepared = prepare_clip(FitInputs(frames_dir, auto_masks=True), cfg, run)
    assert calls == {"open_clip": 1, "iter_frames": 1, "compute_flow": flows}  # no mask file is read back
    assert len(list((run / FLOW_CACHE_DIR).glob("*.npz"))) == flows

    folder = (run / C.AUTO_MASKS_DIR).resolve()
    assert prepared.mask_dirs == [str(folder)] and prepared.layers_source == SCENE_LAYERS_AUTO
    assert prepared.masks_note is not None and prepared.masks_note.startswith("foreground in 6/6 frames")
    monkeypatch.undo()
    info = open_clip(frames_dir)
    # the fit's masks are the written files read back at the working size; the files are the `masks` verb's
    assert np.array_equal(prepared.masks[0], read_masks(folder, info, prepared.size))
    verb = write_auto_masks(frames_dir, tmp_path / "verb")
    for name in verb.files:
        ours = folder / name.rsplit("/", 1)[-1]
        assert np.array_equal(read_image(ours)[0], read_image(name)[0]), ours.name
    iou = mask_iou(prepared.masks[0], read_masks(masks_dir, info, prepared.size))
    assert iou.min() > 0.8, iou


def test_masks_already_in_the_run_folder_are_used_not_searched_again(tmp_path, monkeypatch):
    """``masks PLATE --out RUN/auto_masks`` then ``fit --auto-masks --out RUN`` (a farm's masks task, then its fit;
    or an artist who fixed the found masks): the fit reads those masks, as ``--mask`` would, and finds nothing
    again; a hand fix in them is what the fit gets."""
    frames_dir, _ = write_scene(make_scene(SMALL), tmp_path / "clip")
    run = tmp_path / "run"
    folder = (run / C.AUTO_MASKS_DIR).resolve()
    written = write_auto_masks(frames_dir, folder)
    first = folder / written.files[0].rsplit("/", 1)[-1]
    fixed = np.zeros_like(read_image(first)[0][..., 0], np.uint8)
    fixed[5:15, 5:15] = 255
    cv2.imwrite(str(first), fixed)  # the artist's fix of frame 0
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    calls: dict[str, int] = {}
    _count(monkeypatch, engine.fit.prepare, "auto_masks", calls)
    cfg = apply_overrides(preset_config("draft"), {"long_edge": "512"})
    prepared = prepare_clip(FitInputs(frames_dir, auto_masks=True), cfg, run)
    assert calls == {}, "the motion search ran again"
    assert prepared.mask_dirs == [str(folder)] and prepared.layers_source == SCENE_LAYERS_AUTO
    assert np.array_equal(prepared.masks[0], read_masks(folder, open_clip(frames_dir), prepared.size))
    assert prepared.masks[0][0, 5:15, 5:15].all() and prepared.masks[0][0].sum() == 100
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before, "nothing rewritten"


def test_masks_a_fit_found_on_other_frames_are_refused_not_reused(tmp_path, monkeypatch):
    """The fit records beside the masks it found the fingerprint of the frames it found them on: the same clip
    again reuses them (not searched again); another plate with the same frame names (a ``--refit`` on other
    footage) is one line naming the folder and the ways out, and the folder stays as it is."""
    frames_dir, _ = write_scene(make_scene(SMALL), tmp_path / "clip")
    other_dir, _ = write_scene(make_scene(SceneSpec(**{**SMALL.__dict__, "fg_start": (50.0, 30.0)})), tmp_path / "b")
    run = tmp_path / "run"
    cfg = apply_overrides(preset_config("draft"), {"long_edge": "512"})
    prepare_clip(FitInputs(frames_dir, auto_masks=True), cfg, run)
    folder = (run / C.AUTO_MASKS_DIR).resolve()
    assert (folder / engine.fit.prepare.AUTO_MASKS_PLATE).is_file()
    before = tree_digest(folder)
    calls: dict[str, int] = {}
    _count(monkeypatch, engine.fit.prepare, "auto_masks", calls)
    prepare_clip(FitInputs(frames_dir, auto_masks=True), cfg, run)
    assert calls == {} and tree_digest(folder) == before
    with pytest.raises(InputError, match="the masks an earlier fit found here are of other frames") as err:
        prepare_clip(FitInputs(other_dir, auto_masks=True), cfg, run)
    assert str(err.value).startswith(str(run / C.AUTO_MASKS_DIR)) and "delete the folder" in str(err.value)
    assert tree_digest(folder) == before


def test_empty_masks_already_in_the_run_folder_give_a_background_only_fit(tmp_path):
    """What ``masks`` writes when nothing moves (every mask empty) makes ``fit --auto-masks`` fit the background
    only, as when its own search finds nothing, rather than a foreground layer that no frame has."""
    frames_dir, _ = write_scene(make_scene(SMALL), tmp_path / "clip")
    run = tmp_path / "run"
    folder = run / C.AUTO_MASKS_DIR
    folder.mkdir(parents=True)
    for path in sorted(frames_dir.iterdir()):
        cv2.imwrite(str(folder / f"{path.stem}.png"), np.zeros((SMALL.height, SMALL.width), np.uint8))
    cfg = apply_overrides(preset_config("draft"), {"long_edge": "512"})
    prepared = prepare_clip(FitInputs(frames_dir, auto_masks=True), cfg, run)
    assert prepared.mask_dirs == [] and prepared.masks.shape[0] == 0
    assert prepared.masks_note is not None and "background-only" in prepared.masks_note


def test_a_partial_set_of_masks_in_the_run_folder_is_still_refused(tmp_path):
    frames_dir, _ = write_scene(make_scene(SMALL), tmp_path / "clip")
    folder = tmp_path / "run" / C.AUTO_MASKS_DIR
    folder.mkdir(parents=True)
    first = sorted(frames_dir.iterdir())[0]
    cv2.imwrite(str(folder / f"{first.stem}.png"), np.zeros((SMALL.height, SMALL.width), np.uint8))
    cfg = preset_config("draft")
    with pytest.raises(InputError, match="already holds"):
        prepare_clip(FitInputs(frames_dir, auto_masks=True), cfg, tmp_path / "run")


def test_a_link_planted_at_the_run_folders_auto_masks_is_refused_and_nothing_is_written(tmp_path):
    """``RUN/auto_masks`` is the engine's own folder: a symbolic link there (to an empty folder, or to one that
    holds a whole set of masks) is one line naming it, before anything is decoded; the folder it points to is left
    exactly as it was."""
    frames_dir, _ = write_scene(make_scene(SMALL), tmp_path / "clip")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    run = tmp_path / "run"
    run.mkdir()
    (run / C.AUTO_MASKS_DIR).symlink_to(elsewhere, target_is_directory=True)
    for holds_masks in (False, True):
        if holds_masks:
            write_auto_masks(frames_dir, elsewhere)
        before, run_before = tree_digest(elsewhere), _entries(run)
        code, lines = run_cli("fit", frames_dir, "--auto-masks", "--out", run, *TINY_FIT)
        assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and lines[0].startswith("error: "), lines
        assert C.AUTO_MASKS_DIR in lines[0] and "symbolic link" in lines[0] and "delete the link" in lines[0]
        assert tree_digest(elsewhere) == before
        assert _entries(run) == run_before


def _entries(folder: Path) -> list[str]:
    """What ``folder`` holds, by name, but its lock file (the OS's bookkeeping: a fit takes the lock first)."""
    return sorted(p.name for p in folder.iterdir() if p.name != RUN_LOCK)
