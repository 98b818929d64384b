"""Neural Atlas Blender add-on.

``core/`` is the add-on's logic without bpy (engine commands and jobs, the tree plan, frame and file
naming, scribble maths, estimates), importable and tested outside Blender; ``ops/`` holds the operators,
thin over it; the modules beside them are the bpy side (registration, panels, properties, preferences, the
compositor builder, paint, mask rasterisation, annotation reading, and ``compat``, the one module that
branches on Blender's version). Of the engine only ``engine.contract`` is imported. This file imports the
bpy side only when Blender registers the add-on.
"""


def register() -> None:
    from . import registration

    registration.register()


def unregister() -> None:
    from . import registration

    registration.unregister()
