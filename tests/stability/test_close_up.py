"""A close-up: the object covers most of the frame, or all of it. The default fit (the parts search on) follows
every point of the mask at once, past OpenCV's 32767 samples per row; it must complete, and so must the export and
the render of what it fitted."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from engine import contract as C
from engine.export.manifest import Manifest
from engine.fit.fitted_run import load_fitted
from engine.io.images import read_image
from engine.terms.run_folder import AUTO_PARTS_DIR
from tests.engine_cli import run_cli
from tests.stability.bad_inputs import TINY_FIT
from tests.stability.fitcheck import write_masks, write_sequence

T, H, W = 6, 480, 854


def _close_up(folder: Path, cover: float) -> tuple[Path, Path]:
    """A textured rectangle covering ``cover`` of the frame (1.0: the mask is the whole frame) moving 2 px a frame
    over a plate panning 1 px a frame."""
    rng = np.random.default_rng(0)
    plate = cv2.GaussianBlur(rng.random((H, W + T, 3)).astype(np.float32), (0, 0), 2.0)
    side = np.sqrt(cover)
    bw, bh = round(W * side), round(H * side)
    texture = cv2.GaussianBlur(rng.random((bh, bw, 3)).astype(np.float32), (0, 0), 3.0)
    frames = np.stack([plate[:, t : t + W].copy() for t in range(T)])
    masks = np.zeros((T, H, W), bool)
    for t in range(T):
        x0, y0 = min(W - bw, max(0, (W - bw) // 2 - T + 2 * t)), (H - bh) // 2
        frames[t, y0 : y0 + bh, x0 : x0 + bw] = texture
        masks[t, y0 : y0 + bh, x0 : x0 + bw] = True
    if cover >= 1.0:
        masks[:] = True
    return write_sequence(folder / "frames", frames), write_masks(folder / "masks", masks)


@pytest.mark.slow  # flow at 768x432 and an export at 854x480: about 15 s a fit, 40 s with the export and render
@pytest.mark.parametrize("cover", [0.44, 0.95, 1.0])
def test_the_default_fit_of_a_close_up_completes(tmp_path, cover):
    frames, masks = _close_up(tmp_path / "clip", cover)
    run = tmp_path / "run"
    code, lines = run_cli("fit", frames, "--mask", masks, "--out", run, *TINY_FIT)
    assert code == C.EXIT_OK, lines
    assert not (run / AUTO_PARTS_DIR).exists()  # searched, and one rigid piece: nothing to split
    assert load_fitted(run).model.num_layers == 2
    if cover != 0.95:
        return
    code, lines = run_cli("export", run, "--no-bar")
    assert code == C.EXIT_OK, lines
    manifest = Manifest(next((run / "exports").glob("v*/manifest.json")))
    assert len(manifest.frames) == T and [tuple(p.alpha.shape) for p in manifest.read_passes(0)] == [(H, W)] * 2
    out = tmp_path / "render"
    code, lines = run_cli("render", manifest.path, "--out", out, "--format", "plate", "--no-bar")
    assert code == C.EXIT_OK, lines
    # every edit layer empty: the render is the plate, to the code value
    rendered = sorted(out.glob("*.png"))
    assert len(rendered) == T
    for t, path in enumerate(rendered):
        got, _ = read_image(path)
        want, _ = read_image(frames / f"{t:05d}.png")
        assert np.abs(got - want).max() <= 1.0 / 255.0 + 1e-6
