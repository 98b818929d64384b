"""The files the add-on writes beside a Run Folder. No bpy here.

The engine owns the Run Folder RUN itself (``engine.contract``: checkpoint, exports, edits, auto_masks); the add-on
writes only its edit layers, holding the run folder's lock (``edits_lock``). Beside it the add-on keeps what it made
for the engine and what it logged:

    RUN.masks/layer<N>/   each Mask layer rasterised (one image per frame)
    RUN.scribbles/        the clip's annotation strokes rasterised (one image per scribbled frame)
    RUN.blender.log       the fit and export commands' output
    RUN.masks.log         Find Masks' output
    RUN.estimate.log      Estimate Time's output
    RUN.carry.log         Carry Paint's output
    RUN.farm/shots.json   Submit to Farm's shots file (the clip as the farm's engine reads it)
    RUN.farm/openjd/      Submit to Farm's OpenJD bundles (openjd_2, ... for later submissions)
    RUN.farm.log          Submit to Farm's output
"""

from __future__ import annotations

import os
from contextlib import AbstractContextManager

from ...engine import contract as C  # type: ignore[import-not-found]

#: An edit layer being saved is written under a hidden name beside it first (``.Foreground.saving-1234.png``).
SAVING_MARK = ".saving-"
#: How the add-on's writers of a run folder's edit layers are named to another process that finds it locked.
SAVE_EDITS_HOLDER = "Blender Save Edits"
FLOAT_EDITS_HOLDER = "Blender Float Edit Layers"


def realigned_manifest(manifest_path: str) -> str | None:
    """The manifest of the export the run's edit layers were re-aligned to, when that is another export of the same
    run than ``manifest_path``'s (a refine carried the paint on, and the .blend was not saved after it) and it is
    there; None otherwise (no record, an unreadable one, the same export, a manifest outside a run's exports)."""
    run = imported_run_dir(manifest_path)
    if run is None:
        return None
    folder = os.path.dirname(os.path.realpath(manifest_path))
    try:
        version = C.read_aligned_export(run)
    except ValueError:
        return None
    if version is None or version == os.path.basename(folder):
        return None
    newer = os.path.join(run, C.EXPORTS_DIR, version, C.MANIFEST_NAME)
    return newer if os.path.isfile(newer) else None


class RunFiles:
    """The Run Folder ``run_dir`` (absolute, no trailing separator) and the add-on's files beside it."""

    def __init__(self, run_dir: str):
        self.run_dir = run_dir
        self.fit_log = run_dir + ".blender.log"
        self.masks_log = run_dir + ".masks.log"
        self.estimate_log = run_dir + ".estimate.log"
        self.carry_log = run_dir + ".carry.log"
        self.scribbles = run_dir + ".scribbles"
        self.farm_dir = run_dir + ".farm"
        self.farm_log = run_dir + ".farm.log"
        self.shots_file = os.path.join(self.farm_dir, "shots.json")

    def layer_masks(self, index: int) -> str:
        """The folder foreground layer ``index`` (1-based) is rasterised into."""
        return os.path.join(self.run_dir + ".masks", f"layer{index}")

    def has_fit(self) -> bool:
        """A fit's checkpoint is there (Resume continues it; a new fit would overwrite it)."""
        return os.path.exists(os.path.join(self.run_dir, C.RUN_CHECKPOINT))

    def has_finished_fit(self) -> bool:
        """The fit has finished (its metrics are written): Refine continues it for more steps."""
        return self.has_fit() and os.path.exists(os.path.join(self.run_dir, C.RUN_METRICS))

    def fresh_auto_masks(self) -> str:
        """Where Find Masks writes: ``RUN/auto_masks``, or a numbered sibling when that already holds masks."""
        return fresh_dir(os.path.join(self.run_dir, C.AUTO_MASKS_DIR))


def fresh_dir(base: str) -> str:
    """``base``, else ``base_2``, ``base_3``...: the first that is missing or empty (masks are never overwritten,
    an artist may have fixed the last ones)."""
    candidate, n = base, 1
    while os.path.exists(candidate) and (not os.path.isdir(candidate) or os.listdir(candidate)):
        n += 1
        candidate = f"{base}_{n}"
    return candidate


def png_files(folder: str) -> list[str]:
    """The PNG images in ``folder``, sorted ([] when it does not exist)."""
    if not os.path.isdir(folder):
        return []
    return sorted(os.path.join(folder, n) for n in os.listdir(folder) if n.lower().endswith(".png"))


def clear_numbered_pngs(folder: str) -> None:
    """Remove the numbered PNGs (``00012.png``) a previous fit wrote into the add-on's own ``folder`` (a frame
    whose strokes the artist has since erased must not keep its old scribble); nothing else is touched."""
    for path in png_files(folder):
        if os.path.splitext(os.path.basename(path))[0].isdigit():
            os.remove(path)


def edits_lock(manifest_path: str, what: str) -> AbstractContextManager[None]:
    """The lock of the run folder the export ``manifest_path`` belongs to (``contract.run_lock``), held while the
    add-on writes into its ``edits/``: an export or project-frame running meanwhile is refused, and when one of
    them holds it this raises ``contract.RunLocked`` (one line naming it) before anything is written."""
    return C.run_lock(C.manifest_run_root(manifest_path), what)


def saving_path(path: str) -> str:
    """The hidden temporary name an edit layer is saved under before it is renamed onto ``path`` (same folder, so
    the rename is atomic; same extension, so the format is kept)."""
    folder, name = os.path.split(path)
    stem, ext = os.path.splitext(name)
    return os.path.join(folder, f".{stem}{SAVING_MARK}{os.getpid()}{ext}")


def imported_run_dir(manifest_path: str) -> str | None:
    """The run folder of an imported export's manifest (``RUN/exports/vNNN/manifest.json`` -> RUN): the Run Folder
    Refine continues; None for a manifest outside a run folder's exports."""
    root = C.manifest_run_root(manifest_path)
    folder = os.path.dirname(os.path.realpath(manifest_path))
    return None if os.path.normpath(root) == os.path.normpath(folder) else root
