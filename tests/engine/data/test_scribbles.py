"""Scribble input (paper Sec. 4.4): colour code, sparse frames, resizing, bad input; the mask grouping."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from engine import contract as C
from engine.data.scribbles import (
    NO_LABEL,
    labels_from_rgba,
    propagate_labels,
    read_scribbles,
    resize_labels,
    scribble_layers,
)
from engine.errors import InputError
from engine.io.clip import open_clip
from engine.model.objective import mask_alphas
from tests.two_object_scene import TwoObjectSpec, make_two_object_scene, write_two_object_scene

SMALL = TwoObjectSpec(
    width=80, height=48, frames=4, a_start=(10.0, 8.0), b_start=(40.0, 14.0), a_size=(20, 16), b_size=(18, 16)
)


@pytest.fixture()
def clip(tmp_path):
    scene = make_two_object_scene(SMALL)
    frames_dir, _ = write_two_object_scene(scene, tmp_path / "clip", union=True)
    return open_clip(frames_dir), tmp_path


def test_colour_code_with_tolerance_and_alpha():
    tol = C.SCRIBBLE_TOLERANCE
    img = np.array(
        [
            [[255, 0, 0, 255], [255 - tol, tol, tol, 255], [255 - tol - 1, 0, 0, 255]],
            [[0, 255, 0, 255], [0, 255, 0, 100], [0, 0, 0, 255]],
        ],
        dtype=np.uint8,
    )
    assert labels_from_rgba(img).tolist() == [[0, 0, NO_LABEL], [1, NO_LABEL, NO_LABEL]]
    assert labels_from_rgba(img[..., :3]).tolist() == [[0, 0, NO_LABEL], [1, 1, NO_LABEL]]


def test_thin_stroke_survives_downscaling():
    labels = np.full((40, 40), NO_LABEL, np.int8)
    labels[:, 10] = 1  # a 1-px green line
    small = resize_labels(labels, (20, 20), len(C.SCRIBBLE_COLOURS))
    assert (small[:, 5] == 1).all() and (small[:, :5] == NO_LABEL).all() and (small[:, 6:] == NO_LABEL).all()


def test_sparse_frames_matched_by_number(clip):
    info, tmp = clip
    folder = tmp / "scribbles"
    folder.mkdir()
    img = np.zeros((SMALL.height, SMALL.width, 3), np.uint8)
    img[4:8, 4:8] = (0, 0, 255)  # BGR red, aligned to the 2x downscale
    img[20:24, 50:54] = (0, 255, 0)
    cv2.imwrite(str(folder / C.SCRIBBLE_FILE_FORMAT.format(2)), img)
    labels = read_scribbles(folder, info, (SMALL.width // 2, SMALL.height // 2))
    assert labels.shape == (4, SMALL.height // 2, SMALL.width // 2)
    assert (labels[[0, 1, 3]] == NO_LABEL).all()
    assert (labels[2] == 0).sum() == 4 and (labels[2] == 1).sum() == 4
    assert scribble_layers(labels) == 2


def test_no_scribbles_is_a_clear_error(clip):
    info, tmp = clip
    folder = tmp / "scribbles"
    folder.mkdir()
    cv2.imwrite(str(folder / "00001.png"), np.zeros((SMALL.height, SMALL.width, 3), np.uint8))
    with pytest.raises(InputError, match="no scribbles"):
        read_scribbles(folder, info, (SMALL.width, SMALL.height))
    with pytest.raises(InputError, match="does not exist"):
        read_scribbles(tmp / "nope", info, (SMALL.width, SMALL.height))


def test_wrong_aspect_names_the_file(clip):
    info, tmp = clip
    folder = tmp / "scribbles"
    folder.mkdir()
    cv2.imwrite(str(folder / "00000.png"), np.full((30, 30, 3), 255, np.uint8))
    with pytest.raises(InputError, match=r"00000\.png"):
        read_scribbles(folder, info, (SMALL.width, SMALL.height))


def test_mask_alphas_sum_the_layers_a_mask_covers():
    w = torch.tensor([[0.1, 0.3, 0.6], [0.5, 0.25, 0.25]])
    assert torch.equal(mask_alphas(w, None), w[:, 1:])
    assert torch.allclose(mask_alphas(w, ((1, 2),)), torch.tensor([[0.9], [0.5]]))


def test_two_object_scene_ground_truth():
    scene = make_two_object_scene(SMALL)
    assert not (scene.masks[0] & scene.masks[1]).any()  # visible masks never overlap: A is in front
    assert (scene.coverage[0] & scene.coverage[1]).any()  # but the silhouettes do cross
    assert np.array_equal(scene.union, scene.coverage.any(0))
    # an A texture point has its exact texture colour in every frame it is visible (no resampling)
    tex = np.array([[10.0, 8.0]])
    for t in range(SMALL.frames):
        x, y = (tex + scene.offsets[0, t])[0]
        if float(x).is_integer() and float(y).is_integer():
            np.testing.assert_allclose(scene.frames[t, int(y), int(x)], scene.object_color(0, tex)[0], atol=1e-5)


def _shift_flow(t: int, h: int, w: int, dx: float):
    from engine.data.flow import FlowField

    fwd = np.zeros((t - 1, h, w, 2), np.float32)
    fwd[..., 0] = dx
    ok = np.ones((t - 1, h, w), bool)
    return FlowField(fwd, -fwd, ok, ok.copy(), "test", 1.0)


def test_scribbles_are_carried_along_the_flow_both_ways():
    t, h, w = 4, 6, 12
    labels = np.full((t, h, w), NO_LABEL, np.int8)
    labels[1, 2, 3] = 0
    labels[1, 3, 5] = 1
    out = propagate_labels(labels, _shift_flow(t, h, w, 2.0), np.ones((t, h, w), bool))
    for f, x_red in ((0, 1), (1, 3), (2, 5), (3, 7)):
        assert out[f, 2, x_red] == 0 and out[f, 3, x_red + 2] == 1
        assert (out[f] != NO_LABEL).sum() == 2


def test_carried_scribbles_stop_at_the_object_and_at_unreliable_flow():
    t, h, w = 3, 4, 10
    labels = np.full((t, h, w), NO_LABEL, np.int8)
    labels[0, 1, 2] = 0
    inside = np.ones((t, h, w), bool)
    inside[1, 1, 4] = False  # the point would land off the object in frame 1
    out = propagate_labels(labels, _shift_flow(t, h, w, 2.0), inside)
    assert (out[1:] == NO_LABEL).all()
    flow = _shift_flow(t, h, w, 2.0)
    flow.forward_ok[0, 1, 2] = False
    out = propagate_labels(labels, flow, np.ones((t, h, w), bool))
    assert (out[1:] == NO_LABEL).all()
    assert np.array_equal(propagate_labels(labels, None, inside), labels)  # a single frame: nothing to carry
