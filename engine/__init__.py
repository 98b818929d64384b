"""Neural Atlas engine: fits layered neural atlases to a clip (no bpy here, ever)."""

# relative: the Blender extension imports engine as a subpackage
from .terms.versions import ENGINE_VERSION as __version__

__all__ = ["__version__"]
