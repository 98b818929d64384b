"""``masks PLATE --out FOLDER`` run again with the same arguments (a retried farm task): the folder holds these very
masks, so it is left as it is and the command succeeds; a folder holding other masks under those names is still
refused in one line and left as it is."""

from __future__ import annotations

import contextlib
import io

import numpy as np

from engine import cli
from engine import contract as C
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from tests.folders import tree_digest
from tests.media_files import write_image

SMALL = SceneSpec(width=96, height=64, frames=6, fg_size=(28, 20), fg_start=(20.0, 20.0))


def _masks(*args: object) -> tuple[int, list[str], list[str]]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main([C.VERB_MASKS, *map(str, args)])
    return code, out.getvalue().splitlines(), [line for line in err.getvalue().splitlines() if line.strip()]


def test_masks_run_again_succeed_and_change_nothing(tmp_path):
    frames, _ = write_scene(make_scene(SMALL), tmp_path / "clip")
    out = tmp_path / "masks"
    code, first, err = _masks(frames, "--out", out)
    assert (code, err) == (0, [])
    written = tree_digest(out)
    assert len(written) == SMALL.frames
    code, again, err = _masks(frames, "--out", out)
    assert (code, err) == (0, [])
    assert again[-1] == first[-1] == str(out)
    assert any("left as they are" in line for line in again)
    assert tree_digest(out) == written

    # a mask fixed by hand meanwhile: never overwritten, one line
    name = sorted(written)[2]
    write_image(out / name, np.full((SMALL.height, SMALL.width), 255, np.uint8))
    fixed = tree_digest(out)
    code, _, err = _masks(frames, "--out", out)
    assert code == C.EXIT_BAD_INPUT and len(err) == 1 and "already holds" in err[0], err
    assert tree_digest(out) == fixed
