"""The terms the engine and the add-on agree on, one module per subject (``engine.contract`` names those that cross to
the add-on; the engine takes each term from its subject module). Standard library only: the add-on imports them,
through the contract, inside Blender's Python."""
