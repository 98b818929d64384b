"""``fit --mask M``: by default (and with ``--auto-parts``) the jumping body split into its body and its swinging limb
before the fit (strokes in RUN_DIR/parts, the fit's recorded scribbles, one layer per part), the same command run
again leaves the finished fit as it is, strokes already in RUN_DIR/parts (the artist's fix) are used as they are, an
object moving as one piece is fitted as one layer with no folder; ``--no-auto-parts`` never splits. The default
leaves alone what it does not apply to (two masks, the paper model, a single frame, an empty mask), where
``--auto-parts`` is one line before anything is written."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from bench.motion_scenes import make_motion_scene, write_motion_clip
from engine import contract as C
from engine.config import preset_config
from engine.data.scribbles import NO_LABEL, read_scribbles
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.errors import InputError
from engine.fit.auto_parts import parts_wanted
from engine.fit.fitted_run import load_fitted
from engine.fit.run_folder import RunFolder
from engine.io.clip import open_clip
from engine.terms.cli import FIT_RESUME_IF_STARTED_FLAG
from engine.terms.run_folder import AUTO_PARTS_DIR, FIT_AUTO_MASKS_FLAG, FIT_AUTO_PARTS_FLAG
from tests.engine_cli import run_cli
from tests.folders import tree_digest
from tests.stability.bad_inputs import TINY_FIT


@pytest.fixture(scope="module")
def jumping(tmp_path_factory) -> Path:
    """The limbs_jump scene as the bench makes it (480x272, 36 frames; as ``test_parts_command``)."""
    scene = make_motion_scene("limbs_jump", width=480, height=272, frames=36)
    return write_motion_clip(scene, tmp_path_factory.mktemp("scene") / "limbs_jump")


@pytest.fixture(scope="module")
def rigid(tmp_path_factory) -> tuple[Path, Path]:
    return write_scene(
        make_scene(SceneSpec(width=160, height=96, frames=8, fg_size=(40, 30))), tmp_path_factory.mktemp("rigid")
    )


@pytest.mark.slow  # the scene at the bench's size, its flow and a tiny fit: about 45 s
def test_the_jumping_body_is_fitted_as_its_parts_by_default_and_the_same_command_again_changes_nothing(
    jumping, tmp_path
):
    """No flag: the fit's default splits the one mask (what ``--auto-parts`` does, which insists on it)."""
    run = tmp_path / "run"
    argv = ["fit", jumping / "frames", "--mask", jumping / "masks", "--out", run, *TINY_FIT]
    code, lines = run_cli(*argv)
    assert code == C.EXIT_OK, lines
    assert any(line.startswith("auto parts: 2 parts that move apart") for line in lines), lines
    folder = RunFolder(run)
    assert folder.read_clip().scribbles == str(folder.auto_parts.resolve())
    info = open_clip(jumping / "frames")
    labels = read_scribbles(folder.auto_parts, info, (info.width, info.height))
    assert set(labels[labels != NO_LABEL].tolist()) == {0, 1}
    assert load_fitted(run).model.num_layers == 3  # the background, the body and the limb
    assert len(list(folder.flow_cache.glob("*.npz"))) == 1  # the parts' flow is the fit's: computed once
    before = tree_digest(run)
    code, lines = run_cli(*argv, FIT_RESUME_IF_STARTED_FLAG)  # a farm task run twice: the fit is done
    assert code == C.EXIT_OK and any(line.startswith("already fitted") for line in lines), lines
    assert tree_digest(run) == before


@pytest.mark.parametrize("flag", [[], [FIT_AUTO_PARTS_FLAG]], ids=["default", "auto-parts"])
def test_strokes_already_in_the_run_folder_are_used_as_they_are(rigid, tmp_path, flag):
    """The artist fixed (here: drew) the strokes in RUN_DIR/parts: they are the fit's scribbles, never searched
    again or overwritten, although this object moves as one piece."""
    frames, masks = rigid
    run = tmp_path / "run"
    strokes = _stroke_in(run, frames)
    before = tree_digest(strokes)
    code, lines = run_cli("fit", frames, "--mask", masks, "--out", run, *TINY_FIT, *flag)
    assert code == C.EXIT_OK, lines
    assert not any(line.startswith("auto parts:") for line in lines)  # not searched
    assert RunFolder(run).read_clip().scribbles == str(strokes.resolve())
    assert load_fitted(run).model.num_layers == 3
    assert tree_digest(strokes) == before


def _stroke_in(run: Path, frames: Path, shift: int = 0) -> Path:
    """RUN_DIR/parts holding the first frame's strokes of two parts (drawn by hand, as an artist's fix) on the
    object (its mask spans rows 41-69, columns 51-89 there), or ``shift`` pixels to the left."""
    strokes = RunFolder(run).auto_parts
    strokes.mkdir(parents=True)
    image = np.zeros((96, 160, 4), np.uint8)
    image[44:52, 55 - shift : 65 - shift] = (0, 0, 255, 255)  # red: Foreground1 (BGRA)
    image[58:66, 72 - shift : 82 - shift] = (0, 255, 0, 255)  # green: Foreground2
    cv2.imwrite(str(strokes / f"{Path(open_clip(frames).frame_files[0]).stem}.png"), image)
    return strokes


@pytest.mark.parametrize("flag", [[], [FIT_AUTO_PARTS_FLAG]], ids=["default", "auto-parts"])
def test_strokes_an_earlier_fit_left_for_another_object_or_other_frames_are_one_line(rigid, tmp_path, flag):
    """Strokes in RUN_DIR/parts that lie off this fit's mask (a ``--refit`` with another object's mask) or on none
    of its frames (``--frames`` elsewhere) are not fitted, nor answered as if the artist had drawn scribbles: one
    line naming the folder and the two ways out; the strokes stay as they are and no fit is written."""
    frames, masks = rigid
    numbers = open_clip(frames).frame_numbers
    for shift, frame_args, said in (
        (50, [], "do not lie on this fit's mask"),
        (0, ["--frames", f"{numbers[1]}-{numbers[-1]}"], "hold no stroke on this fit's frames"),
    ):
        run = tmp_path / f"run{shift}"
        strokes = _stroke_in(run, frames, shift)
        before = tree_digest(strokes)
        code, lines = run_cli("fit", frames, "--mask", masks, "--out", run, *TINY_FIT, *frame_args, *flag)
        assert code == C.EXIT_BAD_INPUT and len(lines) == 1, lines
        assert lines[0].startswith(f"error: {strokes}: the strokes an earlier fit left here {said}"), lines
        assert "delete the folder" in lines[0] and C.FIT_NO_AUTO_PARTS_FLAG in lines[0], lines
        assert "pure red" not in lines[0] and tree_digest(strokes) == before
        assert not RunFolder(run).clip.exists() and not RunFolder(run).checkpoint.exists()


def test_a_resume_after_the_strokes_changed_is_one_line(rigid, tmp_path):
    """The fit records the strokes it split its object by (their fingerprint in clip.json): ``--resume`` after the
    strokes in RUN_DIR/parts were edited continues on nothing else; one line names the folder and ``--refit``."""
    frames, masks = rigid
    run = tmp_path / "run"
    strokes = _stroke_in(run, frames)
    code, lines = run_cli("fit", frames, "--mask", masks, "--out", run, *TINY_FIT)
    assert code == C.EXIT_OK, lines
    assert RunFolder(run).read_clip().scribbles_fingerprint is not None
    (RunFolder(run).metrics).unlink()  # a fit stopped before it finished
    image_path = next(strokes.iterdir())
    image = cv2.imread(str(image_path), cv2.IMREAD_UNCHANGED)
    image[60:64, 60:64] = (0, 0, 255, 255)  # one more red stroke
    cv2.imwrite(str(image_path), image)
    before = tree_digest(run)
    code, lines = run_cli("fit", frames, "--mask", masks, "--out", run, "--resume", "--no-bar")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1, lines
    assert lines[0].startswith(f"error: {strokes.resolve()}: the strokes changed since this fit started"), lines
    assert "--refit" in lines[0] and tree_digest(run) == before


def test_no_auto_parts_fits_one_layer_and_leaves_strokes_in_the_run_folder_unused(rigid, tmp_path):
    """``--no-auto-parts``: never split, not even by strokes an earlier fit left in RUN_DIR/parts (kept as they
    are); nothing is searched."""
    frames, masks = rigid
    run = tmp_path / "run"
    before = tree_digest(_stroke_in(run, frames))
    code, lines = run_cli("fit", frames, "--mask", masks, "--out", run, *TINY_FIT, C.FIT_NO_AUTO_PARTS_FLAG)
    assert code == C.EXIT_OK, lines
    assert not any(line.startswith("auto parts:") for line in lines)
    assert RunFolder(run).read_clip().scribbles is None and load_fitted(run).model.num_layers == 2
    assert tree_digest(RunFolder(run).auto_parts) == before


@pytest.mark.parametrize("flag", [[], [FIT_AUTO_PARTS_FLAG]], ids=["default", "auto-parts"])
def test_an_object_moving_as_one_piece_is_fitted_as_one_layer(rigid, tmp_path, flag):
    """Asked for (``--auto-parts``), the finding is one stderr line; by default only a split is (every fit of one
    mask searches: a line on each would be noise), and the progress says it."""
    frames, masks = rigid
    run = tmp_path / "run"
    code, lines = run_cli("fit", frames, "--mask", masks, "--out", run, *TINY_FIT, *flag)
    assert code == C.EXIT_OK, lines
    said = [line for line in lines if line.startswith("auto parts: ")]
    assert len(said) == (1 if flag else 0) and all(line.endswith("fitted as one layer") for line in said), lines
    assert not RunFolder(run).auto_parts.exists()
    assert RunFolder(run).read_clip().scribbles is None
    assert load_fitted(run).model.num_layers == 2


@pytest.mark.parametrize(
    ("extra", "needles"),
    [
        (["--mask", "SECOND"], ("splits one object", "2 --mask folders")),
        ([C.SCRIBBLE_ARG, "SCRIBBLES"], (FIT_AUTO_PARTS_FLAG, C.SCRIBBLE_ARG, "pass one of them")),
        (["--preset", "paper"], ("paper model", "fast preset")),
    ],
    ids=["two-masks", "scribbles", "paper"],
)
def test_what_auto_parts_cannot_go_with_is_one_line_and_writes_nothing(rigid, tmp_path, extra, needles):
    frames, masks = rigid
    run = tmp_path / "run"
    extra = [str(masks) if e in ("SECOND", "SCRIBBLES") else e for e in extra]
    code, lines = run_cli("fit", frames, "--mask", masks, "--out", run, *TINY_FIT, *extra, FIT_AUTO_PARTS_FLAG)
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and lines[0].startswith("error: "), lines
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    assert not run.exists()


def test_auto_parts_with_auto_masks_says_to_check_the_masks_first(rigid, tmp_path):
    frames, _ = rigid
    run = tmp_path / "run"
    code, lines = run_cli("fit", frames, FIT_AUTO_MASKS_FLAG, FIT_AUTO_PARTS_FLAG, "--out", run, *TINY_FIT)
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1, lines
    assert FIT_AUTO_MASKS_FLAG in lines[0] and f"`{C.VERB_MASKS}`" in lines[0]
    assert not run.exists()


def test_a_mask_folder_with_no_mask_pixel_is_one_line_and_leaves_no_run_folder(rigid, tmp_path):
    frames, masks = rigid
    empty = tmp_path / "empty_masks"
    empty.mkdir()
    for p in sorted(Path(masks).iterdir()):
        cv2.imwrite(str(empty / p.name), np.zeros((96, 160), np.uint8))
    run = tmp_path / "run"
    code, lines = run_cli("fit", frames, "--mask", empty, "--out", run, *TINY_FIT, FIT_AUTO_PARTS_FLAG)
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and "holds no mask pixel" in lines[0], lines
    assert not run.exists()


@pytest.mark.parametrize("holds_strokes", [False, True], ids=["empty", "strokes"])
def test_a_link_planted_at_the_run_folders_parts_is_refused_and_nothing_is_written(rigid, tmp_path, holds_strokes):
    """``RUN/parts`` is the engine's own folder: a symbolic link there is one line naming it, whether the folder it
    points to is empty (the strokes would be written through it) or holds strokes (they would be the fit's); that
    folder and the run folder are left exactly as they were."""
    frames, masks = rigid
    run, elsewhere = tmp_path / "run", tmp_path / "elsewhere"
    run.mkdir()
    elsewhere.mkdir()
    if holds_strokes:
        name = f"{Path(open_clip(frames).frame_files[0]).stem}.png"
        image = np.zeros((96, 160, 4), np.uint8)
        image[30:40, 45:55] = (0, 0, 255, 255)
        cv2.imwrite(str(elsewhere / name), image)
    (run / AUTO_PARTS_DIR).symlink_to(elsewhere, target_is_directory=True)
    before, run_before = tree_digest(elsewhere), sorted(p.name for p in run.iterdir())
    code, lines = run_cli("fit", frames, "--mask", masks, "--out", run, *TINY_FIT, FIT_AUTO_PARTS_FLAG)
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and lines[0].startswith("error: "), lines
    assert f"{AUTO_PARTS_DIR}/" in lines[0] and "symbolic link" in lines[0] and "delete the link" in lines[0]
    assert tree_digest(elsewhere) == before
    assert sorted(p.name for p in run.iterdir()) == run_before


@pytest.mark.parametrize(
    ("case", "needles"),
    [
        ("two-masks", ("splits one object", "2 --mask folders")),
        ("single-frame", ("single frame", "at least two frames")),
        ("empty-mask", ("holds no mask pixel", "draw the object's mask")),
    ],
)
def test_the_default_fits_what_it_cannot_split_as_given_where_auto_parts_is_one_line(rigid, tmp_path, case, needles):
    """Where a split cannot apply the default fits the clip as it would without the search (two masks: one layer
    each; a single frame and an empty mask, which the search cannot split, as one layer), while ``--auto-parts``,
    which insists on it, is refused in one line and writes nothing."""
    frames, masks = rigid
    extra: list[str] = []
    if case == "two-masks":  # a second object's masks (the same pixels in a folder of their own)
        extra = ["--mask", str(shutil.copytree(masks, tmp_path / "second"))]
    elif case == "single-frame":
        first = open_clip(frames).frame_files[0]
        extra = ["--frames", f"{Path(first).stem}-{Path(first).stem}"]
    else:
        masks = tmp_path / "empty_masks"
        masks.mkdir()
        for name in sorted(p.name for p in rigid[1].iterdir()):
            cv2.imwrite(str(masks / name), np.zeros((96, 160), np.uint8))
    run = tmp_path / "run"
    code, lines = run_cli("fit", frames, "--mask", masks, "--out", run, *TINY_FIT, *extra)
    assert code == C.EXIT_OK, lines
    assert not RunFolder(run).auto_parts.exists() and RunFolder(run).read_clip().scribbles is None
    assert not [line for line in lines if line.startswith("auto parts:")], lines
    refused = tmp_path / "refused"
    code, lines = run_cli("fit", frames, "--mask", masks, "--out", refused, *TINY_FIT, *extra, FIT_AUTO_PARTS_FLAG)
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and lines[0].startswith("error: "), lines
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    assert not refused.exists()


def test_which_fits_the_default_splits():
    """The default splits one --mask object with a fast model and nothing else splitting it; ``--auto-parts``
    insists (what it cannot go with is one line: ``test_what_auto_parts_cannot_go_with...``), ``--no-auto-parts``
    never."""
    fast, paper = preset_config("draft"), preset_config("paper")
    one, two = ["m"], ["m", "n"]
    assert parts_wanted(None, fast, one, None, False)
    assert not parts_wanted(None, paper, one, None, False)
    assert not parts_wanted(None, fast, two, None, False)
    assert not parts_wanted(None, fast, one, "strokes", False)
    assert not parts_wanted(None, fast, [], None, True)
    assert parts_wanted(True, fast, one, None, False) and not parts_wanted(False, fast, one, None, False)
    with pytest.raises(InputError, match="paper model"):
        parts_wanted(True, paper, one, None, False)
