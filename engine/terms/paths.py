"""A manifest's paths: where to read what it names (the plate where it is now), and the only places a manifest
may have the engine or the add-on write (edit layers, their history, previews)."""

from __future__ import annotations

import json
import os
import re
from typing import Any

from .export_names import EDITS_ALIGNED, EDITS_ALIGNED_TAG, EDITS_DIR, EXPORTS_DIR
from .manifest import MANIFEST_QUOTE_PATH_CHARS, ManifestError, _quote


def resolve_manifest_path(manifest_path: str, path: str) -> str:
    """A path written in a manifest, to READ through: relative to the manifest's folder with its symlinks resolved
    (the export computes them from there, so a run folder moved, mounted or linked elsewhere keeps working), then
    normalised; an absolute path (a plate on another drive) is taken as it is: the reader checks it exists."""
    if os.path.isabs(path):
        return path
    folder = os.path.realpath(os.path.dirname(os.path.abspath(manifest_path)))
    return os.path.normpath(os.path.join(folder, path))


#: What makes a file name a sequence pattern (``plate.####.exr``, ``plate.@@@@.exr``, ``plate.%04d.exr``).
SEQUENCE_TOKEN = re.compile(r"[#@]|%0?\d*d")


def _names_something(path: str) -> bool:
    """A file or folder that exists, or a sequence pattern whose folder does."""
    return os.path.exists(path) or (
        SEQUENCE_TOKEN.search(os.path.basename(path)) is not None and os.path.isdir(os.path.dirname(path))
    )


def resolve_plate_path(manifest_path: str, clip: dict[str, Any], index: int | None = None) -> str:
    """The manifest's plate to READ (``index`` None: its ``source``; else ``frame_files[index]``): as
    ``resolve_manifest_path``; where that names nothing but the path as it was at export (``source_absolute``,
    ``frame_files_absolute``) does, that one: a run folder moved alone still finds the plate it left behind."""
    if index is None:
        relative, absolute = clip["source"], clip.get("source_absolute")
    else:
        relative = clip["frame_files"][index]
        kept = clip.get("frame_files_absolute")
        absolute = kept[index] if isinstance(kept, list) and len(kept) == len(clip["frame_files"]) else None
    here = resolve_manifest_path(manifest_path, relative)
    if isinstance(absolute, str) and not _names_something(here) and _names_something(absolute):
        return absolute
    return here


def read_aligned_export(run_dir: str) -> str | None:
    """The export (``vNNN``) the run's edit layers match, as ``edits/aligned.json`` records it; None when there is no
    record. ValueError when the file is there but is not a record."""
    path = os.path.join(run_dir, EDITS_DIR, EDITS_ALIGNED)
    if not os.path.exists(path):
        return None
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
        version = data["export"] if data.get(EDITS_ALIGNED_TAG) == 1 else None
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        version = None
    if not isinstance(version, str) or not re.fullmatch(r"v\d{3,}", version):
        raise ValueError(f"{path}: is not an edit-alignment record")
    return version


def manifest_run_root(manifest_path: str) -> str:
    """The run folder a manifest belongs to: RUN_DIR for ``RUN_DIR/exports/vNNN/manifest.json`` (found from where
    the manifest IS, so a run folder moved or mounted elsewhere keeps working), else the manifest's own folder."""
    folder = os.path.dirname(os.path.realpath(manifest_path))
    parent = os.path.dirname(folder)
    if os.path.basename(parent) == EXPORTS_DIR:
        return os.path.dirname(parent)
    return folder


def is_within(path: str, root: str) -> bool:
    """Whether ``path`` is ``root`` or lies below it once every symlink and ``..`` is resolved."""
    real, base = os.path.realpath(path), os.path.realpath(root)
    try:
        return os.path.commonpath([real, base]) == base
    except ValueError:  # different drives (Windows)
        return False


def manifest_write_roots(manifest_path: str) -> tuple[str, ...]:
    """The folders a manifest's paths may be written into: the run folder's ``edits/`` (the edit layers and their
    history) and the export's own folder (its previews); for a manifest outside ``RUN_DIR/exports`` its own
    folder. Never the run's records, its checkpoint or another export."""
    root, own = manifest_run_root(manifest_path), os.path.dirname(os.path.realpath(manifest_path))
    return (own,) if root == own else (os.path.join(root, EDITS_DIR), own)


def resolve_manifest_write_path(manifest_path: str, path: str) -> str:
    """A path written in a manifest, to WRITE through (edit layers, their history, previews): relative to the
    manifest, inside ``manifest_write_roots`` once symlinks and ``..`` are resolved; anything else raises
    ManifestError (one line). A manifest cannot make the engine or the add-on write anywhere else. (An absolute path
    is taken only where it lies there too: manifests written by hand or by older tools.)"""
    fix = "export the run again (a manifest's edit paths are relative and stay inside its run folder)"
    if not isinstance(path, str) or not path:
        raise ManifestError(
            f"{manifest_path}: write path {_quote(path, MANIFEST_QUOTE_PATH_CHARS)} is not a path — {fix}"
        )
    resolved = resolve_manifest_path(manifest_path, path)
    if not any(is_within(resolved, root) for root in manifest_write_roots(manifest_path)):
        where = "is absolute and outside" if os.path.isabs(path) else "leaves"
        quoted = _quote(path, MANIFEST_QUOTE_PATH_CHARS)
        raise ManifestError(
            f"{manifest_path}: write path {quoted} {where} the run folder's edits/ and this export — {fix}"
        )
    return resolved


#: What ``engine.contract`` re-exports from this module (its own names, not its imports).
__all__ = [
    "SEQUENCE_TOKEN",
    "is_within",
    "manifest_run_root",
    "manifest_write_roots",
    "read_aligned_export",
    "resolve_manifest_path",
    "resolve_manifest_write_path",
    "resolve_plate_path",
]
