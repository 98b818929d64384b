"""The engine's version and the version of the JSON it writes: what a reader on the other side of the contract
checks first."""

from __future__ import annotations

ENGINE_VERSION = "0.1.0"

#: Version of every JSON file the engine writes (config, metrics, checkpoints' metadata, progress lines).
SCHEMA_VERSION = 1

#: What ``engine.contract`` re-exports from this module (its own names, not its imports).
__all__ = ["ENGINE_VERSION", "SCHEMA_VERSION"]
