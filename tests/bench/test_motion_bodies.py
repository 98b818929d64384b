"""The two bodies of ``bench.motion_bodies`` do what their scenes are named for, checked against geometry
computed here: the turning body is seen in perspective and its sides hide where their normals turn away; the limbs
hide the torso and each other where their capsules cover it, and the body jumps on its parabola."""

from __future__ import annotations

import numpy as np
import pytest

from bench.motion_bodies import BACK_LIMB, FRONT_LIMB, TORSO, LimbsJump, TurningDepth, rotate
from bench.motion_builders import CAMERA_DISTANCE, DEPTH_HEIGHT, JUMP_HEIGHT, JUMP_PERIOD, SWING_PERIOD
from bench.motion_scenes import MotionScene, make_motion_scene
from bench.motion_tracks import NEIGHBOUR_FRAMES


@pytest.fixture(scope="module")
def depth_scene() -> MotionScene:
    # 9 frames: the turn is 90 degrees at frame 4, where the drifting axis crosses the optical axis
    return make_motion_scene("turning_depth", width=128, height=96, frames=9)


@pytest.fixture(scope="module")
def limbs_scene() -> MotionScene:
    # 36 frames: one and a half swings and two jumps, at a small size
    return make_motion_scene("limbs_jump", width=128, height=96, frames=36)


def _pixels(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ys, xs = np.nonzero(mask)
    return xs.astype(np.float64), ys.astype(np.float64)


@pytest.mark.parametrize("which", ["depth", "limbs"])
def test_render_surface_position_round_trip(depth_scene, limbs_scene, which):
    """Every object pixel's surface point, sent forward again, lands on that pixel and is seen there."""
    scene = depth_scene if which == "depth" else limbs_scene
    for t in range(0, scene.spec.frames, 3):
        x, y = _pixels(scene.masks[t])
        uv, cov = scene.model.surface(float(t), x, y)
        assert (cov > 0.5).all()
        xy, seen = scene.model.position(float(t), uv)
        np.testing.assert_allclose(xy, np.stack((x, y), -1), atol=1e-9)
        assert seen.all()


def test_turning_body_is_seen_in_perspective(depth_scene):
    """End-on (frame 4) the near end stands at depth D - a, so its column is D / (D - a) = 1.5 times the body's
    height; side-on (frame 0) the middle of the near side is nearest, taller than the ends."""
    model = depth_scene.model
    assert isinstance(model, TurningDepth)
    height = DEPTH_HEIGHT * depth_scene.spec.height
    end_on = depth_scene.masks[4].sum(axis=0).max()
    expected = height * CAMERA_DISTANCE / (CAMERA_DISTANCE - 1.0)
    assert abs(end_on - expected) <= 1.0 and expected == pytest.approx(1.5 * height)
    cols = np.flatnonzero(depth_scene.masks[0].any(axis=0))
    heights = depth_scene.masks[0].sum(axis=0)
    near = height * model.distance / (model.distance - model.half_width)  # straight ahead of the camera
    assert abs(heights.max() - near) <= 1.0 and heights[cols[2]] < heights.max() - 2


def _world(model: TurningDepth, t: float, theta: float) -> tuple[np.ndarray, np.ndarray]:
    """The 3-D point (x, z) of the cross-section at ``theta`` and its outward normal in frame ``t``, from the
    body's dimensions alone."""
    ax, az = model.axis(t)
    bx, bz = model.half_length * np.cos(theta), model.half_width * np.sin(theta)
    nx, nz = np.cos(theta) / model.half_length, np.sin(theta) / model.half_width
    turn = model.turn * t
    return np.array(rotate(bx, bz, turn)) + np.array([ax, az]), np.array(rotate(nx, nz, turn))


def test_a_front_point_hides_where_its_normal_turns_from_the_camera(depth_scene):
    """The point facing the camera in frame 0 is seen while its normal points at the camera (n . (camera - P) > 0)
    and hidden after: at arccos(b / D) = 80 degrees of turn, not 90 (the camera is at a finite distance D; b the
    half width), and still at 90."""
    model = depth_scene.model
    assert isinstance(model, TurningDepth)
    theta = 1.5 * np.pi  # the -z side's middle: straight towards the camera when the turn is 0
    uv = np.array([theta * model.radius_mean, model.height / 2.0])
    times = np.linspace(0.0, depth_scene.spec.frames - 1, 161)
    seen = np.array([bool(model.position(t, uv)[1]) for t in times])
    geometry = np.array([-(_world(model, t, theta)[1] @ _world(model, t, theta)[0]) > 0 for t in times])
    np.testing.assert_array_equal(seen, geometry)
    assert seen[0] and not seen[-1]
    flip = times[np.flatnonzero(~seen)[0]] * model.turn
    assert np.degrees(abs(flip - np.arccos(model.half_width / model.distance))) < 2.0  # the drift moves it a little
    assert not model.position(4.0, uv)[1]  # 90 degrees turned


def test_a_hidden_point_is_behind_another_surface_point(depth_scene):
    """Where the camera does not see a track's point but its position is on the body, the pixel there shows
    another surface point (the near side), not this one."""
    tr, model = depth_scene.tracks, depth_scene.model
    apart = []
    for n in range(len(tr.xy)):
        quv = model.surface(float(tr.query_txy[n, 0]), *(tr.query_txy[n, 1:] - 0.5))[0]
        for t in np.flatnonzero(tr.occluded[n]):
            p = tr.xy[n, t] - 0.5
            uv, cov = model.surface(float(t), np.float64(p[0]), np.float64(p[1]))
            if cov < 1.0:
                continue
            du = (uv[0] - quv[0] + model.u_period / 2.0) % model.u_period - model.u_period / 2.0
            apart.append(np.hypot(du, uv[1] - quv[1]))
    # just past the silhouette the point in front is a neighbour on the surface; further, the other side
    assert len(apart) >= 20 and min(apart) > 1.0 and np.median(apart) > 10.0


def test_the_turn_hides_one_side_and_shows_the_other(depth_scene):
    model, last = depth_scene.model, depth_scene.spec.frames - 1
    first_uv = depth_scene.uv[0][depth_scene.masks[0]].astype(np.float64)
    last_uv = depth_scene.uv[last][depth_scene.masks[last]].astype(np.float64)
    assert 1.0 - model.position(float(last), first_uv)[1].mean() > 0.95
    assert 1.0 - model.position(0.0, last_uv)[1].mean() > 0.95
    # the two sides look different: the mean colour of what frame 0 shows against what the last frame shows
    first_rgb = depth_scene.frames[0][depth_scene.masks[0]].mean(0)
    last_rgb = depth_scene.frames[last][depth_scene.masks[last]].mean(0)
    assert np.abs(first_rgb - last_rgb).max() > 0.2
    tr = depth_scene.tracks
    assert all(tr.occluded[n].any() and not tr.occluded[n, int(tr.query_txy[n, 0])] for n in range(len(tr.xy)))


def _limb_covers(model: LimbsJump, t: float, which: int, xy: np.ndarray) -> bool:
    """Whether limb ``which``'s capsule covers frame point ``xy``: the hinge and angle from the body's numbers."""
    cx, cy = model.centre(t)
    sign = 1.0 if which == FRONT_LIMB else -1.0
    hinge = np.array([cx + sign * model.hinge[0], cy + model.hinge[1]])
    angle = sign * model.limb_angle(t)
    capsule = model.parts[which]
    end = hinge + capsule.length * np.array([-np.sin(angle), np.cos(angle)])
    d = end - hinge
    s = np.clip((xy - hinge) @ d / (d @ d), 0.0, 1.0)
    return bool(np.linalg.norm(xy - hinge - s * d) < capsule.radius)


def test_a_torso_point_hides_while_the_front_limb_passes(limbs_scene):
    """A point on the torso's axis below the hinges is hidden exactly while the front limb's capsule covers it:
    round the limbs' crossings (hanging straight down at a quarter and three quarters of a swing), seen when the
    limbs are out."""
    model = limbs_scene.model
    assert isinstance(model, LimbsJump)
    torso = model.parts[TORSO]
    uv = np.array([torso.offset[0] + torso.radius, torso.offset[1] + torso.radius + 0.7 * torso.length])
    times = np.arange(0.0, limbs_scene.spec.frames, 0.25)
    seen = []
    for t in times:
        xy, visible = model.position(t, uv)
        assert bool(visible) != _limb_covers(model, t, FRONT_LIMB, xy)
        seen.append(bool(visible))
    seen_arr = np.array(seen)
    for crossing in (0.25 * SWING_PERIOD, 0.75 * SWING_PERIOD, 1.25 * SWING_PERIOD):
        assert not seen_arr[times == crossing].any()
    for out in (0.0, 0.5 * SWING_PERIOD, SWING_PERIOD):
        assert seen_arr[times == out].all()


def test_the_limbs_hide_each_other_and_the_back_one_hides_behind_the_torso(limbs_scene):
    model = limbs_scene.model
    assert isinstance(model, LimbsJump)
    back_behind_front = back_behind_torso = 0
    for t in range(limbs_scene.spec.frames):
        x, y = _pixels(np.ones(limbs_scene.masks[t].shape, bool))
        covs, _ = model.coverages(float(t), x, y)
        label = model.visible_part(float(t), x, y)
        back_behind_front += int(((covs[BACK_LIMB] > 0.5) & (label == FRONT_LIMB) & (covs[TORSO] <= 0.5)).sum())
        back_behind_torso += int(((covs[BACK_LIMB] > 0.5) & (label == TORSO)).sum())
        assert not ((covs[FRONT_LIMB] > 0.5) & (label != FRONT_LIMB)).any()  # nothing is in front of it
    assert back_behind_front > 10 and back_behind_torso > 500  # they cross mostly over the torso


def test_tracks_are_on_every_part_and_some_come_back(limbs_scene):
    """Query points lie on all three parts; some are hidden within NEIGHBOUR_FRAMES of their query frame (they
    were seen, hid, and came back, or the other way round)."""
    model, tr = limbs_scene.model, limbs_scene.tracks
    assert isinstance(model, LimbsJump)
    parts = []
    comes_back = 0
    for n in range(len(tr.xy)):
        tq = int(tr.query_txy[n, 0])
        uv = model.surface(float(tq), *(tr.query_txy[n, 1:].astype(np.float64) - 0.5))[0]
        parts.append(int(model.part_of(uv)))
        near = tr.occluded[n, max(0, tq - NEIGHBOUR_FRAMES) : tq + NEIGHBOUR_FRAMES + 1]
        comes_back += int(near.any() and not tr.occluded[n, tq])
    assert set(parts) == {TORSO, FRONT_LIMB, BACK_LIMB}
    assert min(parts.count(p) for p in (TORSO, FRONT_LIMB, BACK_LIMB)) >= 12
    assert comes_back >= 8
    assert not tr.occluded[np.array(parts) == FRONT_LIMB].any()  # in front of everything, inside the frame


def test_the_body_jumps_on_a_parabola(limbs_scene):
    """The mask's top row is the torso's top, which rises and falls by JUMP_HEIGHT on each JUMP_PERIOD arc."""
    model = limbs_scene.model
    assert isinstance(model, LimbsJump)
    torso = model.parts[TORSO]
    tops = []
    for t in range(limbs_scene.spec.frames):
        top = model.centre(float(t))[1] - torso.length / 2.0 - torso.radius
        assert abs(np.flatnonzero(limbs_scene.masks[t].any(axis=1))[0] - top) <= 1.0
        tops.append(top)
    rise = tops[0] - tops[round(JUMP_PERIOD / 2)]
    assert rise == pytest.approx(JUMP_HEIGHT * limbs_scene.spec.height)
    assert tops[0] == pytest.approx(tops[round(JUMP_PERIOD)])  # landed
