"""Paths that survive a moved shot: relative to the .blend where Blender can, and re-linked when the run folder
moves. No bpy here: the operator (``ops.relink``) reads the datablocks' paths and writes back what this decides.

Blender writes a path relative to the .blend as ``//`` + the path from the .blend's folder (``bpy.path.relpath``),
which keeps working when the .blend and the files it uses are copied together. A file on another drive (Windows)
has no relative path and stays absolute, as Blender leaves it.

The plate moved on its own is found again from one of its files (or its folder): the scene's plate clip takes the
file of its own name there (``plate_choice``). After either, the export itself is told where the plate is
(``plate_sync``: ``engine relink``), so ``engine render``, the export's ``.nk`` and every operator read the one plate
the scene shows.

A run folder moved on its own is found again from one file: the new manifest (or the run folder, whose newest
export's manifest is taken). The old and the new manifest paths end alike (``run/exports/v001/manifest.json``);
what comes before that common ending is the old root and the new root, and every path under the old root is
rewritten under the new one where the file is there (a plate left where it was keeps its path).
"""

from __future__ import annotations

import os
import re
import subprocess
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from ...engine import contract as C  # type: ignore[import-not-found]
from .engine_commands import engine_env, relink_argv

#: How Blender marks a path relative to the .blend's folder.
BLEND_PREFIX = "//"
#: What Relink says when the file chosen is neither a manifest nor a run or export folder holding one.
NO_MANIFEST = "no manifest.json there: choose the run folder, or the manifest.json of its export: "
#: ... nor, for the plate, a file or folder of it.
NOT_PLATE = "choose the run folder, the manifest.json of its export, or the plate's new place (a frame, or the movie)"


def relative_path(path: str, blend_file: str) -> str:
    """``path`` (absolute) relative to the .blend ``blend_file`` (``//``-prefixed, ``/`` separators as Blender
    writes them), or ``path`` as it is where there is none: an unsaved .blend (``blend_file`` '') or another drive."""
    if not path or not blend_file or path.startswith(BLEND_PREFIX):
        return path
    folder = os.path.dirname(os.path.abspath(blend_file))
    if os.path.splitdrive(os.path.abspath(path))[0].lower() != os.path.splitdrive(folder)[0].lower():
        return path
    try:
        rel = os.path.relpath(os.path.abspath(path), folder)
    except ValueError:  # another drive (Windows)
        return path
    return BLEND_PREFIX + rel.replace(os.sep, "/")


def absolute_path(path: str, blend_file: str) -> str:
    """A ``//`` path made absolute against the .blend ``blend_file``'s folder (normalised); others as they are."""
    if not path.startswith(BLEND_PREFIX) or not blend_file:
        return os.path.normpath(path) if path else path
    folder = os.path.dirname(os.path.abspath(blend_file))
    return os.path.normpath(os.path.join(folder, path[len(BLEND_PREFIX) :]))


def _parts(path: str) -> list[str]:
    drive, rest = os.path.splitdrive(os.path.normpath(os.path.abspath(path)))
    return [drive + os.sep, *[p for p in rest.split(os.sep) if p]]


def roots(old_manifest: str, new_manifest: str) -> tuple[str, str]:
    """(old root, new root): the two manifest paths without the ending they share. ``/a/shot/run/exports/v001/
    manifest.json`` -> ``/b/run/exports/v001/manifest.json`` gives (``/a/shot``, ``/b``): whatever lay under
    ``/a/shot`` is looked for under ``/b``."""
    old, new = _parts(old_manifest), _parts(new_manifest)
    same = 0
    while same < min(len(old), len(new)) - 1 and old[-1 - same] == new[-1 - same]:
        same += 1
    return os.path.join(*old[: len(old) - same]), os.path.join(*new[: len(new) - same])


def rebase(path: str, old_root: str, new_root: str) -> str | None:
    """``path`` moved from under ``old_root`` to under ``new_root``; None when it does not lie under ``old_root``."""
    path, old_root = os.path.normpath(path), os.path.normpath(old_root)
    try:
        if os.path.commonpath([path, old_root]) != old_root:
            return None
    except ValueError:  # another drive, or one relative and one absolute
        return None
    rest = os.path.relpath(path, old_root)
    return os.path.normpath(new_root) if rest == os.curdir else os.path.normpath(os.path.join(new_root, rest))


@dataclass(frozen=True)
class Link:
    """One path the scene holds: a datablock's file (an image, a movie clip) or a setting (``kind`` "prop").
    ``required``: reported when missing (a setting such as the Run Folder may name a folder not made yet)."""

    name: str
    kind: str
    path: str  # absolute
    required: bool = True


@dataclass
class RelinkPlan:
    """What Relink does: ``moves`` (name -> new absolute path) for the links found under the new root, ``missing``
    the links whose file is neither where it was nor under the new root."""

    old_root: str
    new_root: str
    moves: dict[str, str] = field(default_factory=dict)
    missing: list[str] = field(default_factory=list)


def plan_relink(
    links: Iterable[Link], old_manifest: str, new_manifest: str, exists: Callable[[str], bool] = os.path.exists
) -> RelinkPlan:
    """Each link under the old root moves to the new root where its file is there; one still where it was stays
    (the old folder was copied, not moved, or it lies outside the moved folder); the others are ``missing``."""
    old_root, new_root = roots(old_manifest, new_manifest)
    plan = RelinkPlan(old_root, new_root)
    for link in links:
        moved = rebase(link.path, old_root, new_root)
        if moved is not None and moved != os.path.normpath(link.path) and exists(moved):
            plan.moves[link.name] = moved
        elif link.required and not exists(link.path):
            plan.missing.append(link.name)
    return plan


def missing(links: Iterable[Link], exists: Callable[[str], bool] = os.path.exists) -> list[str]:
    """The names of the required links whose file is not on disk."""
    return [link.name for link in links if link.required and not exists(link.path)]


def message(plan: RelinkPlan) -> str:
    """The one line Relink reports: how many paths moved from where to where, and what is still missing."""
    line = f"relinked {len(plan.moves)} path(s) from {plan.old_root} to {plan.new_root}"
    if plan.missing:
        line += f"; still missing: {', '.join(plan.missing)}"
    return line


_EXPORT_DIR = re.compile(r"^v\d+$")


def find_manifest(
    path: str, isfile: Callable[[str], bool] = os.path.isfile, listdir: Callable[[str], list[str]] = os.listdir
) -> str:
    """The manifest that ``path`` names: a manifest file itself, an export folder's ``manifest.json``, or a run
    folder's newest export (``RUN/exports/vNNN/manifest.json``, the highest NNN); ValueError (one line) otherwise."""
    path = os.path.normpath(path)
    if isfile(path):
        return path
    own = os.path.join(path, C.MANIFEST_NAME)
    if isfile(own):
        return own
    exports = os.path.join(path, C.EXPORTS_DIR)
    try:
        versions = sorted((v for v in listdir(exports) if _EXPORT_DIR.match(v)), key=lambda v: int(v[1:]))
    except OSError:
        versions = []
    for version in reversed(versions):
        candidate = os.path.join(exports, version, C.MANIFEST_NAME)
        if isfile(candidate):
            return candidate
    raise ValueError(NO_MANIFEST + path)


def plate_choice(
    chosen: str,
    clip_file: str,
    sequence: bool,
    isfile: Callable[[str], bool] = os.path.isfile,
    isdir: Callable[[str], bool] = os.path.isdir,
) -> str:
    """The plate clip's new file when the artist chose the plate's new place ``chosen``: a sequence's frame of the clip
    file's name (``clip_file``, its first) in ``chosen``'s folder (or in ``chosen``, a folder); a movie's file itself.
    ValueError (one line) when that is not there."""
    if sequence:
        folder = chosen if isdir(chosen) else os.path.dirname(chosen)
        new = os.path.join(folder, os.path.basename(clip_file))
        if not isfile(new):
            raise ValueError(f"{folder}: has no plate frame {os.path.basename(clip_file)} — {NOT_PLATE}")
        return os.path.normpath(new)
    if not isfile(chosen):
        raise ValueError(f"{chosen}: not a file — {NOT_PLATE}")
    return os.path.normpath(chosen)


def plate_sync(
    manifest_path: str, clip: dict, plate_file: str, realpath: Callable[[str], str] = os.path.realpath
) -> str | None:
    """What to tell the export at ``manifest_path`` (its manifest's ``clip``) with ``engine relink``: the scene's
    plate file ``plate_file`` where the manifest reads its plate elsewhere (or nowhere); None where it reads it."""
    if clip["kind"] == C.CLIP_KINDS[0]:
        if not clip["frame_files"]:
            return None
        reads, shows = os.path.dirname(C.resolve_plate_path(manifest_path, clip, 0)), os.path.dirname(plate_file)
    else:
        reads, shows = C.resolve_plate_path(manifest_path, clip), plate_file
    return None if realpath(reads) == realpath(shows) else plate_file


#: How long ``engine relink`` may take (it reads and writes two small files; the engine's start is most of it).
RELINK_SECONDS = 120.0


def tell_export(python: str, manifest_path: str, plate: str, run: Callable[..., Any] = subprocess.run) -> str:
    """Run ``engine relink`` (``plate_sync``'s plate) with the engine interpreter ``python``: the line Relink adds to
    its report, what the engine fixed or left (its own lines), or why the export could not be told."""
    if not python:
        return "the export still reads its plate elsewhere (engine render, .nk): run Set up engine, then Relink again"
    try:
        done = run(relink_argv(python, manifest_path, plate), env=engine_env(), capture_output=True, text=True,
                   timeout=RELINK_SECONDS)  # fmt: skip
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"the export still reads its plate elsewhere: engine relink did not run ({exc})"
    lines = [line for line in (done.stderr or "").splitlines() if line.strip()]
    if done.returncode != C.EXIT_OK:
        return f"the export still reads its plate elsewhere: {lines[-1] if lines else f'exit {done.returncode}'}"
    return "; ".join(lines)
