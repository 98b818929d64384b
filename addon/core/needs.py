"""What each operator needs before it can do anything, and the one line that says what is missing. No bpy here.

An operator's ``poll`` reads the scene into plain values and asks the function here; ``None`` means ready.
Blender greys out a button whose poll fails and shows the line as its tooltip (``poll_message_set``); a script
that calls the operator anyway gets the line in its ``RuntimeError``. So no button reports FINISHED having done
nothing. Blender quotes at most 200 characters of the line in that error: the lines stay short, a path last.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from typing import Any

from ...engine import contract as C  # type: ignore[import-not-found]

#: Without an imported export (Import Atlas, or a finished Fit Atlas, imports one).
NO_IMPORT = "Import an atlas first (Import Atlas, or Fit Atlas, which imports its result)"
#: An imported export whose manifest has gone (moved or deleted since the import).
MANIFEST_GONE = "The imported manifest is gone: Relink Run Folder (Paint & Render panel) or put it back: "
#: An import without its passes image (removed from the file since).
NO_PASSES = "The imported atlas has no passes image: import the atlas again"
#: An import whose passes are not on disk (the run folder moved or was cleaned).
PASSES_GONE = "The passes are not on disk: Relink Run Folder (Paint & Render panel) or put it back: "
#: An edit layer file not on disk (deleted, or the run folder moved): the render would be the bare plate.
EDIT_GONE = "An edit layer is not on disk: put it back, or Relink Run Folder: "
#: An atlas image not on disk: the canvases and the preview would show nothing under the paint.
ATLAS_GONE = "An atlas is not on disk: Relink Run Folder, or put it back: "
#: The imported plate clip without its file: the render would be black.
PLATE_GONE = "The plate is not on disk (preview and render would be black): put it back, or Relink Run Folder to it: "
#: An import without its plate clip (removed from the file since).
NO_PLATE = "The imported atlas has no plate clip: import the atlas again"
#: Fit Atlas on a Run Folder that holds a fit (greyed in the panel; the fit would refuse to overwrite it).
USED_RUN_FOLDER = "This Run Folder holds a fit: Resume or Refine it, or choose a new Run Folder to fit again"
#: Save Edits with nothing painted since the last save.
NOTHING_TO_SAVE = "Nothing to save: every edit layer is saved (paint first)"
#: Float Edit Layers when every imported edit layer is a float EXR already.
ALL_FLOAT = "Every edit layer is a float EXR already"
#: Cancel with no job.
NOTHING_RUNNING = "No engine job is running for this scene"
#: Cancel Set up engine with none running.
SETUP_NOT_RUNNING = "Set up engine is not running"
#: Remove Layer with no layer.
NO_LAYER = "No foreground layer to remove"
#: Add Scribble Layers without a clip.
NO_CLIP = "Choose the clip to scribble on"
#: Fit Atlas, Find Masks and Estimate Time without a clip.
NO_FIT_CLIP = "Choose the clip to fit in the Fit Atlas panel"
NO_MASKS_CLIP = "Choose the clip to find masks in, in the Fit Atlas panel"
NO_ESTIMATE_CLIP = "Choose the clip to time in the Fit Atlas panel"

#: Refine with a Run Folder that holds no finished fit.
NO_FINISHED_FIT = "The Run Folder holds no finished fit to refine (Fit Atlas first, or Resume it)"


def refine_need(is_running: bool, finished_fit: bool) -> str | None:
    """Refine continues the Run Folder's finished fit, one engine job at a time."""
    if is_running:
        return "An engine job is running for this scene: wait for it or Cancel it"
    return None if finished_fit else NO_FINISHED_FIT


def render_need(
    manifest: str,
    passes_file: str | None,
    exists: Callable[[str], bool] = os.path.isfile,
    edit_files: Iterable[str] = (),
    plate_file: str | None = "",
    atlas_files: Iterable[str] = (),
) -> str | None:
    """Render Edited Clip: an imported export (``manifest``: the scene's, '' when none) whose passes exist
    (``passes_file``: the passes image's first file, None when the image is gone) and whose edit layers exist
    (``edit_files``: the file of each edit image the tree shows; a missing one would render as nothing, so the
    result would silently be the bare plate), its atlases (``atlas_files``) and its plate (``plate_file``: the plate
    clip's file, None when the clip is gone, '' not checked; a missing one renders black). ``exists`` is the file
    test (poll runs on every redraw: a few stats, never the manifest read)."""
    line = moved_need(manifest, passes_file, exists)
    if line:
        return line
    for path in edit_files:
        if not exists(path):
            return EDIT_GONE + path
    for path in atlas_files:
        if not exists(path):
            return ATLAS_GONE + path
    if plate_file is None:
        return NO_PLATE
    if plate_file and not exists(plate_file):
        return PLATE_GONE + plate_file
    return None


def moved_need(
    manifest: str,
    passes_file: str | None,
    exists: Callable[[str], bool] = os.path.isfile,
    plate_file: str | None = "",
) -> str | None:
    """An import whose manifest, passes and plate (``plate_file``: the plate clip's file, '' or None not checked here)
    are on disk (None), else the line saying what is gone: the panel shows it above Relink Run Folder (a run folder
    or plate moved since the import); Render, Live Preview and Paint on Frame refuse with it."""
    if not manifest:
        return NO_IMPORT
    if not exists(manifest):
        return MANIFEST_GONE + manifest
    if passes_file is None:
        return NO_PASSES
    if not exists(passes_file):
        return PASSES_GONE + passes_file
    if plate_file and not exists(plate_file):
        return PLATE_GONE + plate_file
    return None


def relink_need(manifest: str) -> str | None:
    """Relink Run Folder: an import to relink (its manifest may be gone: that is what Relink is for)."""
    return None if manifest else NO_IMPORT


def clip_need(has_clip: bool, line: str = NO_FIT_CLIP) -> str | None:
    """Fit Atlas, Find Masks, Estimate Time: the panel's clip (``line``: what the button says without one)."""
    return None if has_clip else line


#: Carry Paint without a fit to take the paint from.
NO_CARRY_SOURCE = "Choose Paint From: another fit of this plate (its run folder or manifest.json)"


def carry_need(manifest: str, source: str) -> str | None:
    """Carry Paint: an import to carry onto, and another fit to carry from."""
    if not manifest:
        return NO_IMPORT
    return None if source else NO_CARRY_SOURCE


def save_edits_need(edit_layers: int, unsaved: int) -> str | None:
    """Save Edits: edit layers loaded (``edit_layers``: how many) and paint not yet saved in ``unsaved`` of them."""
    if edit_layers == 0:
        return NO_IMPORT
    if unsaved == 0:
        return NOTHING_TO_SAVE
    return None


def float_edits_need(manifest: str, edit_paths: Iterable[str]) -> str | None:
    """Float Edit Layers: an import with at least one edit layer (``edit_paths``: each loaded edit image's file) that
    is not a float EXR yet. A layer that shows another image than the run's counts: the operator says it skipped it."""
    paths = list(edit_paths)
    if not manifest or not paths:
        return NO_IMPORT
    if all(p.lower().endswith(C.EDIT_LAYER_FLOAT_EXT) for p in paths):
        return ALL_FLOAT
    return None


def paint_setup_need(edit_layers: int) -> str | None:
    """Paint Canvases: edit layers to make canvases for."""
    return NO_IMPORT if edit_layers == 0 else None


def cancel_need(is_running: bool, not_running: str = NOTHING_RUNNING) -> str | None:
    """Cancel: a job running for what the button cancels."""
    return None if is_running else not_running


def layer_remove_need(layers: int) -> str | None:
    """Remove Layer: a layer to remove."""
    return NO_LAYER if layers == 0 else None


def scribble_layers_need(has_clip: bool) -> str | None:
    """Add Scribble Layers: the clip the annotation layers go on."""
    return None if has_clip else NO_CLIP


def esc_text(label: str, where: str) -> str:
    """What ESC says while an engine job runs: ESC also stops playback and leaves modes in every editor, so it
    never ends a job that may have run for an hour; Cancel (``where``) does."""
    return f"{label} keeps running (ESC does not stop it): press Cancel in {where} to stop it"


def poll(cls: Any, need: str | None) -> bool:
    """An operator's poll from its need (None: nothing missing): greyed out, with the line as the button's tooltip
    (``poll_message_set``), when something is missing."""
    if need:
        cls.poll_message_set(need)
    return need is None
