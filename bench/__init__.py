"""Measurement tools for developing the engine (not shipped in the extension; ``python -m bench``):
accuracy against time, seconds per step, the scene analysis' speed-up, tracking scores and named test scenes."""
