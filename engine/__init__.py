"""Neural Atlas engine: fits layered neural atlases to a clip (no bpy here, ever)."""

from engine.contract import ENGINE_VERSION as __version__

__all__ = ["__version__"]
