# Extension root shim: Blender loads this file as the extension's package; the add-on lives in addon/.
# Imported on its own (pytest imports a checkout folder whose name is not a Python name, e.g. neural-atlas/, as the
# module "__init__"), there is no package to import from, and nothing to register.
if __package__:
    from .addon import register, unregister  # noqa: F401
