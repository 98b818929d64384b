"""The add-on's operators, thin: each reads the scene, calls the logic in ``addon/core`` (or the bpy helpers
beside it) and reports. Each that needs something has a ``poll`` (``core.needs``: greyed out, saying why), and
each that changes the scene pushes an undo step (docs/addon.md, *Buttons, undo and ESC*). Grouped by what they
act on:

- ``fit``: engine jobs for a scene: Fit Atlas, Find Masks, Estimate Time, Cancel (driven by ``driver``);
- ``refine``: Refine, a finished fit continued with the paint carried over (driven by ``driver``);
- ``layers``: the foreground layer list and the clip's scribble layers;
- ``import_run``: Import Atlas;
- ``paint``: paint canvases, Save Edits, Float Edit Layers;
- ``frame_paint``: Paint on Frame, Land Paint on Atlases (``engine project-frame``, driven by ``driver``);
- ``preview``: Live Preview (the composite on a plane in the 3D viewport);
- ``render``: Render Edited Clip;
- ``relink``: Relink Run Folder (the run folder moved since the import);
- ``setup``: the preferences' Set up engine (and its Cancel), Copy Install Command and Check engine;
- ``farm``: Submit to Farm (a Flamenco job or an OpenJD bundle of the clip).
"""

from __future__ import annotations

from . import farm, fit, frame_paint, import_run, layers, paint, preview, refine, relink, render, setup

classes = (
    *fit.classes,
    *refine.classes,
    *layers.classes,
    *import_run.classes,
    *paint.classes,
    *frame_paint.classes,
    *preview.classes,
    *render.classes,
    *relink.classes,
    *setup.classes,
    *farm.classes,
)
