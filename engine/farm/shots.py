"""The shots file: the shots of a sequence a farm fits, exports and renders, read and validated in one place.

A shots file is TOML (``.toml``) or JSON (``.json``), chosen by its extension, and versioned by
``contract.SHOTS_TAG``. Every mistake is refused before anything is submitted, as one line naming the file, the
shot, the key and the fix: a farm that finds a typo an hour into a sequence has wasted the hour on every shot.

::

    neural_atlas_shots = 1

    [defaults]               # any of terms.farm.SHOT_DEFAULT_KEYS; a shot's own value wins
    preset = "draft"
    export_chunk = 50

    [[shots]]
    name = "sh010"           # letters, digits, - and _: it names the shot's tasks and its run folder
    plate = "plates/sh010"   # a folder of frames, a pattern (plate.####.exr) or a movie; relative to this file
    masks = ["masks/sh010_car"]
    frames = "1001-1100"

Relative paths resolve against the file's folder, so a sequence's folder can move with its shots file; a shot's
run folder defaults to ``runs/<name>`` beside the file.

Each key is declared once, with its checks, by ``Shot`` (engine/farm/shots_model.py), the validated shot itself;
this module reads the file around it: its version, its keys, the defaults merged into each shot, and what holds
across shots (names and run folders of their own, no shot writing where any shot reads or writes).
"""

from __future__ import annotations

import difflib
import json
import os
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from .. import contract as C
from ..errors import InputError
from ..terms.farm import SHOT_DEFAULT_KEYS, SHOT_REQUIRED_KEYS
from .shots_model import DEFAULT_EXPORT_CHUNK, DEFAULT_RENDER_CHUNK, FOLDER, Shot, refusal, shown

_FORMATS = {".toml": "TOML", ".json": "JSON"}


@dataclass(frozen=True)
class ShotsFile:
    """A validated shots file."""

    path: Path
    shots: tuple[Shot, ...]


def load_shots(path: str | Path) -> ShotsFile:
    """Read and validate a shots file; ``InputError`` (one line: the file, the shot, the key, the fix) otherwise."""
    file = Path(os.path.abspath(os.path.expanduser(os.fspath(path))))
    try:
        data = _parse(file)
        return ShotsFile(file, parse_shots(data, file))
    except RecursionError:  # the decoders (and a repr of the value) recurse once per level: one line, no traceback
        raise InputError(
            file,
            "nests lists or tables too deeply to be a shots file",
            f"write {C.SHOTS_TAG}, a [{C.SHOTS_DEFAULTS_KEY}] table and one table per shot (docs/farm.md)",
        ) from None


def parse_shots(data: Any, file: Path) -> tuple[Shot, ...]:
    """Validate the decoded document ``data`` of ``file`` (its folder resolves relative paths)."""
    if not isinstance(data, dict):
        raise InputError(file, "is not a table of keys", f"start it with {C.SHOTS_TAG} = {C.SHOTS_VERSION}")
    _check_version(file, data)
    _check_keys(file, "the file", data, (C.SHOTS_TAG, C.SHOTS_DEFAULTS_KEY, C.SHOTS_LIST_KEY))
    defaults = data.get(C.SHOTS_DEFAULTS_KEY, {})
    if not isinstance(defaults, dict):
        raise InputError(file, f"'{C.SHOTS_DEFAULTS_KEY}' is not a table", f"write [{C.SHOTS_DEFAULTS_KEY}] with keys")
    for key in defaults:
        if key in C.SHOT_KEYS and key not in SHOT_DEFAULT_KEYS:
            raise InputError(
                file,
                f"'{C.SHOTS_DEFAULTS_KEY}' sets '{key}', which is a shot's own",
                f"move '{key}' into each shot; defaults may hold {', '.join(SHOT_DEFAULT_KEYS)}",
            )
    _check_keys(file, f"'{C.SHOTS_DEFAULTS_KEY}'", defaults, SHOT_DEFAULT_KEYS)
    entries = data.get(C.SHOTS_LIST_KEY)
    if not isinstance(entries, list) or not entries:
        raise InputError(
            file,
            f"no '{C.SHOTS_LIST_KEY}' list" if entries is None else f"'{C.SHOTS_LIST_KEY}' is not a list of shots",
            f"add one table per shot ([[{C.SHOTS_LIST_KEY}]] in TOML) with at least {' and '.join(SHOT_REQUIRED_KEYS)}",
        )
    shots = []
    for index, entry in enumerate(entries):
        where = f"shot #{index + 1}"
        if not isinstance(entry, dict):
            raise InputError(file, f"{where} is not a table", f"write each shot as a table of {C.SHOT_KEYS}")
        if isinstance(entry.get("name"), str):
            where = f"shot {entry['name']!r}"
        _check_keys(file, where, entry, C.SHOT_KEYS)
        table = {**defaults, **entry}
        try:
            shots.append(Shot.model_validate(table, context={FOLDER: file.parent}))
        except ValidationError as exc:
            raise refusal(file, where, table, exc) from None
    _check_unique(file, shots)
    _check_folders(file, shots)
    return tuple(shots)


def _parse(file: Path) -> Any:
    kind = _FORMATS.get(file.suffix.lower())
    if kind is None:
        raise InputError(file, "is not a .toml or .json file", "name the shots file *.toml or *.json")
    try:
        raw = file.read_bytes()
    except FileNotFoundError:
        raise InputError(file, "does not exist", "check the path of the shots file") from None
    except OSError as exc:
        raise InputError(file, f"cannot be read ({exc.strerror})", "check the path and its permissions") from None
    try:
        text = raw.decode("utf-8")
        return tomllib.loads(text) if kind == "TOML" else json.loads(text)
    except UnicodeDecodeError:
        raise InputError(file, "is not UTF-8 text", "save the shots file as UTF-8") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(file, f"is not valid TOML ({exc})", "fix the syntax at that line") from None
    except json.JSONDecodeError as exc:
        raise InputError(
            file, f"is not valid JSON ({exc.msg} at line {exc.lineno} column {exc.colno})", "fix the syntax there"
        ) from None


def _check_version(file: Path, data: dict[str, Any]) -> None:
    version = data.get(C.SHOTS_TAG)
    if version is None:
        raise InputError(
            file, f"has no '{C.SHOTS_TAG}' version key", f"add {C.SHOTS_TAG} = {C.SHOTS_VERSION} at the top"
        )
    if isinstance(version, bool) or version != C.SHOTS_VERSION:
        raise InputError(
            file,
            f"is a shots file of version {version!r}; this engine reads version {C.SHOTS_VERSION}",
            f"write it in version {C.SHOTS_VERSION} (docs/farm.md) or use the engine that wrote it",
        )


def _check_keys(file: Path, where: str, table: dict[str, Any], known: tuple[str, ...]) -> None:
    for key in table:
        if key not in known:
            close = difflib.get_close_matches(str(key), known, n=1)
            hint = f"did you mean '{close[0]}'?" if close else f"the keys are {', '.join(known)}"
            raise InputError(file, f"{where}: unknown key '{key}'", hint)


def plate_input(plate: str) -> str:
    """What a plate reads: the folder of frames, the folder a sequence pattern lists, or the movie file (what an
    output folder may not be, nor be inside, nor hold)."""
    return plate if os.path.exists(plate) else os.path.dirname(plate)


def _real(path: str) -> str:
    """``path`` with every link resolved, as the file system sees it: two names of one folder compare equal."""
    return os.path.normcase(os.path.realpath(path))


def _parents(path: str) -> Iterator[str]:
    """The folders above ``path``, nearest first, up to the root."""
    parent = os.path.dirname(path)
    while parent != path:
        yield parent
        path, parent = parent, os.path.dirname(parent)


def _check_folders(file: Path, shots: list[Shot]) -> None:
    """No shot writes where any shot reads or writes: every run and render folder (by real path, through links)
    is neither equal to, inside, nor around another shot's (or its own) plate folder, mask folders, run folder
    or render folder. A render folder that is another plate's folder would put ``edit.*`` frames among that
    plate's frames; a run folder inside another would be fitted over."""
    places: list[tuple[Shot, str, str]] = []  # (shot, what, path); outputs first, in shot order
    for shot in shots:
        places.append((shot, "'run' folder", shot.run))
        if shot.render is not None:
            places.append((shot, "'render' folder", shot.render))
    outputs = len(places)
    for shot in shots:
        places.append((shot, "'plate'", plate_input(shot.plate)))
        places.extend((shot, f"'masks' folder {i + 1}", mask) for i, mask in enumerate(shot.masks))
    real = [_real(path) for _s, _w, path in places]
    at: dict[str, list[int]] = {}  # a real path: the places there
    below: dict[str, list[int]] = {}  # a real folder: the places inside it
    for j, path in enumerate(real):
        at.setdefault(path, []).append(j)
        for parent in _parents(path):
            below.setdefault(parent, []).append(j)
    for i in range(outputs):  # each output against every place through the maps: linear in the shots, not square
        shot, what, path = places[i]
        mine = real[i]
        met = [(j, "is") for j in at.get(mine, ())]
        met += [(j, "is inside") for parent in _parents(mine) for j in at.get(parent, ())]
        met += [(j, "holds") for j in below.get(mine, ())]
        met = [(j, relation) for j, relation in met if j != i and not (j < outputs and j < i)]  # each pair once
        if met:
            j, relation = min(met)
            other, other_what, other_path = places[j]
            theirs = real[j]
            whose = "its own" if other is shot else f"shot {other.name!r}'s"
            plain = os.path.normcase(path) == mine and os.path.normcase(other_path) == theirs
            seen = "" if plain else f" (through links: {shown(mine)} and {shown(theirs)})"
            raise InputError(
                file,
                f"shot {shot.name!r}: the {what} {shown(path)} {relation} {whose} {other_what} "
                f"{shown(other_path)}{seen}",
                "give every run and render folder a place of its own, outside every plate, mask, run and render "
                "folder of the shots file",
            )


def _check_unique(file: Path, shots: list[Shot]) -> None:
    """Shot names, and run folders, name one shot each (case-insensitively: a folder on macOS or Windows)."""
    for what, key in (("name", lambda s: s.name.casefold()), ("run folder", lambda s: os.path.normcase(s.run))):
        seen: dict[str, str] = {}
        for shot in shots:
            k = key(shot)
            if k in seen:
                raise InputError(
                    file,
                    f"shots {seen[k]!r} and {shot.name!r} have the same {what}",
                    "give every shot its own name and run folder",
                )
            seen[k] = shot.name


__all__ = ["DEFAULT_EXPORT_CHUNK", "DEFAULT_RENDER_CHUNK", "Shot", "ShotsFile", "load_shots"]
