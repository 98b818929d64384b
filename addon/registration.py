"""Registration: one ``classes`` tuple (registered in order, unregistered in reverse) and the scene's root
PropertyGroup. Registration errors raise."""

from __future__ import annotations

import bpy

from . import blend_paths, ops, preferences, preview_plane, properties, save_paint, ui
from .core import running
from .ops import frame_paint, import_run

classes = (*properties.classes, *preferences.classes, *ops.classes, *ui.classes)


@bpy.app.handlers.persistent
def _cancel_jobs(*_args) -> None:
    """Loading another file (or unregistering) ends the modal operators: stop their engines too."""
    running.cancel_all()


@bpy.app.handlers.persistent
def _fresh_file(*_args) -> None:
    """``load_post`` (File > Open, Revert, another shot): what the add-on remembers of the file that was open is
    forgotten, so the live preview shows the loaded file's paint and Land reads its frame paint afresh; a file saved
    before a refine follows the export its paint was re-aligned to (``import_run.follow_realigned``)."""
    preview_plane.forget_copies()
    frame_paint.forget_painted()
    if bpy.context.scene is not None:
        import_run.follow_realigned(bpy.context)


#: The add-on's handlers of file events: (the handler list, the handler); each persistent (a load keeps it).
HANDLERS = ((bpy.app.handlers.load_pre, _cancel_jobs), (bpy.app.handlers.load_post, _fresh_file))


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    properties.register_props()
    for handlers, handler in HANDLERS:
        if handler not in handlers:
            handlers.append(handler)
    save_paint.register()  # Save (Ctrl+S) writes the paint too; before the paths are rebased for the file
    blend_paths.register()  # the add-on's paths stay relative to the .blend across saves
    preview_plane.start_live()  # a saved file's preview follows the paint too (the timer idles while none is shown)


def unregister() -> None:
    _cancel_jobs()
    blend_paths.unregister()
    save_paint.unregister()
    preview_plane.stop_live()
    for handlers, handler in HANDLERS:
        for h in [h for h in handlers if getattr(h, "__name__", "") == handler.__name__]:
            handlers.remove(h)
    properties.unregister_props()
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
