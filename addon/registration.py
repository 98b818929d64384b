"""Registration: one ``classes`` tuple (registered in order, unregistered in reverse) and the scene's root
PropertyGroup. Registration errors raise."""

from __future__ import annotations

import bpy

from . import operators, preferences, properties, ui

classes = (*properties.classes, *preferences.classes, *operators.classes, *ui.classes)


@bpy.app.handlers.persistent
def _cancel_fits(*_args) -> None:
    """Loading another file (or unregistering) ends the modal operators: stop their engines too."""
    for session in list(operators._SESSIONS.values()):
        session.cancel()
    operators._SESSIONS.clear()


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    properties.register_props()
    bpy.app.handlers.load_pre.append(_cancel_fits)


def unregister() -> None:
    _cancel_fits()
    for handler in [h for h in bpy.app.handlers.load_pre if getattr(h, "__name__", "") == "_cancel_fits"]:
        bpy.app.handlers.load_pre.remove(handler)
    properties.unregister_props()
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
