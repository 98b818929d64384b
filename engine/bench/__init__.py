"""Measurement tools for developing the engine (not shipped in the extension): bench, speed, tracking."""
