"""Neural Atlas engine: fits layered neural atlases to a clip (no bpy here, ever)."""

from .contract import ENGINE_VERSION as __version__  # relative: the Blender extension imports engine as a subpackage

__all__ = ["__version__"]
