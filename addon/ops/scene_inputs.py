"""What the engine operators read from the scene: the engine Python, the Run Folder, the clip and its frame
range, and each foreground layer's masks (rasterised from a Mask datablock, or a folder of images), plus the
clip's scribbles for a fit that splits one object; for Submit to Farm, the same as one shot of a shots file."""

from __future__ import annotations

import os
from typing import Any

import bpy

from .. import masks, preferences, scribbles
from ..core import engine_commands as EC
from ..core import farm as FM
from ..core import frames as F
from ..core import scribble_math as S
from ..core.errors import UserError
from ..core.run_files import RunFiles, clear_numbered_pngs


def abspath(path: str) -> str:
    """A path as the artist typed it (``//`` is the .blend's folder), absolute and normalised; '' stays ''."""
    return os.path.normpath(bpy.path.abspath(path)) if path else ""


def engine_python(context: Any) -> str:
    python = preferences.engine_python(context)
    if not python:
        raise UserError("no engine Python: run Set up engine in the add-on's preferences")
    return python


def run_dir(props: Any) -> str:
    if not props.run_dir:
        raise UserError("choose a Run Folder")
    if props.run_dir.startswith("//") and not bpy.data.filepath:
        raise UserError("save the .blend file first (the Run Folder is relative to it), or choose an absolute one")
    return abspath(props.run_dir).rstrip(os.sep)


def clip_plate(clip: Any) -> tuple[str, int | None]:
    """(what the engine reads: a sequence's pattern or the movie file, the first file's number or None)."""
    path = abspath(clip.filepath)
    if clip.source == "SEQUENCE":
        return F.sequence_pattern(path), F.file_number(path)
    return path, None


def clip_range(props: Any) -> tuple[int, int]:
    """The scene frames to fit (first, last)."""
    clip = props.clip
    return F.frame_range(
        clip.frame_start, clip.frame_duration, props.frame_start, props.frame_end, props.use_clip_range
    )


def _scribbles(clip: Any, folder: str, frames: list[int], first_number: int | None) -> str:
    """Rasterise the clip's code-coloured annotation strokes on ``frames`` into ``folder``; returns it."""
    colours = ", ".join(f"part {i + 1} in {name}" for i, (name, _) in enumerate(S.legend()[:2]))
    labels = scribbles.scribble_labels(scribbles.clip_annotation(clip), frames)
    if not labels:
        raise UserError(
            f"Split with Scribbles: clip {clip.name!r} has no annotation strokes in the scribble colours on "
            f"frames {frames[0]}-{frames[-1]}: with the Annotate tool draw {colours}"
        )
    if max(labels) < 1:
        raise UserError("Split with Scribbles: only red strokes, so nothing is split: scribble the other part in green")
    clear_numbered_pngs(folder)

    def name(frame: int) -> str:
        return F.scribble_file_name(frame, first_number, clip.frame_start)

    width, height = clip.size
    scribbles.write_scribbles(clip, folder, width, height, name, frames)
    return folder


def _require_one_layer(props: Any) -> None:
    """Split with Scribbles splits one object: a UserError unless there is exactly one foreground layer."""
    if len(props.layers) != 1:
        raise UserError(
            "Split with Scribbles splits one object: keep exactly one foreground layer (the whole object's mask), not "
            f"{len(props.layers)}, or turn Split with Scribbles off"
        )


def clip_inputs(props: Any, files: RunFiles, with_scribbles: bool = True) -> EC.ClipInputs:
    """The plate, each layer's mask folder (Mask layers rasterised now), the frames and (with
    ``props.use_scribbles``) the rasterised scribbles; Find Parts off: the engine told not to split the object
    (on, the engine's default: the parts that move apart wherever that applies). ``with_scribbles`` False: no
    scribbles, and the split left to the engine (the estimate's and the farm's inputs)."""
    clip = props.clip
    if clip is None:
        raise UserError("choose the clip to fit")
    if not props.layers:
        raise UserError("add a foreground layer (a Mask or a folder of mask images)")
    scribbled = with_scribbles and props.use_scribbles
    if scribbled:
        _require_one_layer(props)
    find_parts = props.find_parts or not with_scribbles
    plate, first_number = clip_plate(clip)
    first, last = clip_range(props)
    frames = list(range(first, last + 1))
    scribble_dir = _scribbles(clip, files.scribbles, frames, first_number) if scribbled else None
    width, height = clip.size
    names = F.mask_file_names(frames, first_number, clip.frame_start)
    folders = []
    for i, layer in enumerate(props.layers, start=1):
        if layer.source == "MASK":
            if layer.mask is None:
                raise UserError(f"layer {i} has no Mask")
            folder = files.layer_masks(i)
            masks.rasterize(layer.mask, width, height, frames, folder, names)
        else:
            folder = abspath(layer.folder)
            if not os.path.isdir(folder):
                raise UserError(f"layer {i}: mask folder {folder!r} does not exist")
        folders.append(folder)
    numbers = F.plate_numbers(first, last, clip.frame_start, first_number)
    return EC.ClipInputs(plate, tuple(folders), *numbers, scribble_dir, auto_parts=find_parts)


def sets(props: Any) -> list[str]:
    """The engine's ``--set`` arguments: the working size and the artist's overrides."""
    return EC.set_args(props.long_edge, props.overrides)


def farm_shot(props: Any, files: RunFiles) -> FM.FarmShot:
    """The clip as one farm shot, read as Fit Atlas reads it: the same plate, the same frames (the plate's numbers),
    Mask layers rasterised into the same folders, the same preset and overrides, the same Run Folder. No foreground
    layer: the farm finds the moving objects first (``auto_masks``); Find Parts off: the shot's ``auto_parts`` false
    (on: left to the fit's default)."""
    clip = props.clip
    if clip is None:
        raise UserError("choose the clip to submit")
    if props.use_scribbles:
        raise UserError(
            "Submit to Farm: Split with Scribbles is fitted here only (Fit Atlas): turn it off to submit the clip"
        )
    if props.layers:
        inputs = clip_inputs(props, files, with_scribbles=False)
        plate, masks, first, last = inputs.plate, inputs.masks, inputs.first, inputs.last
    else:
        plate, first_number = clip_plate(clip)
        masks = ()
        first, last = F.plate_numbers(*clip_range(props), clip.frame_start, first_number)
    return FM.FarmShot(
        name=FM.shot_name(clip.name, clip.source == "SEQUENCE"),
        plate=plate,
        masks=masks,
        first=first,
        last=last,
        preset=props.preset,
        sets=FM.set_items(props.long_edge, props.overrides),
        run_dir=files.run_dir,
        colorspace=FM.engine_colorspace(clip.colorspace_settings.name),
        follow_flow=props.follow_flow,
        auto_parts=props.find_parts,
    )
