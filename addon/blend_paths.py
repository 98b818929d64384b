"""Keep the add-on's paths relative to the .blend across saves (``core.relink`` does the path maths).

Blender itself rebases the ``//`` paths of images and clips when the .blend is saved somewhere else (Save As's
Remap Relative), but not the add-on's settings, and an import into a .blend never saved yet has nothing to be
relative to. So, before each save: the imported manifest (a setting) is written relative to the file being saved;
and on the first save of a .blend the ``NA_`` images and clips and the Run Folder, absolute until then (an import
into a file never saved, as ``headless.py`` makes one), become relative to it (no image is reloaded: unsaved paint
stays). After a Save Copy the open file's own values are put back.
"""

from __future__ import annotations

from typing import Any

import bpy

from .core import relink
from .core import tree_plan as P

#: What the last save changed, to put back after a copy: (kind, name, value before).
_changed: list[tuple[str, str, str]] = []


def _ours(collection: Any) -> list[Any]:
    return [
        b
        for b in collection
        if b.name.startswith(P.PREFIX)
        and b.filepath
        and getattr(b, "packed_file", None) is None
        and b.source != "GENERATED"
    ]


@bpy.app.handlers.persistent
def relative_before_save(filepath: str = "", *_args: Any) -> None:
    """``save_pre``: the paths as they should be in the file being written to ``filepath``."""
    _changed.clear()
    old = bpy.data.filepath
    if not filepath:
        return
    for scene in bpy.data.scenes:
        props = getattr(scene, "neural_atlas", None)
        if props is None or not props.manifest:
            continue
        if props.manifest.startswith(relink.BLEND_PREFIX) and not old:
            continue  # relative to nothing: cannot be resolved
        stored = relink.relative_path(relink.absolute_path(props.manifest, old), filepath)
        if stored != props.manifest:
            _changed.append(("scene", scene.name, props.manifest))
            props.manifest = stored
    if old:
        return  # Blender rebases the datablocks' relative paths itself
    for scene in bpy.data.scenes:
        props = getattr(scene, "neural_atlas", None)
        if props is None or not props.run_dir or props.run_dir.startswith(relink.BLEND_PREFIX):
            continue
        stored = relink.relative_path(props.run_dir.rstrip("/\\"), filepath) + "/"
        if stored.startswith(relink.BLEND_PREFIX):
            _changed.append(("run_dir", scene.name, props.run_dir))
            props.run_dir = stored
    for img in _ours(bpy.data.images):
        stored = relink.relative_path(img.filepath, filepath)
        if stored != img.filepath:
            _changed.append(("image", img.name, img.filepath))
            img.filepath_raw = stored  # no reload: unsaved paint stays
    for clip in _ours(bpy.data.movieclips):
        stored = relink.relative_path(clip.filepath, filepath)
        if stored != clip.filepath:
            _changed.append(("clip", clip.name, clip.filepath))
            start = clip.frame_start
            clip.filepath = stored
            clip.frame_start = start


@bpy.app.handlers.persistent
def restore_after_copy(filepath: str = "", *_args: Any) -> None:
    """``save_post``: after a Save Copy (the file written is another one) the open file keeps its own paths."""
    changed, _changed[:] = list(_changed), []
    if not changed or bpy.data.filepath == filepath:
        return
    for kind, name, value in changed:
        if kind == "scene" and name in bpy.data.scenes:
            bpy.data.scenes[name].neural_atlas.manifest = value
        elif kind == "run_dir" and name in bpy.data.scenes:
            bpy.data.scenes[name].neural_atlas.run_dir = value
        elif kind == "image" and name in bpy.data.images:
            bpy.data.images[name].filepath_raw = value
        elif kind == "clip" and name in bpy.data.movieclips:
            clip = bpy.data.movieclips[name]
            start = clip.frame_start
            clip.filepath = value
            clip.frame_start = start


HANDLERS = ((bpy.app.handlers.save_pre, relative_before_save), (bpy.app.handlers.save_post, restore_after_copy))


def register() -> None:
    for handlers, handler in HANDLERS:
        if handler not in handlers:
            handlers.append(handler)


def unregister() -> None:
    for handlers, handler in HANDLERS:
        for h in [h for h in handlers if getattr(h, "__name__", "") == handler.__name__]:
            handlers.remove(h)
