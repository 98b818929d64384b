"""Rasterize the Movie Clip Editor's annotation strokes into the engine's scribble images (paper Sec. 4.4).

The artist draws on the clip with the Annotate tool, one annotation layer per colour (red marks the first
part, green the second, ...: ``engine.contract.SCRIBBLE_COLOURS``), on one or a few frames. Only the
frames that hold an annotation keyframe are written (the engine accepts sparse frames).

Versions: 4.5 keeps the clip's annotations in ``clip.grease_pencil`` (legacy GreasePencil), 5.0 in
``clip.annotation`` (Annotation); layers, frames, strokes and points read the same on both. An
annotation keyframe's ``frame_number`` is the SCENE frame (measured: clip starting at 2, scene frame 3
-> 3). ``frame.strokes`` has no ``new``, but the Annotate operator run in a Movie Clip Editor area with a
``stroke`` list draws a real stroke on both versions; headless its points are NaN (the editor's
stabilisation matrix exists only once it has drawn) and ``point.co`` is writable, which is how
tests/addon/test_scribble_fit.py builds real strokes. The layer's ``thickness`` is in screen pixels; it
is taken as the stroke's width in frame pixels.
"""

from __future__ import annotations

import os
from typing import Any

from ..engine import contract as C
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


#: Annotation thickness (screen pixels, taken as frame pixels) of the layers the add-on creates: a stroke
#: 6 px wide marks a part clearly without bleeding over a thin limb's edges.
SCRIBBLE_THICKNESS = 6


def ensure_scribble_layers(clip: Any, parts: int, new_annotation: Any) -> list[str]:
    """Give ``clip`` one annotation layer per part in the code colours ("Part 1 (red)", ...), keeping any
    layer that already has a part's colour; the first part's layer becomes the active one (the Annotate
    tool draws on it). ``new_annotation(name)`` makes the datablock when the clip has none (4.5:
    ``bpy.data.grease_pencils.new``, 5.0: ``bpy.data.annotations.new``). Returns the names of the layers
    the parts are drawn on."""
    annotation = clip_annotation(clip)
    if annotation is None:
        annotation = new_annotation(f"{clip.name} scribbles")
        setattr(clip, "annotation" if hasattr(clip, "annotation") else "grease_pencil", annotation)
    existing = {}
    for layer in annotation.layers:
        label = S.layer_label(tuple(layer.color))
        if label is not None and label not in existing:
            existing[label] = layer.info
    names = []
    for k, (colour, _) in enumerate(legend()[:parts]):
        if k not in existing:
            layer = annotation.layers.new(f"Part {k + 1} ({colour})")
            layer.color = tuple(c / 255.0 for c in C.SCRIBBLE_COLOURS[k])
            layer.thickness = SCRIBBLE_THICKNESS
            existing[k] = layer.info
        names.append(existing[k])
    annotation.layers.active_note = names[0]
    return names


def scribble_labels(annotation: Any, frames: Any = None) -> set[int]:
    """The colour indices (0 = red, 1 = green, ...) that have strokes, on ``frames`` only when given."""
    labels: set[int] = set()
    if annotation is None:
        return labels
    wanted = None if frames is None else set(frames)
    for layer in annotation.layers:
        label = S.layer_label(tuple(layer.color))
        if getattr(layer, "annotation_hide", False) or label is None:
            continue
        if any(len(f.strokes) and (wanted is None or f.frame_number in wanted) for f in layer.frames):
            labels.add(label)
    return labels


def write_scribbles(clip: Any, out_dir: str, width: int, height: int, file_name: Any, frames: Any = None) -> list[str]:
    """Write one PNG per scribbled frame into ``out_dir``; ``file_name(scene_frame)`` names it (the plate's
    file number, like masks: ``mask_math.mask_file_names``). ``frames``: only these scene frames (the fitted
    range; a scribble outside it would name a frame the engine does not read). Returns the paths (empty:
    nothing scribbled)."""
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


def clear_scribbles(out_dir: str) -> None:
    """Remove the scribble PNGs a previous fit wrote into the add-on's own ``out_dir`` (a frame whose strokes
    the artist has since erased must not keep its old scribble). Only numbered ``.png`` files are touched."""
    if not os.path.isdir(out_dir):
        return
    for name in os.listdir(out_dir):
        stem, ext = os.path.splitext(name)
        if ext.lower() == ".png" and stem.isdigit():
            os.remove(os.path.join(out_dir, name))


def legend() -> list[tuple[str, str]]:
    """(colour name, what it marks) for the panel, from the engine's colour code."""
    names = {(255, 0, 0): "red", (0, 255, 0): "green", (0, 0, 255): "blue", (255, 255, 0): "yellow"}
    out = []
    for k, rgb in enumerate(C.SCRIBBLE_COLOURS):
        out.append((names.get(tuple(rgb), "#{:02x}{:02x}{:02x}".format(*rgb)), f"part {k + 1} (Foreground{k + 1})"))
    return out
