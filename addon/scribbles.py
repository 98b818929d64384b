"""Read the Movie Clip Editor's annotation strokes as scribbles, and write the engine's scribble images (paper
Sec. 4.4).

The artist draws on the clip with the Annotate tool, one annotation layer per colour (red marks the first
part, green the second, ...: ``engine.contract.SCRIBBLE_COLOURS``), on one or a few frames. Only the
frames that hold an annotation keyframe are written (the engine accepts sparse frames).

The clip's annotation datablock is ``compat.clip_annotation``'s (it moved between versions); layers, frames,
strokes and points read the same on every version, so the reading here only walks them (and is tested on
stand-ins shaped like them). An annotation keyframe's ``frame_number`` is the SCENE frame. The layer's
``thickness`` is in screen pixels; it is taken as the stroke's width in frame pixels. How real strokes are
drawn headless for the tests: docs/blender-compat.md.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from ..engine import contract as C
from .compat import clip_annotation, new_clip_annotation
from .core import scribble_math as S

#: Annotation thickness (screen pixels, taken as frame pixels) of the layers the add-on creates: a stroke
#: this wide marks a part clearly without bleeding over a thin limb's edges.
SCRIBBLE_THICKNESS = 6


def _code_layers(annotation: Any) -> Iterator[tuple[int, Any]]:
    """(label, layer) for every visible annotation layer in a code colour."""
    if annotation is None:
        return
    for layer in annotation.layers:
        label = S.layer_label(tuple(layer.color))
        if label is not None and not layer.annotation_hide:
            yield label, layer


def frame_strokes(annotation: Any, frame: int, width: int, height: int) -> list[S.Stroke]:
    """Strokes drawn ON ``frame`` (an annotation keyframe there) of every visible code-coloured layer."""
    out: list[S.Stroke] = []
    for label, layer in _code_layers(annotation):
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
    for _label, layer in _code_layers(annotation):
        frames |= {f.frame_number for f in layer.frames if len(f.strokes)}
    return sorted(frames)


def ensure_scribble_layers(clip: Any, parts: int) -> list[str]:
    """Give ``clip`` one annotation layer per part in the code colours ("Part 1 (red)", ...), keeping any
    layer that already has a part's colour; the first part's layer becomes the active one (the Annotate
    tool draws on it). Returns the names of the layers the parts are drawn on."""
    annotation = clip_annotation(clip)
    if annotation is None:
        annotation = new_clip_annotation(clip, f"{clip.name} scribbles")
    existing = {}
    for layer in annotation.layers:
        label = S.layer_label(tuple(layer.color))
        if label is not None and label not in existing:
            existing[label] = layer.info
    names = []
    for k, (colour, _) in enumerate(S.legend()[:parts]):
        if k not in existing:
            layer = annotation.layers.new(f"Part {k + 1} ({colour})")
            layer.color = tuple(c / 255.0 for c in C.SCRIBBLE_COLOURS[k])
            layer.thickness = SCRIBBLE_THICKNESS
            existing[k] = layer.info
        names.append(existing[k])
    annotation.layers.active_note = names[0]
    return names


def scribble_labels(annotation: Any, frames: Iterable[int] | None = None) -> set[int]:
    """The colour indices (0 = red, 1 = green, ...) that have strokes, on ``frames`` only when given."""
    wanted = None if frames is None else set(frames)
    return {
        label
        for label, layer in _code_layers(annotation)
        if any(len(f.strokes) and (wanted is None or f.frame_number in wanted) for f in layer.frames)
    }


def write_scribbles(
    clip: Any,
    out_dir: str,
    width: int,
    height: int,
    file_name: Callable[[int], str],
    frames: Iterable[int] | None = None,
) -> list[str]:
    """Write one PNG per scribbled frame into ``out_dir``; ``file_name(scene_frame)`` names it (the plate's
    file number, like masks: ``core.frames.scribble_file_name``). ``frames``: only these scene frames (the
    fitted range; a scribble outside it would name a frame the engine does not read). Returns the paths
    (empty: nothing scribbled)."""
    annotation = clip_annotation(clip)
    wanted = None if frames is None else set(frames)
    paths = []
    for frame in scribbled_frames(annotation):
        if wanted is not None and frame not in wanted:
            continue
        rows = S.rasterize(frame_strokes(annotation, frame, width, height), width, height)
        os.makedirs(out_dir, exist_ok=True)
        path = os.path.join(out_dir, file_name(frame))
        with open(path, "wb") as f:
            f.write(S.encode_png(rows))
        paths.append(path)
    return paths
