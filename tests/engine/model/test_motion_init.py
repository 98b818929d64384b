"""The foreground's starting motion when some frames have no mask: the object's atlas must not jump by the camera's
motion at a frame the roto or the detector left out."""

from __future__ import annotations

import numpy as np
import pytest

from engine.data.flow import FlowField
from engine.model import motion_init
from engine.model.motion_init import LayerMotion, estimate_layer_motion

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


# --- an occluder inside the mask ---------------------------------------------------------------------------------

PAD = 2  # the mask is the object's box grown by this much: a little background inside it, as in any real mask
TRUNK_X = 44  # a trunk, 10 px wide in frame 3 and moving with the background, passes in front of the object


def _occluded_clip(cover: int, dropped: tuple[int, ...] = ()) -> tuple[FlowField, np.ndarray]:
    """The moving object of ``_clip`` in a slightly loose mask, passing behind a trunk that moves with the camera;
    in frames 3 and 4 the trunk covers ``cover`` of the object's 16 columns (16: all of it), so inside the mask the
    trunk's flow and the background's outvote the object's there."""
    fwd = np.zeros((T - 1, H, W, 2), np.float32)
    fwd[..., 0] = CAMERA_STEP
    masks = np.zeros((T, H, W), bool)
    for t in range(T):
        x0, y0, x1, y1 = _object_box(t)
        if t < T - 1:
            fwd[t, y0:y1, x0:x1, 0] = OBJECT_STEP
            if t in (3, 4):
                fwd[t, :, x0 : x0 + cover, 0] = CAMERA_STEP
        if t not in dropped:
            masks[t, y0 - PAD : y1 + PAD, x0 - PAD : x1 + PAD] = True
    ok = np.ones((T - 1, H, W), bool)
    return FlowField(fwd, -fwd, ok, ok.copy(), "test", 1.0), masks


def _centre_spread(flow: FlowField, masks: np.ndarray, background: bool) -> float:
    """How far the object's centre in every frame lands from frame 0's in the layer's reference frame (pixels)."""
    camera = estimate_layer_motion(flow, None, (W, H), True, 0.0) if background else None
    motion = estimate_layer_motion(flow, masks, (W, H), True, 0.06, background=camera)
    centres = []
    for t in range(T):
        x0, y0, x1, y1 = _object_box(t)
        centres.append(motion.to_ref[t] @ np.array([(x0 + x1) / 2, (y0 + y1) / 2, 1.0]))
    return float(np.abs(np.array(centres) - centres[0]).max())


@pytest.mark.parametrize("dropped", [(), (4,)], ids=str)
@pytest.mark.parametrize("cover", [10, 16], ids=["partly", "wholly"])
def test_the_object_stays_put_in_its_atlas_behind_an_occluder(cover: int, dropped: tuple[int, ...]) -> None:
    """Behind the trunk the larger consensus inside the mask moves with the background, unlike the layer's other
    pairs: the object's own consensus is taken instead (partly hidden), or its motion relative to the camera from
    the pair before (wholly hidden), also when the frame behind the trunk has no mask."""
    flow, masks = _occluded_clip(cover, dropped)
    assert _centre_spread(flow, masks, background=True) < 0.25


def test_without_the_background_the_occluder_displaces_the_object() -> None:
    """The case above is a real one: the larger consensus alone moves the object 5 px in each pair behind the trunk,
    10 px in its atlas from frame 5 on."""
    flow, masks = _occluded_clip(10)
    assert _centre_spread(flow, masks, background=False) > 9.0


def _stopping_clip() -> tuple[FlowField, np.ndarray]:
    """A locked-off shot: the object moves 4 px a frame to the right, then stops at frame 4 (its flow, like the
    background's, is zero from there)."""
    fwd = np.zeros((T - 1, H, W, 2), np.float32)
    masks = np.zeros((T, H, W), bool)
    x = [20 + 4 * min(t, 4) for t in range(T)]
    for t in range(T):
        if t < T - 1:
            fwd[t, 24 : 24 + SIDE, x[t] : x[t] + SIDE, 0] = x[t + 1] - x[t]
        masks[t, 24 - PAD : 24 + SIDE + PAD, x[t] - PAD : x[t] + SIDE + PAD] = True
    ok = np.ones((T - 1, H, W), bool)
    return FlowField(fwd, -fwd, ok, ok.copy(), "test", 1.0), masks


def test_an_object_that_stops_is_not_driven_on(monkeypatch: pytest.MonkeyPatch) -> None:
    """After it stops, the object's pairs move with the background, unlike its earlier ones, and there is no other
    consensus: carrying on at its earlier speed would be the occluder's answer. The masks' boxes, which stop too,
    keep the pairs still; without them (the check switched off) the object would drift 12 px in its atlas."""
    flow, masks = _stopping_clip()
    still = LayerMotion(np.tile(np.eye(2, 3), (T, 1, 1)), np.zeros(2), 1.0)
    motion = estimate_layer_motion(flow, masks, (W, H), True, 0.06, background=still)
    np.testing.assert_allclose(motion.to_ref[:, 0, 2], [-4.0 * min(t, 4) for t in range(T)], atol=1e-3)

    monkeypatch.setattr(motion_init, "_box_centre", lambda mask: None)
    drifted = estimate_layer_motion(flow, masks, (W, H), True, 0.06, background=still)
    assert drifted.to_ref[-1, 0, 2] == pytest.approx(-28.0, abs=1e-3)


def test_no_reliable_flow_with_a_background_gives_the_identity() -> None:
    """Every flow vector unreliable (a blown-out plate): no consensus anywhere, nothing to compare with the
    background, and the layer starts still rather than failing."""
    flow, masks = _occluded_clip(10)
    none_ok = np.zeros_like(flow.forward_ok)
    blind = FlowField(flow.forward, flow.backward, none_ok, none_ok.copy(), "test", 1.0)
    camera = estimate_layer_motion(flow, None, (W, H), True, 0.0)
    motion = estimate_layer_motion(blind, masks, (W, H), True, 0.06, background=camera)
    np.testing.assert_allclose(motion.to_ref, np.tile(np.eye(2, 3), (T, 1, 1)))


# --- a deforming object: the body's motion, not its largest part's -----------------------------------------------


def _deforming_pair() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One frame pair: a 20 px object whose rows move 2 px (three rows in five) or 5.5 px (the other two: limbs that
    swing; no motion is within 1.5 px of both), inside a mask 2 px too wide whose background ring moves 6 px the
    other way."""
    flow = np.zeros((H, W, 2), np.float32)
    region = np.zeros((H, W), bool)
    region[20:44, 30:54] = True
    flow[20:44, 30:54, 0] = -6.0
    for y in range(22, 42):
        flow[y, 32:52, 0] = 2.0 if (y - 22) % 5 < 3 else 5.5
    return flow, np.ones((H, W), bool), region


def test_a_deforming_object_moves_as_a_whole_not_as_its_largest_part(monkeypatch: pytest.MonkeyPatch) -> None:
    """The RANSAC consensus at 1.5 px is the rows that move 2 px; refitted to every vector within 5 px of it and
    nearer it than the background's motion, the motion is the object's mean, 3.4 px; the ring stays out."""
    flow, ok, region = _deforming_pair()
    centre = np.array([42.0, 32.0, 1.0])
    ring = np.array([[1.0, 0.0, -6.0], [0.0, 1.0, 0.0]])
    fit = motion_init._pair_fit(flow, ok, region)
    assert (fit.first @ centre)[0] - 42.0 == pytest.approx(2.0, abs=0.05)
    refined = motion_init._refined(fit.first, fit.points, fit.targets, ring)
    assert (refined @ centre)[0] - 42.0 == pytest.approx(3.4, abs=0.05)
    monkeypatch.setattr(motion_init, "REFINE_ROUNDS", 0)
    assert (motion_init._refined(fit.first, fit.points, fit.targets, ring) @ centre)[0] - 42.0 == pytest.approx(2.0)


def test_the_refit_keeps_the_consensus_scale() -> None:
    """Legs that spread as they swing (their rows' flow 2 px plus a quarter of each pixel's distance from the body's
    centre line) read as a zoom to a least-squares similarity: the refit takes its rotation and the translation,
    and keeps the consensus's scale, so a chain of pairs cannot shrink or grow an object that does not."""
    flow = np.zeros((H, W, 2), np.float32)
    region = np.zeros((H, W), bool)
    region[20:44, 30:54] = True
    flow[20:44, 30:54, 0] = -6.0  # the background ring of the mask
    xs = np.arange(32, 52, dtype=np.float32)
    for y in range(22, 42):
        flow[y, 32:52, 0] = 2.0 if (y - 22) % 5 < 3 else 2.0 + 0.25 * (xs + 0.5 - 42.0)
    fit = motion_init._pair_fit(flow, np.ones((H, W), bool), region)
    zoom = motion_init._least_squares_similarity(fit.points, fit.targets)
    assert zoom is not None and motion_init._scale(zoom) > 1.02  # 2% a frame: 1.8 times the size in 30 frames
    refined = motion_init._refined(fit.first, fit.points, fit.targets, np.array([[1.0, 0.0, -6.0], [0.0, 1.0, 0.0]]))
    assert motion_init._scale(refined) == pytest.approx(motion_init._scale(fit.first), abs=1e-9)
    assert (refined @ np.array([42.0, 32.0, 1.0]))[0] - 42.0 == pytest.approx(2.0, abs=0.1)


def test_a_slow_object_is_refined_apart_from_the_background() -> None:
    """A locked-off shot: rows of the object moving 1 and 2 px inside a mask whose ring is still. Every vector is
    within 5 px of the consensus; the ring's, nearer the background's (still) motion, stay out of the refit, which
    is the object's mean (1.6 px); the RANSAC consensus takes the ring in and is pulled towards it."""
    flow = np.zeros((H, W, 2), np.float32)
    region = np.zeros((H, W), bool)
    region[20:44, 30:54] = True
    for y in range(22, 42):
        flow[y, 32:52, 0] = 2.0 if (y - 22) % 5 < 3 else 1.0
    centre = np.array([42.0, 32.0, 1.0])
    fit = motion_init._pair_fit(flow, np.ones((H, W), bool), region)
    assert (fit.first @ centre)[0] - 42.0 < 1.5
    refined = motion_init._refined(fit.first, fit.points, fit.targets, np.eye(2, 3))
    assert (refined @ centre)[0] - 42.0 == pytest.approx(1.6, abs=0.05)


def _layer_motion(fwd: np.ndarray, masks: np.ndarray, background: bool = True) -> LayerMotion:
    """The starting motion of the object layer of ``masks`` under the forward flow ``fwd`` (reliable everywhere,
    the backward flow its negative), knowing the background layer's motion, or alone without ``background``."""
    ok = np.ones(fwd.shape[:3], bool)
    flow = FlowField(fwd, -fwd, ok, ok.copy(), "test", 1.0)
    camera = estimate_layer_motion(flow, None, (W, H), True, 0.0) if background else None
    return estimate_layer_motion(flow, masks, (W, H), True, 0.06, background=camera)


@pytest.mark.parametrize("background", [True, False], ids=["with the background", "alone"])
def test_a_deforming_object_over_a_clip(background: bool) -> None:
    """End to end: the object of ``_deforming_pair`` in every frame (the camera panning 3 px a frame the other way).
    A layer that knows the background's motion starts at the object's mean motion, 3.4 px a frame, so the object's
    centre stays put in its atlas (within the half pixel its box is rounded to); alone (no background to keep apart
    from, as the background layer itself) at its largest part's, 2 px a frame, and the object drifts 10 px."""
    fwd = np.zeros((T - 1, H, W, 2), np.float32)
    fwd[..., 0] = CAMERA_STEP
    masks = np.zeros((T, H, W), bool)
    for t in range(T):
        x0 = 10 + round(3.4 * t)
        masks[t, 20:44, x0 - 2 : x0 + 22] = True
        if t < T - 1:
            for y in range(22, 42):
                fwd[t, y, x0 : x0 + 20, 0] = 2.0 if (y - 22) % 5 < 3 else 5.5
    motion = _layer_motion(fwd, masks, background)
    centres = np.array([motion.to_ref[t] @ np.array([20 + round(3.4 * t), 32.0, 1.0]) for t in range(T)])
    drift = float(np.abs(centres - centres[0]).max())
    assert drift < 0.6 if background else drift > 9.0


def test_the_size_error_compares_the_motion_with_the_masks() -> None:
    """The size a chained motion gives the object against the size its masks show, from the first frame with a
    mask: 0 where they agree, the median |log| ratio where they do not; frames without a mask count for nothing,
    and fewer than two frames with one give 0 (nothing to compare, no division by an empty mask's area)."""
    grow = np.array([1.0, 1.1, 1.2, 1.3])  # frame pixels per reference pixel
    to_ref = np.stack([np.eye(2, 3) / g for g in grow])
    assert motion_init._size_error(to_ref, [int(100 * g * g) for g in grow]) == pytest.approx(0.0, abs=0.01)
    assert motion_init._size_error(to_ref, [100, 100, 0, 100]) == pytest.approx(np.log(1.3 / 1.0) / 2 + np.log(1.1) / 2)
    assert motion_init._size_error(to_ref, [0, 100, 0, 0]) == 0.0
    assert motion_init._size_error(to_ref, [0, 0, 0, 0]) == 0.0


def test_a_deforming_object_keeps_its_size_where_its_masks_do() -> None:
    """Legs that spread as they swing (their rows' flow 2 px plus half of each pixel's distance from the body's centre
    line) in every frame of a clip whose masks keep one size: the least-squares scale would grow the object 6% a
    frame (1.5 times by the last), the masks say it does not, so the layer keeps its consensus's scale (0.4% a frame:
    RANSAC's at 1.5 px)."""
    fwd = np.zeros((T - 1, H, W, 2), np.float32)
    fwd[..., 0] = CAMERA_STEP
    masks = np.zeros((T, H, W), bool)
    xs = np.arange(20, dtype=np.float32)
    for t in range(T):
        x0 = 10 + 2 * t
        masks[t, 20:44, x0 - 2 : x0 + 22] = True
        if t < T - 1:
            for y in range(22, 42):
                legs = 2.0 + 0.5 * (xs + 0.5 - 10.0)
                fwd[t, y, x0 : x0 + 20, 0] = 2.0 if (y - 22) % 5 < 3 else legs
    motion = _layer_motion(fwd, masks)
    sizes = [1.0 / motion_init._scale(m) for m in motion.to_ref]
    assert max(abs(s - 1.0) for s in sizes) < 0.03


def test_a_deforming_object_takes_the_least_squares_scale_where_its_masks_grow() -> None:
    """Spreading legs like ``test_a_deforming_object_keeps_its_size_where_its_masks_do``'s in every other row of an
    object whose masks grow 6% a frame, as the least-squares scale does (a dog coming towards the camera, whose
    largest rigid part says little of its size): the layer takes that scale, and the object's size in the last frame
    is near the masks' (1.5 times the first)."""
    fwd = np.zeros((T - 1, H, W, 2), np.float32)
    fwd[..., 0] = CAMERA_STEP
    masks = np.zeros((T, H, W), bool)
    for t in range(T):
        centre = 20.0 + 2 * t
        half = 10.0 * 1.061**t
        y0, y1, x0, x1 = round(32 - half), round(32 + half), round(centre - half), round(centre + half)
        masks[t, y0:y1, x0:x1] = True
        if t < T - 1:
            for y in range(y0, y1):
                legs = 2.0 + 0.5 * (np.arange(x0, x1) + 0.5 - centre)
                fwd[t, y, x0:x1, 0] = 2.0 if (y - y0) % 2 == 0 else legs
    motion = _layer_motion(fwd, masks)
    # the masks' 1.5 times; the consensus's scale would leave it at 1.03
    assert 1.0 / motion_init._scale(motion.to_ref[-1]) == pytest.approx(1.5, abs=0.15)


def test_a_rigid_object_keeps_its_consensus_motion() -> None:
    """A rigid object (a car) whose flow is one similarity but for a window where reflections move 3 px further:
    its consensus holds most of the mask's vectors (``RIGID_SHARE``), so it is not refitted towards the window's
    (which a refit within 5 px would take in), and the car stays put in its atlas."""
    fwd = np.zeros((T - 1, H, W, 2), np.float32)
    fwd[..., 0] = CAMERA_STEP
    masks = np.zeros((T, H, W), bool)
    for t in range(T):
        x0 = 10 + 3 * t
        masks[t, 20:44, x0 : x0 + 24] = True
        if t < T - 1:
            fwd[t, 20:44, x0 : x0 + 24, 0] = 3.0
            fwd[t, 22:28, x0 + 14 : x0 + 22, 0] = 6.0  # the window: 48 of 576 vectors
    motion = _layer_motion(fwd, masks)
    centres = np.array([motion.to_ref[t] @ np.array([22.0 + 3 * t, 32.0, 1.0]) for t in range(T)])
    assert np.abs(centres - centres[0]).max() < 1e-3


def test_the_least_squares_similarity_is_exact_and_refuses_degenerate_points() -> None:
    """A known similarity is recovered exactly; fewer than two distinct points fix none (no division by a zero
    spread), and the RANSAC motion is kept."""
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 50, (30, 2))
    angle, scale = 0.1, 1.05
    known = np.array(
        [[scale * np.cos(angle), -scale * np.sin(angle), 3.0], [scale * np.sin(angle), scale * np.cos(angle), -2.0]]
    )
    fitted = motion_init._least_squares_similarity(src, src @ known[:, :2].T + known[:, 2])
    assert fitted is not None
    np.testing.assert_allclose(fitted, known, atol=1e-9)
    assert motion_init._least_squares_similarity(src[:1], src[:1]) is None
    assert motion_init._least_squares_similarity(np.repeat(src[:1], 5, 0), src[:5]) is None
