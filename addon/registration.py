"""Registration: one ``classes`` tuple (registered in order, unregistered in reverse) and the scene's root
PropertyGroup. Registration errors raise."""

from __future__ import annotations

import bpy

from . import blend_paths, ops, preferences, preview, properties, ui
from .core import running

classes = (*properties.classes, *preferences.classes, *ops.classes, *ui.classes)


@bpy.app.handlers.persistent
def _cancel_jobs(*_args) -> None:
    """Loading another file (or unregistering) ends the modal operators: stop their engines too."""
    running.cancel_all()


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    properties.register_props()
    bpy.app.handlers.load_pre.append(_cancel_jobs)
    blend_paths.register()  # the add-on's paths stay relative to the .blend across saves
    preview.start_live()  # a saved file's preview follows the paint too (the timer idles while none is shown)


def unregister() -> None:
    _cancel_jobs()
    blend_paths.unregister()
    preview.stop_live()
    for handler in [h for h in bpy.app.handlers.load_pre if getattr(h, "__name__", "") == "_cancel_jobs"]:
        bpy.app.handlers.load_pre.remove(handler)
    properties.unregister_props()
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
