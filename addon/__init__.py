"""Neural Atlas Blender add-on (bpy side).

Imports bpy and, of the engine, only ``engine.contract``. The modules without bpy (``engine_process``,
``engine_setup``, ``tree_plan``, ``mask_math``, ``estimate``) are importable and tested outside Blender,
so this file imports the bpy side only when Blender registers the add-on.
"""


def register() -> None:
    from . import registration

    registration.register()


def unregister() -> None:
    from . import registration

    registration.unregister()
