"""Paint on a plate frame: where the paint of frame N lives, which frames take it, when it is refused. No bpy here.

The artist paints over plate frame N in the image ``tree_plan.FRAME_PAINT_IMAGE`` (plate-sized RGBA, transparent
where unpainted); ``engine project-frame`` lands that paint on the atlases of the layers that own each pixel. The
paint is a file in the run folder, beside the edit layers and in their encoding (8-bit sRGB, straight alpha):

    RUN/edits/frames/frame.01002.png                     the paint of plate frame 1002, until it is landed
    RUN/edits/frames/landed/frame.01002.<stamp>.png      that paint once landed (kept, never deleted)

Scene frame F shows plate frame F (the import numbers the scene as the plate: ``core.frames``), so the frame
painted is the scene's current frame, which must be one the export has passes for.
"""

from __future__ import annotations

import datetime
import os
from collections.abc import Sequence
from typing import Any

from ...engine import contract as C  # type: ignore[import-not-found]
from . import engine_commands as EC
from .needs import NO_IMPORT

#: The folder beside the edit layers that holds the frame paints.
FRAMES_DIR = "frames"
#: The folder inside it that keeps each frame paint once landed on the atlases.
LANDED_DIR = "landed"
#: The frame paint file of plate frame N (the passes' five-digit numbering).
FILE_FORMAT = "frame.{:05d}.png"
#: The image's custom property holding the plate frame it was painted on.
FRAME_PROP = "neural_atlas_frame"
#: What the two operators are called in their lines.
START_LABEL = "Paint on Frame"
LAND_LABEL = "Land Paint on Atlases"

#: Land with no frame paint started (the poll's line).
NO_FRAME_PAINT = f"Nothing to land: press {START_LABEL} at the frame to paint on first"
#: Land with a frame paint that holds no paint (the poll's line, and execute's).
EMPTY_PAINT = "Nothing to land: the frame paint of frame {frame} is empty (paint over the plate first)"


def frames_dir(manifest_path: str, manifest: dict[str, Any]) -> str:
    """``edits/frames`` beside the run's edit layers (the first layer's folder, checked as a write path: paint
    never goes outside the run folder)."""
    layers = manifest.get("layers") or []
    if not layers:
        raise ValueError(f"{manifest_path}: the export has no layers — export the run again")
    edit = C.resolve_manifest_write_path(manifest_path, layers[0]["edit_layer"])
    return os.path.join(os.path.dirname(os.path.normpath(edit)), FRAMES_DIR)


def paint_file(folder: str, frame: int) -> str:
    """The frame paint of plate frame ``frame`` in ``folder`` (``frames_dir``)."""
    return os.path.join(folder, FILE_FORMAT.format(frame))


def landed_file(path: str, stamp: str | None = None) -> str:
    """Where the frame paint ``path`` is kept once landed: ``landed/frame.01002.<stamp>.png`` beside it (a new
    name each time: a frame painted and landed twice keeps both)."""
    stamp = stamp or datetime.datetime.now().strftime("%Y%m%d-%H%M%S-%f")
    folder, name = os.path.split(path)
    stem, ext = os.path.splitext(name)
    return os.path.join(folder, LANDED_DIR, f"{stem}.{stamp}{ext}")


def frame_refusal(frame: int, exported: Sequence[int]) -> str | None:
    """The one line a frame without passes is refused with (None: the export has passes for it)."""
    if frame in exported:
        return None
    if not exported:
        return "The imported export has no passes: export the run again"
    return (
        f"Frame {frame} has no passes in the imported export (frames {min(exported)}-{max(exported)}): "
        "go to a frame inside it"
    )


def start_need(manifest: str) -> str | None:
    """Paint on Frame: an imported export (its passes give the frame's UVs)."""
    return None if manifest else NO_IMPORT


def land_need(manifest: str, frame: int | None, painted: bool) -> str | None:
    """Land Paint on Atlases: an import, a frame paint (``frame``: the plate frame it was started on, None when
    there is none) and some paint in it."""
    if not manifest:
        return NO_IMPORT
    if frame is None:
        return NO_FRAME_PAINT
    if not painted:
        return EMPTY_PAINT.format(frame=frame)
    return None


def has_paint(alpha_max: float) -> bool:
    """Whether a frame paint whose largest alpha is ``alpha_max`` holds paint (an 8-bit alpha of 1/255 counts)."""
    return alpha_max > 0.5 / 255


def painted_answer_holds(painted: bool, was_unsaved: bool, unsaved: bool, age: float, max_age: float) -> bool:
    """Whether an earlier answer to "does the frame paint hold paint" (``painted``, given ``age`` seconds ago when
    the image was ``was_unsaved``) still holds now that it is ``unsaved``: a "yes" holds (a brush only adds paint;
    Paint on Frame and Land forget the answer); a "no" holds while the image is as it was: saved both times (no stroke
    since), or unsaved both times and at most ``max_age`` old (a later stroke shows within that)."""
    if painted:
        return True
    if was_unsaved != unsaved:
        return False  # a stroke since (or a save): read the pixels again
    return not unsaved or age <= max_age


def project_frame_argv(python: str, manifest: str, frame: int, paint: str) -> list[str]:
    """``engine project-frame MANIFEST --frame N --edit PAINT``: the paint lands on every layer that owns it."""
    return EC.engine_argv(python, C.VERB_PROJECT_FRAME, manifest, "--frame", str(frame), "--edit", paint)


def log_file(manifest_path: str) -> str:
    """The add-on's log of the projections into a run: ``RUN.frame-paint.log`` beside the run folder (as the fit's
    ``RUN.blender.log``, ``core.run_files``)."""
    return C.manifest_run_root(manifest_path) + ".frame-paint.log"


#: How ``project-frame`` says on stderr where the paint of a layer landed ("Foreground: paint landed in PATH").
LANDED_MARK = ": paint landed in "


def landed_layers(stderr_lines: Sequence[str]) -> dict[str, str]:
    """Layer -> the edit layer file ``project-frame`` landed its paint in, from its stderr lines."""
    out = {}
    for line in stderr_lines:
        name, mark, path = line.strip().partition(LANDED_MARK)
        if mark and name and path:
            out[name] = path
    return out
