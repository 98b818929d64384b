"""``engine relink``: an export told where its plate is now, so every tool that reads it (``render``, ``preview``, the
add-on, the export's Nuke script) finds the plate again after the plate or the run folder moved.

A manifest names its plate relative to itself and, as a fallback, as it was at export (``contract.resolve_plate_path``):
that survives a run folder moved with its plate, or moved alone while the plate stays. A shot moved and then its
run folder moved elsewhere again breaks both; the artist (or the add-on's Relink Run Folder, which knows where the
scene's plate clip is) says where the plate is, and this rewrites the manifest's plate paths and the export's
``.nk``. The plate must be the same plate: a sequence's folder must hold every frame file the export names.

The ``.nk`` beside the manifest is rewritten only while it is the one the export wrote (its text is what the old
manifest gives): a script the artist saved over it from Nuke is left as it is, and the report says how to write a
new one.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from .. import contract as C
from ..errors import InputError
from ..io.atomic import atomic_write_text
from ..io.clip import is_sequence_pattern
from ..terms.cli import VERB_NUKE
from ..terms.export_names import NUKE_SCRIPT_NAME
from ..terms.manifest import validate_manifest
from .manifest import Manifest
from .manifest_writer import relative_path

#: The fix a plate that is not the export's gets.
PLATE_CHOICE_FIX = "choose the folder that holds the export's plate frames (or the plate movie)"


def plate_frames(clip: dict[str, Any], plate: Path) -> tuple[Path, list[Path]]:
    """Where the manifest's plate ``clip`` is when it lies at ``plate`` (a sequence's folder or one of its frame
    files; a movie's file): (its source, its frame files). A folder without one of the export's frame files is an
    InputError naming the first one missing."""
    if clip["kind"] == C.CLIP_KINDS[0]:
        folder = plate if plate.is_dir() else plate.parent
        if not folder.is_dir():
            raise InputError(plate, "plate folder does not exist", PLATE_CHOICE_FIX)
        files = [folder / os.path.basename(name) for name in clip["frame_files"]]
        lacking = next((f for f in files if not f.is_file()), None)
        if lacking is not None:
            raise InputError(folder, f"has no plate frame {lacking.name} (the export's)", PLATE_CHOICE_FIX)
        source = os.path.basename(os.path.normpath(clip["source"]))
        return (folder / source if is_sequence_pattern(source) else folder), files
    if not plate.is_file():
        raise InputError(plate, "plate movie does not exist", PLATE_CHOICE_FIX)
    return plate, []


def relinked_clip(clip: dict[str, Any], manifest_path: Path, plate: Path) -> dict[str, Any]:
    """The manifest's ``clip`` section with its plate at ``plate``: relative to the manifest's folder, and absolute
    as the fallback a run folder moved alone reads (``contract.resolve_plate_path``)."""
    source, files = plate_frames(clip, plate)
    folder = manifest_path.parent
    out = dict(clip)
    out["source"] = relative_path(source, folder)
    out["source_absolute"] = os.path.realpath(source)
    if files:
        out["frame_files"] = [relative_path(f, folder) for f in files]
        out["frame_files_absolute"] = [os.path.realpath(f) for f in files]
    return out


def _same_plate(manifest: Manifest, clip: dict[str, Any]) -> bool:
    """Whether the manifest already reads the plate ``clip`` names."""
    now = os.path.realpath(C.resolve_plate_path(str(manifest.path), manifest.clip))
    return now == clip["source_absolute"] and os.path.exists(now)


def relink_plate(manifest_path: str | os.PathLike[str], plate: str | os.PathLike[str]) -> list[str]:
    """Point the export at ``manifest_path`` at its plate at ``plate``: the manifest's plate paths rewritten, and the
    export's ``.nk`` where it is still the export's own. Returns one line per file: what was done, or why not."""
    from .nuke import NukeScriptError, nuke_script

    manifest = Manifest(os.fspath(manifest_path))
    clip = relinked_clip(manifest.clip, manifest.path, Path(plate).absolute())
    if _same_plate(manifest, clip):
        return [f"{manifest.path}: already reads the plate at {clip['source_absolute']}"]
    script = manifest.path.parent / NUKE_SCRIPT_NAME
    try:
        ours = script.is_file() and script.read_text(encoding="utf-8") == nuke_script(manifest.data, str(manifest.path))
    except (NukeScriptError, InputError, OSError, UnicodeDecodeError):
        ours = False
    data = {**manifest.data, "clip": clip}
    validate_manifest(data)
    lines = [f"{manifest.path}: reads the plate at {clip['source_absolute']}"]
    with C.run_lock(manifest.run_root, C.VERB_RELINK):  # not while a fit or an export writes the run folder
        atomic_write_text(manifest.path, json.dumps(data, indent=2))
        if ours:
            try:
                atomic_write_text(script, nuke_script(data, str(manifest.path)))
                lines.append(f"{script}: reads the plate at {clip['source_absolute']}")
            except (NukeScriptError, InputError) as exc:
                lines.append(f"{script}: not rewritten ({exc})")
    if not ours and script.exists():
        lines.append(
            f"{script}: left as it is (saved since the export); write a new script with "
            f"`python -m {C.CLI_MODULE} {VERB_NUKE} {manifest.path} --out NEW.nk`"
        )
    return lines


__all__ = ["PLATE_CHOICE_FIX", "plate_frames", "relink_plate", "relinked_clip"]
