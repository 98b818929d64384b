"""Unsaved paint before the edit layers are reloaded: whether it can be saved to its file first. No bpy here.

Import Atlas, the import that ends a Fit, and Float Edit Layers reload (or replace) the edit images, which drops any
paint Blender has not written to a file. So every one of them saves that paint first, as Save Edits does; an image
whose paint has no file to go to (packed into the .blend, or made in Blender) makes the action refuse instead, with
one line, and nothing is reloaded.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import NamedTuple


class EditImage(NamedTuple):
    """What the decision needs of one edit image with unsaved paint (read from Blender by the caller)."""

    name: str
    filepath: str
    packed: bool
    generated: bool


def refusal(action: str, dirty: Iterable[EditImage]) -> str | None:
    """The one line ``action`` refuses with when some unsaved paint cannot be saved to its file first (None: every
    painted image has a file to save to). Short: Blender quotes at most 200 characters of an operator's line."""
    for img in dirty:
        if img.packed:
            why = "it is packed in the .blend"
        elif img.generated or not img.filepath:
            why = "it has no file"
        else:
            continue
        return (
            f"{action} would drop the unsaved paint of {img.name} ({why}): "
            "unpack it or Save As into the run's edits folder, then try again"
        )
    return None
