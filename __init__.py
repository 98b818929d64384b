# Extension root shim: Blender loads this file; the add-on lives in addon/.
from .addon import register, unregister  # noqa: F401
