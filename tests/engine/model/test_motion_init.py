"""The foreground's starting motion when some frames have no mask: the object's atlas must not jump by the camera's
motion at a frame the roto or the detector left out."""

from __future__ import annotations

import numpy as np
import pytest

from engine.data.flow import FlowField
from engine.model import motion_init
from engine.model.motion_init import estimate_layer_motion

W, H, T = 96, 64, 8
OBJECT_STEP = 2.0  # the object moves right by 2 px a frame
CAMERA_STEP = -3.0  # the background moves left by 3 px a frame (the camera pans right)
SIDE = 16


def _object_box(t: int, start: int = 20, step: float = OBJECT_STEP) -> tuple[int, int, int, int]:
    x0 = start + round(step * t)
    return x0, 24, x0 + SIDE, 24 + SIDE


def _clip(dropped: tuple[int, ...], start: int = 20, step: float = OBJECT_STEP) -> tuple[FlowField, np.ndarray]:
    """Flow with the object (left edge at ``start``, ``step`` px a frame to the right) and the background moving
    apart, and the object's masks with ``dropped`` frames empty. Once the object has left the frame, its masks
    and its flow are cut off at the edge."""
    fwd = np.zeros((T - 1, H, W, 2), np.float32)
    fwd[..., 0] = CAMERA_STEP
    masks = np.zeros((T, H, W), bool)
    for t in range(T):
        x0, y0, x1, y1 = _object_box(t, start, step)
        if t < T - 1:
            fwd[t, y0:y1, x0:x1, 0] = step
        if t not in dropped:
            masks[t, y0:y1, x0:x1] = True
    ok = np.ones((T - 1, H, W), bool)
    return FlowField(fwd, -fwd, ok, ok.copy(), "test", 1.0), masks


def _ref_centres(dropped: tuple[int, ...]) -> np.ndarray:
    """The object's centre in each frame, mapped to the reference frame by the layer's starting motion."""
    flow, masks = _clip(dropped)
    motion = estimate_layer_motion(flow, masks, (W, H), True, 0.06)
    centres = []
    for t in range(T):
        x0, y0, x1, y1 = _object_box(t)
        centres.append(motion.to_ref[t] @ np.array([(x0 + x1) / 2, (y0 + y1) / 2, 1.0]))
    return np.array(centres)


@pytest.mark.parametrize("dropped", [(), (3,), (3, 4), (0, 1), (6, 7)], ids=str)
def test_the_object_stays_put_in_its_atlas_through_frames_without_a_mask(dropped: tuple[int, ...]) -> None:
    """Every frame's object lands on frame 0's object: a missing mask's pair is fitted inside the last region
    carried by the object's own motion (or the first region, before any), never on the whole frame, where the
    background's flow wins (it moved the object 5 px a frame the wrong way)."""
    centres = _ref_centres(dropped)
    spread = np.abs(centres - centres[0]).max()
    assert spread < 0.25, (dropped, centres)


def test_without_any_mask_the_layer_follows_the_whole_frame() -> None:
    """No region at all (the background of a clip without masks): each pair is fitted on the whole frame, so the
    chain follows the camera, 3 px a frame."""
    flow, _ = _clip(())
    motion = estimate_layer_motion(flow, None, (W, H), True, 0.0)
    shift = motion.to_ref[:, 0, 2]
    np.testing.assert_allclose(np.diff(shift), -CAMERA_STEP, atol=1e-3)


def test_an_object_that_leaves_the_frame_falls_back_to_the_whole_frame() -> None:
    """A fast object with masks in its first two frames only: its region is carried out of the frame (12 px a frame
    from x = 60 in a 96 px frame: half out at frame 2, gone at frame 3). While any of it is in the frame each pair
    follows the object; once the carried region has no pixel left, the pairs are the whole frame's (the camera's),
    as for a layer without a mask, and nothing fails."""
    step = 12.0
    flow, masks = _clip(tuple(range(2, T)), start=60, step=step)
    assert masks[:2].any(axis=(1, 2)).all() and not masks[2:].any()

    motion = estimate_layer_motion(flow, masks, (W, H), True, 0.06)

    assert np.isfinite(motion.to_ref).all() and motion.half_extent > 0
    shift = np.diff(motion.to_ref[:, 0, 2])  # -(each pair's translation)
    np.testing.assert_allclose(shift[:3], -step, atol=1e-3)  # pairs 0-2: the object, the last one half out
    np.testing.assert_allclose(shift[3:], -CAMERA_STEP, atol=1e-3)  # pairs 3..: its region has left, the camera
    far = np.eye(2, 3)
    far[0, 2] = 10 * W
    assert motion_init._carried(masks[1], far, (W, H)) is None
