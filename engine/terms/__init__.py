"""The terms of the contract between the engine and the add-on (``engine.contract`` names them all), one module per
subject. Standard library only: the add-on imports them, through the contract, inside Blender's Python."""
