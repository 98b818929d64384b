"""Scribble images (paper Sec. 4.4): sparse per-frame strokes that say which foreground layer owns a pixel.

The colour code and the file naming are defined in ``engine.contract`` (SCRIBBLE_*); this module reads a
folder into per-frame labels at working resolution, which the objective turns into -log(alpha_i) terms.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import cv2
import numpy as np

from .. import contract as C
from ..errors import InputError
from ..io.clip import ClipInfo, same_aspect
from ..io.images import cv2_read, image_header
from ..terms.clip import SCRIBBLE_ALPHA_CUTOFF
from .flow import FlowField

#: No scribble at this pixel.
NO_LABEL = -1
#: After area-resizing a stroke to working resolution, a pixel keeps its label where the stroke covered at
#: least this fraction of it: thin strokes survive downscaling, a stroke's faint fringe does not.
MIN_STROKE_COVERAGE = 0.25
#: The stroke image files ``read_scribbles`` reads (and a fit finds in RUN_DIR/parts).
SCRIBBLE_EXTENSIONS = (".png", ".tif", ".tiff")
_NUMBER = re.compile(r"(\d+)(?!.*\d)")


def labels_from_rgba(image: np.ndarray) -> np.ndarray:
    """int8 [H, W] labels (0-based foreground layer, NO_LABEL) of an 8-bit RGB or RGBA image [H, W, 3|4]."""
    rgb = image[..., :3].astype(np.int16)
    drawn = image[..., 3] > SCRIBBLE_ALPHA_CUTOFF if image.shape[-1] == 4 else np.ones(rgb.shape[:2], dtype=bool)
    out = np.full(rgb.shape[:2], NO_LABEL, dtype=np.int8)
    for k, colour in enumerate(C.SCRIBBLE_COLOURS):
        near = (np.abs(rgb - np.asarray(colour, dtype=np.int16)) <= C.SCRIBBLE_TOLERANCE).all(-1)
        out[near & drawn] = k
    return out


def resize_labels(labels: np.ndarray, size: tuple[int, int], count: int) -> np.ndarray:
    """Labels at ``size=(W, H)``: per label the stroke's area coverage, the best-covered label where it
    covers at least MIN_STROKE_COVERAGE (nearest-neighbour resizing would drop thin strokes)."""
    w, h = size
    if labels.shape == (h, w):
        return labels.astype(np.int8)
    cover = np.stack(
        [cv2.resize((labels == k).astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) for k in range(count)]
    )
    out = cover.argmax(0).astype(np.int8)
    out[cover.max(0) < MIN_STROKE_COVERAGE] = NO_LABEL
    return out


#: How many times a side of the clip a scribble image may be: drawn at a proxy or at the plate's size, never a
#: 16000x12000 image for a 2K clip (a 600 KB PNG that decodes to 4 GB).
MAX_SCRIBBLE_SCALE = 2


def _check_header(file: str, info: ClipInfo) -> None:
    """A scribble image whose header declares a size beyond ``MAX_SCRIBBLE_SCALE`` times the clip's, refused in one
    line before a pixel is decoded (a file that cannot be opened is left to the decoder's own message)."""
    try:
        w, h, _ = image_header(file)
    except InputError:
        return
    if w > MAX_SCRIBBLE_SCALE * info.width or h > MAX_SCRIBBLE_SCALE * info.height:
        raise InputError(
            file,
            f"scribble image is {w}x{h} but the clip is {info.width}x{info.height}",
            "draw the scribbles at the clip's resolution",
        )


class NoScribbles(InputError):
    """A scribble folder with no stroke on the clip's selected frames (``read_scribbles``)."""


def read_scribbles(folder: str | Path, info: ClipInfo, size: tuple[int, int]) -> np.ndarray:
    """int8 [T, H, W] labels for the clip's selected frames at working ``size``; NO_LABEL where nothing is
    scribbled (every pixel of a frame without a scribble file). Files are matched by the frame number in
    their name (frames of a movie are numbered from 0, or from the fit's ``--start-frame``)."""
    path = os.path.abspath(os.path.expanduser(os.fspath(folder)))
    if not os.path.isdir(path):
        what = "is not a folder" if os.path.exists(path) else "scribble folder does not exist"
        raise InputError(path, what, "pass the folder that holds the scribble images")
    by_number: dict[int, str] = {}
    for name in sorted(os.listdir(path)):
        if name.startswith(".") or not name.lower().endswith(SCRIBBLE_EXTENSIONS):
            continue
        m = _NUMBER.search(os.path.splitext(name)[0])
        if m is None:
            raise InputError(
                os.path.join(path, name), "scribble file has no frame number", "name it like the frame: 00012.png"
            )
        number = int(m.group(1))
        if number in by_number:  # 0.png and 00000.png: which one the artist meant is theirs to say
            raise InputError(
                os.path.join(path, name),
                f"{os.path.basename(by_number[number])} and {name} both have frame number {number}",
                "keep one scribble file per frame",
            )
        by_number[number] = os.path.join(path, name)
    w, h = size
    out = np.full((info.num_frames, h, w), NO_LABEL, dtype=np.int8)
    used = 0
    for i, number in enumerate(info.frame_numbers):
        file = by_number.get(number)
        if file is None:
            continue
        _check_header(file, info)
        image = cv2_read(file)
        if image is None or image.ndim != 3 or image.dtype != np.uint8:
            raise InputError(file, "not an 8-bit RGB(A) image", "save scribbles as 8-bit RGB or RGBA PNG")
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGBA if image.shape[-1] == 4 else cv2.COLOR_BGR2RGB)
        ih, iw = image.shape[:2]
        if not same_aspect((iw, ih), (info.width, info.height)):
            raise InputError(
                file,
                f"scribble image is {iw}x{ih} but the clip is {info.width}x{info.height}",
                "draw the scribbles at the clip's resolution",
            )
        out[i] = resize_labels(labels_from_rgba(image), size, len(C.SCRIBBLE_COLOURS))
        used += 1
    if used == 0 or not (out != NO_LABEL).any():
        raise NoScribbles(
            path,
            "no scribbles for the selected frames",
            "scribble at least one frame in pure red and green (file named with the frame number)",
        )
    return out


def propagate_labels(labels: np.ndarray, flow: FlowField | None, inside: np.ndarray) -> np.ndarray:
    """Carry the scribbles of the scribbled frames to every frame along the (consistent) optical flow.

    Each labelled pixel moves with the flow, frame to frame, forwards and backwards, and is dropped where
    the flow is unreliable or it leaves the object (``inside``, bool [T, H, W]). Scribbles drawn on a frame
    replace what arrives there. The result seeds each part's initial motion: one or two scribbled frames
    are enough for the fast model's per-frame similarity fit, which needs points in every frame.
    """
    t_count, h, w = labels.shape
    out = labels.copy()
    if flow is None or t_count < 2:
        return out
    for step in (1, -1):
        frames = range(t_count - 1) if step == 1 else range(t_count - 1, 0, -1)
        carried = np.full((h, w), NO_LABEL, dtype=np.int8)
        for t in frames:
            cur = np.where(labels[t] != NO_LABEL, labels[t], carried)
            out[t] = np.where(out[t] != NO_LABEL, out[t], cur)
            vec, ok = (
                (flow.forward[t], flow.forward_ok[t]) if step == 1 else (flow.backward[t - 1], flow.backward_ok[t - 1])
            )
            ys, xs = np.nonzero((cur != NO_LABEL) & ok)
            tx = np.rint(xs + vec[ys, xs, 0]).astype(int)
            ty = np.rint(ys + vec[ys, xs, 1]).astype(int)
            keep = (tx >= 0) & (tx < w) & (ty >= 0) & (ty < h)
            carried = np.full((h, w), NO_LABEL, dtype=np.int8)
            tx, ty, lab = tx[keep], ty[keep], cur[ys[keep], xs[keep]]
            nxt = t + step
            on_object = inside[nxt, ty, tx]
            carried[ty[on_object], tx[on_object]] = lab[on_object]
        last = t_count - 1 if step == 1 else 0
        cur = np.where(labels[last] != NO_LABEL, labels[last], carried)
        out[last] = np.where(out[last] != NO_LABEL, out[last], cur)
    return out


def scribble_layers(labels: np.ndarray) -> int:
    """Foreground layers the scribbles ask for: the highest colour index used, plus one."""
    return int(labels.max()) + 1


__all__ = [
    "NO_LABEL",
    "SCRIBBLE_EXTENSIONS",
    "NoScribbles",
    "labels_from_rgba",
    "propagate_labels",
    "read_scribbles",
    "resize_labels",
    "scribble_layers",
]
