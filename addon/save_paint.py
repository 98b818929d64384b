"""Save (Ctrl+S, Save As, Save Copy) writes the paint too: the edit layers and the frame paint with unsaved strokes are
saved to their files in the run folder before the .blend is written, so a saved .blend never stands beside paint
that only lives in memory (Blender itself saves images only when asked, or in its quit dialog).

The handler runs before the one that rebases the add-on's paths onto the file being written (``blend_paths``): the
images' paths are still those of the open file, which is what they resolve against. A paint that cannot be saved (a
run folder in use, a full disk, an image with no file) leaves the .blend's save alone: the paint stays unsaved in
Blender, its line is printed, and Save Edits or Blender's quit dialog still offer it.
"""

from __future__ import annotations

import sys
from typing import Any

import bpy

from ..engine import contract as C
from . import edit_layers
from .core import tree_plan as P


def _save_frame_paint() -> list[str]:
    """The frame paint's unsaved strokes to its file (``RUN/edits/frames/frame.NNNNN.png``)."""
    from .ops import frame_paint

    img = bpy.data.images.get(P.FRAME_PAINT_IMAGE)
    if img is None or not img.is_dirty or not img.filepath or img.source != "FILE":
        return []
    return [frame_paint.save_frame_paint(img)]


@bpy.app.handlers.persistent
def save_paint_with_file(*_args: Any) -> None:
    """``save_pre``: every edit layer and the frame paint with unsaved strokes written to its file."""
    try:
        saved = edit_layers.save_edits() + _save_frame_paint()
    except (ValueError, OSError, RuntimeError, C.RunLocked) as exc:
        print(f"Neural Atlas: the paint was not saved with the .blend: {exc}", file=sys.stderr)
        return
    if saved:
        print(f"Neural Atlas: saved the paint of {len(saved)} image(s) with the .blend", file=sys.stderr)


def register() -> None:
    """First among the save handlers: before any that changes the images' paths for the file being written."""
    if save_paint_with_file not in bpy.app.handlers.save_pre:
        bpy.app.handlers.save_pre.insert(0, save_paint_with_file)


def unregister() -> None:
    handlers = bpy.app.handlers.save_pre
    for h in [h for h in handlers if getattr(h, "__name__", "") == save_paint_with_file.__name__]:
        handlers.remove(h)
