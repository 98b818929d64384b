"""Parts from motion: a limb that swings in front of a moving body is split from it (strokes inside each part, on most
key frames), an object that moves as one piece is not, and the degenerate clips (static, empty, one frame, masks
on a few frames) give no strokes and no error."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from engine import contract as C
from engine.data.flow import FlowField, consistency_mask
from engine.data.motion_parts import PartsConfig, key_frame_positions, motion_parts, split_motion
from engine.data.motion_parts_files import stroke_image
from engine.data.scribbles import NO_LABEL, labels_from_rgba

T, H, W = 16, 200, 280
BODY = (60, 120)  # width, height
LIMB = (14, 100)
SPEED = 3.0  # body, px per frame to the right


def _pivot(t: int) -> np.ndarray:
    return np.array([80.0 + SPEED * t, 60.0])


def _angle(t: int, swing: float) -> float:
    """Degrees: the limb swings this far either way over the clip."""
    return swing * np.sin(2 * np.pi * t / T)


def _rot(deg: float) -> np.ndarray:
    r = np.deg2rad(deg)
    return np.array([[np.cos(r), -np.sin(r)], [np.sin(r), np.cos(r)]])


def _parts(t: int, swing: float) -> tuple[np.ndarray, np.ndarray]:
    """bool [H, W] body and limb (the limb in front) at frame t."""
    body = np.zeros((H, W), np.uint8)
    x0, y0 = _pivot(t) - np.array([BODY[0] / 2, 10.0])
    cv2.rectangle(body, (int(x0), int(y0)), (int(x0 + BODY[0]), int(y0 + BODY[1])), 1, -1)
    lw, lh = LIMB
    corners = np.array([[-lw / 2, 0], [lw / 2, 0], [lw / 2, lh], [-lw / 2, lh]]) @ _rot(_angle(t, swing)).T
    limb = np.zeros((H, W), np.uint8)
    cv2.fillPoly(limb, [np.rint(corners + _pivot(t)).astype(np.int32)], 1)
    return body.astype(bool) & ~limb.astype(bool), limb.astype(bool)


def _flow(t: int, step: int, swing: float) -> np.ndarray:
    """The exact flow [H, W, 2] from frame t to t + step (step +-1): the limb turns about its pivot, the body and
    everything else translate with the body (background included: it is never followed)."""
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    p = np.stack([xs, ys], -1)
    _, limb = _parts(t, swing)
    moved = p + np.array([SPEED * step, 0.0])
    turn = _rot(_angle(t + step, swing) - _angle(t, swing))
    on_limb = (p - _pivot(t)) @ turn.T + _pivot(t + step)
    moved[limb] = on_limb[limb]
    return (moved - p).astype(np.float32)


def _clip(swing: float) -> tuple[np.ndarray, FlowField, np.ndarray, np.ndarray]:
    body = np.zeros((T, H, W), bool)
    limb = np.zeros((T, H, W), bool)
    for t in range(T):
        body[t], limb[t] = _parts(t, swing)
    fwd = np.stack([_flow(t, 1, swing) for t in range(T - 1)])
    bwd = np.stack([_flow(t + 1, -1, swing) for t in range(T - 1)])
    # where the limb uncovers or covers the body the round trip fails, as it does for a real flow
    return (
        body | limb,
        FlowField(fwd, bwd, consistency_mask(fwd, bwd), consistency_mask(bwd, fwd), "exact", 1.0),
        body,
        limb,
    )


def test_a_swinging_limb_is_split_from_the_body():
    masks, flow, body, limb = _clip(swing=35.0)
    result = motion_parts(masks, flow)
    assert result.found and result.parts == 2
    stroked = [t for t in range(T) if (result.labels[t] != NO_LABEL).any()]
    assert len(stroked) >= 4  # of the six key frames, all but those where the limb turns back and rests
    assert "2 parts that move apart" in result.message
    on_body, on_limb = result.labels == 0, result.labels == 1
    # the body is part 0 (the larger), the limb part 1; each stroke lies in its own part
    assert (on_body & body).sum() >= 0.98 * on_body.sum() and on_body.sum() > 2000
    assert (on_limb & limb).sum() >= 0.98 * on_limb.sum() and on_limb.sum() > 300
    # strokes stay inside the mask, off its outline
    inner = np.stack([cv2.erode(m.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0 for m in masks])
    assert not ((result.labels != NO_LABEL) & ~inner).any()


def test_an_object_that_moves_as_one_piece_is_not_split():
    masks, flow, _, _ = _clip(swing=0.0)
    result = motion_parts(masks, flow)
    assert not result.found and result.parts == 1
    assert (result.labels == NO_LABEL).all()
    assert "nothing to split" in result.message


def test_a_limb_that_moves_apart_on_only_some_key_frames_is_not_split():
    """The limb swings for the first 13 frames, then moves with the body: four of the six key frames find two parts,
    fewer than ``min_agreement`` asks (five); on real footage such splits cost the paint more than they give."""
    swing = [35.0 if t < 13 else 0.0 for t in range(T)]
    masks = np.stack([np.logical_or(*_parts(t, swing[t])) for t in range(T)])
    fwd = np.stack([_flow(t, 1, swing[t]) for t in range(T - 1)])
    bwd = np.stack([_flow(t + 1, -1, swing[t + 1]) for t in range(T - 1)])
    flow = FlowField(fwd, bwd, consistency_mask(fwd, bwd), consistency_mask(bwd, fwd), "exact", 1.0)
    result = motion_parts(masks, flow)
    assert sum(len(k.shares) == 2 for k in result.key_frames) == 4
    assert not result.found and (result.labels == NO_LABEL).all()
    assert "no parts move apart on at least 5 of 6 key frames (split on 4)" in result.message
    assert motion_parts(masks, flow, PartsConfig(min_agreement=0.5)).found  # at half, as before


def test_a_static_object_and_degenerate_clips_give_no_strokes():
    masks, flow, _, _ = _clip(swing=35.0)
    still = FlowField(np.zeros_like(flow.forward), np.zeros_like(flow.backward), flow.forward_ok,
                      flow.backward_ok, "none", 1.0)  # fmt: skip
    assert not motion_parts(masks, still).found
    empty = np.zeros_like(masks)
    result = motion_parts(empty, flow)
    assert not result.found and result.parts == 0 and result.key_frames == []
    one = motion_parts(masks[:1], FlowField(flow.forward[:0], flow.backward[:0], flow.forward_ok[:0],
                                            flow.backward_ok[:0], "none", 1.0))  # fmt: skip
    assert not one.found and one.labels.shape == (1, H, W)
    # a flow that fails its round trip everywhere: nothing is followed, nothing split
    never = np.zeros_like(flow.forward_ok)
    bad = FlowField(flow.forward, flow.backward, never, never.copy(), "x", 1.0)
    lost = motion_parts(masks, bad)
    assert not lost.found and all(k.followed == 0 for k in lost.key_frames)


def test_masks_on_a_few_frames_are_enough_and_frames_without_one_do_not_judge():
    masks, flow, _, limb = _clip(swing=35.0)
    sparse = masks.copy()
    sparse[1::2] = False  # every other frame undrawn: the points cross them on the flow alone
    result = motion_parts(sparse, flow)
    assert result.found and result.parts == 2
    assert all(sparse[k.frame].any() for k in result.key_frames)
    on_limb = result.labels == 1
    assert (on_limb & limb).sum() >= 0.98 * on_limb.sum()


def test_key_frames_spread_over_the_frames_that_have_a_mask():
    assert key_frame_positions(np.ones(36, bool), 6) == [0, 7, 14, 21, 28, 35]
    assert key_frame_positions(np.ones(3, bool), 6) == [0, 1, 2]  # a short clip: each frame once
    has = np.ones(36, bool)
    has[[0, 7, 35]] = False
    assert key_frame_positions(has, 6) == [1, 6, 14, 21, 28, 34]
    assert key_frame_positions(np.zeros(10, bool), 6) == []
    assert key_frame_positions(np.ones(10, bool), 0) == []


def test_split_motion_separates_two_affine_motions_and_leaves_the_joint():
    rng = np.random.default_rng(0)
    body = rng.uniform(0, 100, (600, 2))
    limb = rng.uniform(100, 160, (200, 2))
    pivot = np.array([100.0, 100.0])
    src = np.concatenate([body, limb])
    shift = np.array([6.0, 0.0])
    moved = np.concatenate([body, (limb - pivot) @ _rot(10.0).T + pivot]) + shift  # the limb turns at its joint
    labels = split_motion(src, moved + rng.normal(0, 0.3, (800, 2)), PartsConfig())
    far = np.linalg.norm(limb - pivot, axis=1)
    assert (labels[:600] == 0).mean() > 0.9 and not (labels[:600] == 1).any()
    assert (labels[600:][far > 45] == 1).mean() > 0.9 and not (labels[600:] == 0).any()
    # near the joint both motions explain a point: no label there
    assert (labels[600:][far < 15] == NO_LABEL).all()
    # one motion: nothing to split
    assert (split_motion(body, body + shift, PartsConfig()) == NO_LABEL).all()


@pytest.mark.parametrize("size", [(280, 200), (560, 400), (100, 60)])
def test_stroke_images_read_back_as_the_labels(size):
    labels = np.full((H, W), NO_LABEL, np.int8)
    labels[40:80, 50:90] = 0
    labels[120:150, 150:170] = 1
    labels[10:20, 200:260] = 2
    image = stroke_image(labels, size)
    assert image.shape == (size[1], size[0], 4)
    back = labels_from_rgba(cv2.cvtColor(image, cv2.COLOR_BGRA2RGBA))
    expected = cv2.resize(labels.astype(np.int16), size, interpolation=cv2.INTER_NEAREST)
    assert np.array_equal(back, expected.astype(np.int8))
    assert len(C.SCRIBBLE_COLOURS) >= PartsConfig().max_parts


@pytest.mark.parametrize("cover", [0.44, 0.95, 1.0])
def test_an_object_filling_most_or_all_of_the_frame_is_searched(cover):
    """A close-up at the working size (768x432): up to 83k points followed at once, past OpenCV's 32767 per row. A
    mask filling the frame (1.0) moves with it: the points leaving the frame are dropped, the rest followed."""
    t_count, h, w = 8, 432, 768
    side = np.sqrt(cover)
    bw, bh = round(w * side), round(h * side)
    masks = np.zeros((t_count, h, w), bool)
    for t in range(t_count):
        x0 = min(w - bw, (w - bw) // 2 + t)
        masks[t, (h - bh) // 2 : (h - bh) // 2 + bh, x0 : x0 + bw] = True
    shift = np.zeros((t_count - 1, h, w, 2), np.float32)
    shift[..., 0] = 1.0
    ok = np.ones((t_count - 1, h, w), bool)
    flow = FlowField(shift, -shift, ok, ok.copy(), "exact", 1.0)
    result = motion_parts(masks, flow)
    assert not result.found and result.parts == 1  # one rigid piece: nothing to split
    judged = [k for k in result.key_frames if k.followed]
    assert judged and max(k.followed for k in judged) > 32767 * cover
