"""The add-on's logic that needs no Blender: nothing in this package imports bpy.

- ``engine_commands``: the command line of each engine verb the add-on runs.
- ``engine_process``: one engine process, started from an argv list, its JSON progress lines followed.
- ``progress``: what those lines say (the progress bar's state) and what the logs record.
- ``jobs``: the jobs the operators drive (fit then export, find masks, estimate, set up the engine): one
  state machine, polled from a modal timer or in a blocking loop.
- ``running``: the jobs running now, by scene.
- ``needs``: what each operator needs before it can run (its poll), and the line that says what is missing.
- ``engine_setup``: the engine's Python (its virtual environment, pip, the environment of its processes).
- ``run_files``: the files the add-on writes beside a Run Folder.
- ``frames``: scene frames -> sequence file numbers, mask file names, the engine's frame positions.
- ``estimate``: the documented fit-time estimate and the engine's own.
- ``tree_plan``: the compositor tree as plain data, planned from a manifest.
- ``scribble_math``: annotation strokes -> the engine's scribble images.
- ``float_edit``: an 8-bit sRGB edit layer's pixels -> linear premultiplied floats.

Everything here is tested without Blender (tests/addon/core) and type-checked.
"""
