"""Loose masks snapped to the clip's edges: a dilated or eroded mask comes back to the object, a precise one stays."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from engine.data.mask_snap import (
    FAR_LINE,
    OUTLINE_EDGE,
    SNAP_CONTRAST,
    best_offset,
    edge_profile,
    signed_distance,
    snap_masks,
)
from engine.data.synthetic import SceneSpec, make_scene
from engine.fit.fit_inputs import FitInputs

REACH = 12


def _disc(px: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * px + 1, 2 * px + 1))


def _dilate(masks: np.ndarray, px: int) -> np.ndarray:
    return np.stack([cv2.dilate(m.astype(np.uint8), _disc(px)) > 0 for m in masks])


def _erode(masks: np.ndarray, px: int) -> np.ndarray:
    return np.stack([cv2.erode(m.astype(np.uint8), _disc(px)) > 0 for m in masks])


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


@pytest.fixture(scope="module")
def scene():
    """A textured sprite over a textured, panning plate: the sprite's outline is an edge in every frame."""
    return make_scene(SceneSpec(width=160, height=112, frames=5, fg_size=(60, 44), fg_start=(40.0, 30.0)))


@pytest.mark.parametrize("dilate", [4, 8])
def test_a_dilated_mask_shrinks_back_to_the_object(scene, dilate):
    loose = _dilate(scene.masks, dilate)
    out, snaps = snap_masks(scene.frames, loose[None], REACH)
    assert _iou(loose, scene.masks) < 0.85
    assert snaps[0].offset_px in (-dilate - 1, -dilate, -dilate + 1)
    assert _iou(out[0], scene.masks) > 0.95
    assert snaps[0].kept_frames == []


def test_an_eroded_mask_grows_back(scene):
    tight = _erode(scene.masks, 5)
    out, snaps = snap_masks(scene.frames, tight[None], REACH)
    assert _iou(tight, scene.masks) < 0.85
    assert 4 <= snaps[0].offset_px <= 6
    assert _iou(out[0], scene.masks) > 0.93


def test_a_precise_mask_is_left_as_drawn(scene):
    out, snaps = snap_masks(scene.frames, scene.masks[None], REACH)
    assert snaps[0].offset_px == 0
    assert np.array_equal(out[0], scene.masks)
    # its own outline is where the edges are strongest
    strength = dict(zip(snaps[0].offsets, snaps[0].strength, strict=True))
    assert max(strength, key=strength.get) in (-1, 1)


def test_no_edges_no_mask_or_off_changes_nothing(scene):
    flat = np.full_like(scene.frames, 0.5)
    loose = _dilate(scene.masks, 6)[None]
    out, snaps = snap_masks(flat, loose, REACH)  # nothing to snap to
    assert snaps[0].offset_px == 0 and np.array_equal(out, loose)
    empty = np.zeros_like(loose)
    out, snaps = snap_masks(scene.frames, empty, REACH)
    assert not out.any() and snaps[0].offset_px == 0
    out, snaps = snap_masks(scene.frames, loose, 1)  # off
    assert np.array_equal(out, loose) and snaps[0].offsets == []
    out, snaps = snap_masks(scene.frames, np.zeros((0, *loose.shape[1:]), bool), REACH)  # no layer
    assert out.shape[0] == 0 and snaps == []


def test_frames_without_a_mask_stay_empty_and_a_tiny_mask_is_kept(scene):
    """A dropped frame (empty mask) stays empty; a frame whose mask a shrink would empty keeps the mask as drawn."""
    loose = _dilate(scene.masks, 8)
    loose[2] = False
    loose[3] = False
    loose[3, 50:53, 60:63] = True  # a 3x3 speck: 8 px in would leave nothing
    out, snaps = snap_masks(scene.frames, loose[None], REACH)
    assert snaps[0].offset_px < 0
    assert not out[0, 2].any()
    assert snaps[0].kept_frames == [3] and np.array_equal(out[0, 3], loose[3])


def test_each_layer_is_snapped_on_its_own(scene):
    masks = np.stack([_dilate(scene.masks, 6), scene.masks])
    out, snaps = snap_masks(scene.frames, masks, REACH)
    assert snaps[0].offset_px < 0 and snaps[1].offset_px == 0
    assert np.array_equal(out[1], scene.masks)


def test_signed_distance_and_contrast_guard():
    m = np.zeros((9, 9), bool)
    m[3:6, 3:6] = True
    sd = signed_distance(m)
    assert sd[4, 4] < 0 and sd[0, 0] > 0 and not (sd == 0).any()
    assert sd[3, 4] == -1 and sd[2, 4] == 1
    offsets = [d for d in range(-6, 7) if d]

    def profile(**at: float) -> np.ndarray:
        """1.0 on every line but those named (m4 = -4, p3 = +3)."""
        vals = {int(k[1:]) * (-1 if k[0] == "m" else 1): v for k, v in at.items()}
        return np.array([vals.get(d, 1.0) for d in offsets])

    # a dilated mask: its outline on background like the lines beyond it; the object's edge peaks at -4
    assert best_offset(offsets, profile(m3=2.0, m4=3.0, m5=1.2)) == -4
    # a peak only 1.2x the outline's own edges: not clear enough to move the mask
    assert best_offset(offsets, profile(m4=1.2)) == 0
    # a textured interior stronger than the object's edge: the first strong line met going in wins, not the maximum
    assert best_offset(offsets, profile(m2=2.0, m3=3.0, m4=2.0, m5=9.0, m6=9.0)) == -3
    # edges both ways: the nearer
    assert best_offset(offsets, profile(m3=3.0, p2=2.0)) == 2
    # a precise mask: its outline is an edge against both sides, so even strong interior lines do not move it
    assert best_offset(offsets, profile(m1=3.0, p1=3.0, m2=6.0, m3=9.0)) == 0
    # lines no pixel lies on (deeper than the object) are skipped; no outline lines, no offset
    nan_deep = profile(m3=2.0, m4=3.0)
    nan_deep[:2] = np.nan
    assert best_offset(offsets, nan_deep) == -4
    assert best_offset([-2, 2], np.array([5.0, 1.0])) == 0
    assert best_offset([], np.array([])) == 0
    assert 0 < FAR_LINE < 6 and OUTLINE_EDGE > 1 and SNAP_CONTRAST > 1


def test_a_small_textured_object_is_not_eaten_by_its_own_texture(tmp_path):
    """A 24x18 sprite whose stripes and spots are stronger edges than its outline, masks grown by 2 px (within the
    outline's own blur, so they read as drawn on it): the masks stay or move at most 3 px in, never to the strongest
    texture line in the middle of the sprite."""
    tiny = make_scene(SceneSpec(width=64, height=48, frames=6, fg_size=(24, 18), fg_start=(12.0, 10.0)))
    loose = _dilate(tiny.masks, 2)
    out, snaps = snap_masks(tiny.frames, loose[None], 16)
    strength = dict(zip(snaps[0].offsets, snaps[0].strength, strict=True))
    assert max(strength, key=strength.get) < -5  # the profile's maximum is deep inside
    assert snaps[0].offset_px in (-3, -2, -1, 0)
    assert _iou(out[0], tiny.masks) >= _iou(loose, tiny.masks)


def test_hdr_and_nan_frames_do_not_move_the_outline(scene):
    """A blown-out highlight or NaN pixels in the plate: edge strength is read on the display range, finite."""
    frames = scene.frames.copy()
    frames[:, :10, :10] = 1e4
    frames[:, -5:, -5:] = np.nan
    loose = _dilate(scene.masks, 6)
    _, profile = edge_profile(frames, loose, REACH)
    assert np.isfinite(profile).all()
    out, _ = snap_masks(frames, loose[None], REACH)
    assert _iou(out[0], scene.masks) > 0.95


def test_the_fit_prepares_snapped_masks_and_says_so(scene, tmp_path, capsys):
    """Every preset snaps (``mask_snap_px``); ``--set mask_snap_px=0`` fits the masks as drawn."""
    from engine.config import apply_overrides, preset_config
    from engine.data.synthetic import write_pngs
    from engine.fit.prepare import prepare_clip

    loose = _dilate(scene.masks, 6)
    frames_dir, masks_dir = tmp_path / "frames", tmp_path / "masks"
    frames_dir.mkdir()
    masks_dir.mkdir()
    write_pngs(scene.frames, frames_dir, {masks_dir: loose})
    cfg = preset_config("draft")
    assert all(preset_config(p).mask_snap_px >= REACH for p in ("draft", "balanced", "final", "paper"))
    snapped = prepare_clip(FitInputs(frames_dir, [masks_dir]), cfg, tmp_path / "run")
    assert snapped.mask_snaps[0].offset_px < 0
    assert _iou(snapped.masks[0], scene.masks) > 0.95
    assert "outline moved" in capsys.readouterr().err
    drawn = prepare_clip(
        FitInputs(frames_dir, [masks_dir]), apply_overrides(cfg, {"mask_snap_px": "0"}), tmp_path / "run2"
    )
    assert np.array_equal(drawn.masks[0], loose) and drawn.mask_snaps == ()


def test_a_mask_covering_the_whole_frame_has_no_outline_to_move(scene):
    """A full-frame mask (every pixel foreground) in some frames or all: those frames have no outline; they add
    nothing to the profile and stay full; the other frames are snapped as usual."""
    full = np.ones_like(scene.masks)
    out, snaps = snap_masks(scene.frames, full[None], REACH)
    assert snaps[0].offset_px == 0 and out.all()
    assert np.isnan(snaps[0].strength).all()
    sd = signed_distance(full[0])
    assert np.isneginf(sd).all() and np.isposinf(signed_distance(~full[0])).all()
    loose = _dilate(scene.masks, 6)
    loose[1] = True
    out, snaps = snap_masks(scene.frames, loose[None], REACH)
    assert snaps[0].offset_px < 0 and out[0, 1].all()
    assert _iou(out[0, [0, 2, 3, 4]], scene.masks[[0, 2, 3, 4]]) > 0.95
