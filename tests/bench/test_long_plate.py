"""The long plate on a tiny clip: frames played forward and back, each the clip frame the ping-pong names, resized
(masks still binary), the tracks scaled to the new size on the clip's own first frames, and bad clip folders refused
in one line."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from bench.long_plate import ping_pong, write_long_plate
from bench.tracking import Tracks, load_tracks, save_tracks
from engine.errors import InputError
from engine.io.images import cv2_read, cv2_write


def test_ping_pong_plays_forward_then_back() -> None:
    assert ping_pong(4, 10) == [0, 1, 2, 3, 2, 1, 0, 1, 2, 3]
    assert ping_pong(1, 3) == [0, 0, 0]
    assert ping_pong(5, 3) == [0, 1, 2]


def _clip(root: Path, count: int = 4) -> Path:
    for name in ("frames", "masks"):
        (root / name).mkdir(parents=True)
    for i in range(count):
        frame = np.full((12, 16, 3), 40 * i, np.uint8)  # each frame one grey: which one is written is readable
        mask = np.zeros((12, 16), np.uint8)
        mask[3:9, 4:12] = 255
        cv2_write(root / "frames" / f"{i:05d}.jpg", frame)
        cv2_write(root / "masks" / f"{i:05d}.png", mask)
    xy = np.array([[[2.0, 3.0], [4.0, 5.0], [6.0, 7.0]]], np.float32)
    tracks = Tracks(xy, np.zeros((1, 3), bool), np.array([[0.0, 2.0, 3.0]], np.float32), (16, 12), np.ones(1, bool))
    save_tracks(root / "tracks_tapvid.npz", tracks)
    return root


def test_the_long_plate_is_the_clip_ping_ponged_at_its_size(tmp_path: Path) -> None:
    out = write_long_plate(_clip(tmp_path / "clip"), tmp_path / "long", 32, 18, 9)
    frames = sorted((out / "frames").iterdir())
    assert len(frames) == 9 and len(list((out / "masks").iterdir())) == 9
    greys = [int(np.median(cv2_read(f))) for f in frames]
    expected = [40 * k for k in ping_pong(4, 9)]
    assert np.abs(np.array(greys) - expected).max() <= 2  # JPEG's rounding
    mask = cv2_read(out / "masks" / "00005.png", cv2.IMREAD_GRAYSCALE)
    assert mask.shape == (18, 32) and set(np.unique(mask)) == {0, 255}
    tracks = load_tracks(out / "tracks_tapvid.npz")
    assert tracks.image_size == (32, 18)
    np.testing.assert_allclose(tracks.xy[0, :, 0], [4.0, 8.0, 12.0])
    np.testing.assert_allclose(tracks.xy[0, :, 1], [4.5, 7.5, 10.5])
    np.testing.assert_allclose(tracks.query_txy[0], [0.0, 4.0, 4.5])


def test_a_short_long_plate_cuts_the_tracks(tmp_path: Path) -> None:
    out = write_long_plate(_clip(tmp_path / "clip"), tmp_path / "long", 16, 12, 2)
    assert load_tracks(out / "tracks_tapvid.npz").num_frames == 2


def test_a_clip_without_frames_or_with_too_few_masks_is_refused(tmp_path: Path) -> None:
    (tmp_path / "empty" / "frames").mkdir(parents=True)
    with pytest.raises(InputError, match="no images here"):
        write_long_plate(tmp_path / "empty", tmp_path / "out", 16, 16, 4)
    clip = _clip(tmp_path / "clip")
    (clip / "masks" / "00003.png").unlink()
    with pytest.raises(InputError, match="3 masks for 4 frames"):
        write_long_plate(clip, tmp_path / "out", 16, 16, 4)
