"""Rasterize the Movie Clip Editor's annotation strokes into the engine's scribble images (paper Sec. 4.4).

The artist draws on the clip with the Annotate tool, one annotation layer per colour (red marks the first
part, green the second, ...: ``engine.contract.SCRIBBLE_COLOURS``), on one or a few frames. Only the
frames that hold an annotation keyframe are written (the engine accepts sparse frames).

Versions: 4.5 keeps the clip's annotations in ``clip.grease_pencil`` (legacy GreasePencil), 5.0 in
``clip.annotation`` (Annotation); layers, frames, strokes and points read the same on both. Neither
version can create strokes from Python (``frame.strokes`` has no ``new``), so the stroke reading is
tested on stand-in objects and the datablock access on real ones (tests/addon/test_scribbles.py).
The layer's ``thickness`` is in screen pixels; it is taken as the stroke's width in frame pixels.
"""

from __future__ import annotations

import os
from typing import Any

from . import scribble_math as S


def clip_annotation(clip: Any) -> Any | None:
    """The clip's annotation datablock, or None (a feature check, not a version check)."""
    for attr in ("annotation", "grease_pencil"):
        if hasattr(clip, attr):
            return getattr(clip, attr)
    return None


def frame_strokes(annotation: Any, frame: int, width: int, height: int) -> list[S.Stroke]:
    """Strokes drawn ON ``frame`` (an annotation keyframe there) of every visible code-coloured layer."""
    out: list[S.Stroke] = []
    if annotation is None:
        return out
    for layer in annotation.layers:
        if getattr(layer, "annotation_hide", False):
            continue
        label = S.layer_label(tuple(layer.color))
        if label is None:
            continue
        for gp_frame in layer.frames:
            if gp_frame.frame_number != frame:
                continue
            for stroke in gp_frame.strokes:
                pts = [(p.co[0], p.co[1]) for p in stroke.points]
                if pts:
                    out.append(S.Stroke(label, float(layer.thickness) / 2.0, S.to_pixels(pts, width, height)))
    return out


def scribbled_frames(annotation: Any) -> list[int]:
    """Frames with at least one stroke on a code-coloured layer, sorted."""
    frames: set[int] = set()
    if annotation is None:
        return []
    for layer in annotation.layers:
        if getattr(layer, "annotation_hide", False) or S.layer_label(tuple(layer.color)) is None:
            continue
        frames |= {f.frame_number for f in layer.frames if len(f.strokes)}
    return sorted(frames)


def write_scribbles(clip: Any, out_dir: str, width: int, height: int, file_name: Any) -> list[str]:
    """Write one PNG per scribbled frame into ``out_dir``; ``file_name(scene_frame)`` names it (the plate's
    file number, like masks: ``mask_math.mask_file_names``). Returns the paths (empty: nothing scribbled)."""
    annotation = clip_annotation(clip)
    paths = []
    for frame in scribbled_frames(annotation):
        rows = S.rasterize(frame_strokes(annotation, frame, width, height), width, height)
        os.makedirs(out_dir, exist_ok=True)
        path = os.path.join(out_dir, file_name(frame))
        with open(path, "wb") as f:
            f.write(S.encode_png(rows))
        paths.append(path)
    return paths
