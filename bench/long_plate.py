"""A long, large plate made of a real clip: its frames upscaled to a production size and played forward and back
(ping-pong) to a production length, with its masks and its TAP-Vid tracks carried along.

Why ping-pong: every stretch of the long plate as long as the clip is as hard as the clip itself (the same motion,
the same turns), so a long fit's quality on its first frames can be set beside a fit of those frames alone, and the
difference is the length's cost, not new content's. The first ``len(clip)`` frames are the clip's own, in order, so
the clip's tracks (frames 0..T-1, T <= the clip's length) hold on the long plate once scaled to its size.
Frames are upscaled bicubic, masks nearest (they stay binary); written as 8-bit PNG, the clip's own depth.
"""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from bench.bench_clip import TRACKS_FILE
from bench.report_file import to_plate_scale
from bench.tracking import load_tracks, save_tracks
from engine.errors import InputError
from engine.io.clip_messages import FRAME, MASK, Role
from engine.io.images import cv2_read, cv2_write
from engine.io.sequences import list_images


def ping_pong(count: int, length: int) -> list[int]:
    """The clip frame shown at each of ``length`` frames: 0, 1, .., count-1, count-2, .., 1, 0, 1, ... (a clip of one
    frame repeats it)."""
    cycle = list(range(count)) + list(range(count - 2, 0, -1))
    return [cycle[i % len(cycle)] for i in range(length)]


def _images(folder: Path, role: Role) -> list[Path]:
    """The folder's images in frame-number order (the engine's own listing and its refusals)."""
    files = list_images(str(folder), role) if folder.is_dir() else []
    if not files:
        raise InputError(folder, "no images here", "give a clip folder holding frames/ and masks/")
    return [Path(f.path) for f in files]


def write_long_plate(clip: str | Path, out: str | Path, width: int, height: int, length: int) -> Path:
    """Write ``out``/frames, ``out``/masks (and ``out``/tracks_tapvid.npz when the clip has tracks): the clip's
    frames at ``width`` x ``height``, ping-ponged to ``length`` frames. Returns ``out``."""
    clip, out = Path(clip), Path(out)
    frames, masks = _images(clip / "frames", FRAME), _images(clip / "masks", MASK)
    if len(masks) != len(frames):
        raise InputError(clip / "masks", f"{len(masks)} masks for {len(frames)} frames", "give one mask a frame")
    for name in ("frames", "masks"):
        (out / name).mkdir(parents=True, exist_ok=True)
    written: dict[int, int] = {}  # clip frame -> the long plate's first frame showing it: later ones are copies
    for i, k in enumerate(ping_pong(len(frames), length)):
        for name, files, interpolation in (
            ("frames", frames, cv2.INTER_CUBIC),
            ("masks", masks, cv2.INTER_NEAREST),
        ):
            dest = out / name / f"{i:05d}.png"
            if k in written:
                shutil.copyfile(out / name / f"{written[k]:05d}.png", dest)
                continue
            image = cv2_read(files[k])
            if image is None:
                raise InputError(files[k], "cannot be decoded", "replace the file")
            cv2_write(dest, cv2.resize(image, (width, height), interpolation=interpolation))
        written.setdefault(k, i)
    if (clip / TRACKS_FILE).is_file():
        tracks = load_tracks(clip / TRACKS_FILE).cut(length)
        scale = to_plate_scale(tracks, (width, height)).astype(np.float32)  # the tracks file is float32
        query = tracks.query_txy.copy()
        query[:, 1:] *= scale
        scaled = replace(tracks, xy=tracks.xy * scale, query_txy=query, image_size=(width, height))
        save_tracks(out / TRACKS_FILE, scaled)
    return out
