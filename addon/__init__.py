"""Neural Atlas Blender add-on (bpy side).

This package imports bpy and, of the engine, only ``engine.contract``. The Fit Atlas panel, the engine
process runner and the compositor builder land with the add-on issue; until then registration is empty
so the extension installs and enables cleanly.
"""

classes: tuple = ()


def register() -> None:
    import bpy

    for cls in classes:
        bpy.utils.register_class(cls)


def unregister() -> None:
    import bpy

    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
