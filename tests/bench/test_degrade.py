"""The bench's mask degradations on tiny synthetic masks: dilation grows and erosion shrinks by the expected
areas, dropped frames are the seeded count (never the first) and written empty, polygon simplification stays
close, the degraded masks' IoU against the precise ones is in the expected range, and the same seed gives the
same bytes. On the real clips (skipped when absent): the standard recipe's masks, without any fit."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from bench.degrade import (
    RECIPES,
    Degradation,
    degrade_mask,
    dropped_frames,
    read_gt,
    recipe,
    write_degraded,
)
from engine.data.auto_masks import mask_iou
from engine.errors import InputError
from tests.paths import CLIPS, NO_CLIPS

H, W = 120, 160


def square(x0: int, y0: int, side: int) -> np.ndarray:
    m = np.zeros((H, W), bool)
    m[y0 : y0 + side, x0 : x0 + side] = True
    return m


def disc(cx: int, cy: int, r: int) -> np.ndarray:
    yy, xx = np.mgrid[:H, :W]
    return (xx - cx) ** 2 + (yy - cy) ** 2 <= r * r


@pytest.fixture
def gt_dir(tmp_path) -> Path:
    """20 frames of a disc moving right, as 8-bit 0/255 PNGs named like DAVIS's."""
    d = tmp_path / "gt"
    d.mkdir()
    for t in range(20):
        cv2.imwrite(str(d / f"{t:05d}.png"), disc(40 + 3 * t, 60, 25).astype(np.uint8) * 255)
    return d


def test_dilation_grows_and_erosion_shrinks_by_the_expected_area():
    m = square(50, 40, 40)
    grown = degrade_mask(m, Degradation(dilate_px=10))
    # a square grown by a 10-px disc: its area plus the rim (4 sides of 40 x 10) plus the rounded corners (pi 10^2)
    assert grown.sum() == pytest.approx(40 * 40 + 4 * 40 * 10 + np.pi * 100, rel=0.03)
    assert (grown & m).sum() == m.sum()
    shrunk = degrade_mask(m, Degradation(erode_px=5))
    assert shrunk.sum() == 30 * 30 and not (shrunk & ~m).any()
    assert not degrade_mask(square(10, 10, 8), Degradation(erode_px=5)).any()  # a thin object erodes away


def test_polygon_simplification_stays_within_its_tolerance():
    m = disc(80, 60, 40)
    poly = degrade_mask(m, Degradation(simplify_px=8.0))
    assert 0.85 < mask_iou(poly[None], m[None])[0] < 1.0
    band = cv2.dilate(m.astype(np.uint8), np.ones((19, 19), np.uint8)).astype(bool)
    assert not (poly & ~band).any()
    assert degrade_mask(m, Degradation(simplify_px=0.0)).sum() == m.sum()


def test_dropped_frames_are_seeded_and_never_the_first():
    a = dropped_frames(50, 0.1, seed=3)
    assert len(a) == 5 and a == sorted(a) and 0 not in a and len(set(a)) == 5
    assert a == dropped_frames(50, 0.1, seed=3)
    assert any(dropped_frames(50, 0.1, seed=s) != a for s in range(4, 10))
    assert dropped_frames(50, 0.0, 0) == [] and dropped_frames(1, 0.5, 0) == []
    assert dropped_frames(3, 0.9, 0) == [1, 2]  # at most every frame but the first


def test_write_degraded_writes_every_frame_with_dropped_ones_empty(gt_dir, tmp_path):
    out = write_degraded(gt_dir, tmp_path / "deg", "dilated10_dropped10", seed=0)
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(p.name for p in gt_dir.iterdir())
    gt = np.stack([read_gt(gt_dir / n) for n in names])
    deg = np.stack([read_gt(out / n) for n in names])
    image = cv2.imread(str(out / names[0]), cv2.IMREAD_UNCHANGED)
    assert image.dtype == np.uint8 and image.ndim == 2 and set(np.unique(image)) == {0, 255}
    empty = [t for t in range(len(names)) if not deg[t].any()]
    assert empty == dropped_frames(20, 0.1, 0) and len(empty) == 2
    kept = [t for t in range(20) if t not in empty]
    assert (deg[kept] >= gt[kept]).all()  # dilation only adds
    iou = mask_iou(deg[kept], gt[kept])
    # a disc of radius 25 grown to 35: IoU (25/35)^2 = 0.51
    assert np.allclose(iou, (25 / 35) ** 2, atol=0.03)


def test_write_degraded_is_deterministic(gt_dir, tmp_path):
    for name in RECIPES:
        a = write_degraded(gt_dir, tmp_path / f"a_{name}", name, seed=5)
        b = write_degraded(gt_dir, tmp_path / f"b_{name}", recipe(name), seed=5)
        for f in sorted(a.iterdir()):
            assert f.read_bytes() == (b / f.name).read_bytes(), (name, f.name)
    c = write_degraded(gt_dir, tmp_path / "c", "dropped10", seed=6)
    a = tmp_path / "a_dropped10"
    assert any(f.read_bytes() != (c / f.name).read_bytes() for f in sorted(a.iterdir()))


def test_bad_recipes_are_refused(tmp_path):
    with pytest.raises(InputError, match="dilated10"):
        recipe("dilated")
    with pytest.raises(ValueError):
        Degradation(drop_fraction=1.0)
    with pytest.raises(ValueError):
        Degradation(dilate_px=-1)
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError):
        write_degraded(tmp_path / "empty", tmp_path / "out", "exact")


@pytest.mark.skipif(not CLIPS.is_dir(), reason=NO_CLIPS)
def test_the_standard_recipe_on_the_real_clips(tmp_path):
    """``dilated10_dropped10`` on every real clip: the same file names, a tenth of the frames empty, the kept
    ones holding the whole object; on these objects (2% to 14% of the frame) the grown masks' IoU against the
    precise ones is about 0.4 (the smallest) to 0.85 (the largest)."""
    from bench.all_clips import find_clips
    from bench.degrade import mask_files

    for clip in find_clips(CLIPS):
        files = mask_files(clip / "masks")
        out = write_degraded(clip / "masks", tmp_path / clip.name, "dilated10_dropped10")
        assert sorted(p.name for p in out.iterdir()) == [f.stem + ".png" for f in files]
        gt = np.stack([read_gt(f) for f in files])
        deg = np.stack([read_gt(out / (f.stem + ".png")) for f in files])
        kept = deg.reshape(len(files), -1).any(1)
        assert (~kept).sum() == round(0.1 * len(files)) and kept[0], clip.name
        assert (deg[kept] >= gt[kept]).all(), clip.name
        assert 0.3 < mask_iou(deg[kept], gt[kept]).mean() < 0.9, clip.name
