"""``parts``: the strokes that split one masked object into the parts that move apart, written as scribble images.

The clip and the mask are read as ``fit`` reads them (its working size and encoding, as ``masks`` reads a plate;
the outline snapped to the clip's edges), the adjacent flow is computed as ``fit`` computes it, and
``engine.data.motion_parts`` finds the parts. The strokes are written as RGBA PNGs at the clip's resolution, one
per stroked frame, named like the frames, in ``contract.SCRIBBLE_COLOURS`` (Foreground1 red, Foreground2 green,
...): the files ``fit --scribbles`` reads, which an artist can open, check and fix like strokes of their own.
The set is written all or nothing (``mask_files.write_file_set``), never over a file; the same command run again
over its own output leaves it as it is and succeeds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from .. import contract as C
from ..config import FitConfig
from ..errors import InputError
from ..io.clip import ClipInfo, open_clip, read_frames, read_masks, working_size
from ..io.colour import to_working
from .flow import DISFlow, compute_flow
from .mask_files import already_holds, mask_file_names, output_folder, write_file_set
from .mask_snap import snap_masks
from .motion_parts import MotionParts, PartsConfig, motion_parts
from .scribbles import NO_LABEL

#: What the files are, in the one-line refusals of ``mask_files``.
STROKE = "stroke"


class NothingToSplit(InputError):
    """The clip gives the search nothing to split: a single frame, or a mask empty on every selected frame. Refused
    in one line when the split was asked for (``parts``, ``fit --auto-parts``); a fit that splits by default fits
    such a clip as it is (``fit.auto_parts.PartsSearch``)."""


@dataclass
class PartsReport:
    """What ``write_motion_parts`` did, for the CLI's summary: the folder is None when nothing was split."""

    result: MotionParts
    folder: str | None = None
    files: list[str] = field(default_factory=list)
    reused: bool = False
    """The folder held these very strokes already (the same command run before): left as it is."""

    def summary(self) -> list[str]:
        again = " (the folder held these very strokes already: left as they are)" if self.reused else ""
        lines = [f"parts: {self.result.message}{again}"]
        if self.folder is not None:
            lines.append(f"fit with: --mask MASKS --scribbles {self.folder}")
        return lines


def stroke_image(labels: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """uint8 [H, W, 4] BGRA (OpenCV's order) of working-resolution ``labels`` at the clip's ``size`` (W, H): each
    label in its scribble colour, opaque; transparent where there is no stroke. Nearest resizing keeps the colours
    exact, which the scribble reader matches within ``contract.SCRIBBLE_TOLERANCE``."""
    w, h = size
    big = cv2.resize(labels.astype(np.int16), (w, h), interpolation=cv2.INTER_NEAREST)
    out = np.zeros((h, w, 4), np.uint8)
    for k, (r, g, b) in enumerate(C.SCRIBBLE_COLOURS):
        out[big == k] = (b, g, r, 255)
    return out


def _encode(image: np.ndarray, path: Path) -> bytes:
    ok, data = cv2.imencode(".png", image)
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 BGRA array
        raise InputError(path, "could not be encoded as PNG", "check the disk and run again")
    return data.tobytes()


def write_motion_parts(
    clip: str | Path,
    mask: str | Path,
    out: str | Path,
    frame_range: tuple[int, int] | None = None,
    colorspace: str | None = None,
    cfg: PartsConfig | None = None,
    say: Callable[[str], None] | None = None,
) -> PartsReport:
    """Find the parts of the object in ``mask`` (one mask folder) that move apart and write their strokes to
    ``out`` (created). Nothing is written when the object moves as one piece. A file of the same name already there
    is refused, unless every file would be the same (the command run before), which is left as it is. The analysis
    runs at a default fit's working size, mask snap and flow (a fit's own search, ``fit.auto_parts.PartsSearch``,
    uses the fit's)."""
    info = open_clip(clip, frame_range, colorspace)
    require_something_to_split(info, mask, None)
    fit = FitConfig()
    size = working_size(info.width, info.height, fit.long_edge)
    folder = output_folder(info, out, STROKE)
    if say is not None:
        say(f"following the object's parts in {info.num_frames} frames at {size[0]}x{size[1]}")
    frames = to_working(np.nan_to_num(read_frames(info, size), nan=0.0, posinf=1.0, neginf=0.0), info.colorspace,
                        info.colour_config)  # fmt: skip
    frames = np.clip(np.nan_to_num(frames, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0).astype(np.float32)
    masks = read_masks(mask, info, size)
    require_something_to_split(info, mask, masks)
    snapped, _ = snap_masks(frames, masks[None], fit.mask_snap_px)
    flow = compute_flow(frames, DISFlow(fit.flow_preset), None, fit.flow_threshold_px)
    return write_strokes(info, folder, motion_parts(snapped[0], flow, cfg))


def require_something_to_split(info: ClipInfo, mask: str | Path, masks: np.ndarray | None) -> None:
    """``NothingToSplit`` (one line) for a clip of one frame, or a ``mask`` folder whose ``masks`` (bool [T, H, W];
    None: not read yet) are empty on every frame."""
    if info.num_frames < 2:
        raise NothingToSplit(
            info.source, "a single frame has no motion to split the object by", "select at least two frames"
        )
    if masks is not None and not masks.any():
        raise NothingToSplit(mask, "holds no mask pixel on the selected frames", "draw the object's mask first")


def write_strokes(info: ClipInfo, folder: Path, result: MotionParts) -> PartsReport:
    """The strokes of ``result`` written to ``folder`` (resolved by ``output_folder``), one image per stroked frame
    at the clip's resolution, named like its frames; nothing when it found no parts. A file of the same name already
    there is refused, unless every file would be the same, which is left as it is."""
    if not result.found:
        return PartsReport(result)
    names = mask_file_names(info)
    stroked = [t for t in range(info.num_frames) if (result.labels[t] != NO_LABEL).any()]
    images = {names[t]: _encode(stroke_image(result.labels[t], (info.width, info.height)), folder) for t in stroked}
    there = [n for n in images if (folder / n).exists()]
    if there:  # the same command run before left these very strokes: nothing to do; anything else is refused
        if len(there) == len(images) and all((folder / n).read_bytes() == data for n, data in images.items()):
            return PartsReport(result, str(folder), [str(folder / n) for n in images], reused=True)
        raise already_holds(folder, there, STROKE)
    return PartsReport(result, str(folder), write_file_set(folder, images, STROKE))


__all__ = [
    "NothingToSplit",
    "PartsReport",
    "require_something_to_split",
    "stroke_image",
    "write_motion_parts",
    "write_strokes",
]
