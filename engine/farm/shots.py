"""The shots file: the shots of a sequence a farm fits, exports and renders, read and validated in one place.

A shots file is TOML (``.toml``) or JSON (``.json``), chosen by its extension, and versioned by
``contract.SHOTS_TAG``. Every mistake is refused before anything is submitted, as one line naming the file, the
shot, the key and the fix: a farm that finds a typo an hour into a sequence has wasted the hour on every shot.

::

    neural_atlas_shots = 1

    [defaults]               # any of contract.SHOT_DEFAULT_KEYS; a shot's own value wins
    preset = "draft"
    export_chunk = 50

    [[shots]]
    name = "sh010"           # letters, digits, - and _: it names the shot's tasks and its run folder
    plate = "plates/sh010"   # a folder of frames, a pattern (plate.####.exr) or a movie; relative to this file
    masks = ["masks/sh010_car"]
    frames = "1001-1100"

Relative paths resolve against the file's folder, so a sequence's folder can move with its shots file; a shot's
run folder defaults to ``runs/<name>`` beside the file.

Each key's type, bounds and choices are declared once, in engine/farm/shots_model.py; this module reads a shot's keys
in a fixed order, between them the checks no declaration makes (the plate and the mask folders exist, ``masks`` and
``auto_masks`` exclude each other, the ``set`` overrides and the colour space are the fit's), so a file with several
mistakes is always refused for the same one.
"""

from __future__ import annotations

import difflib
import json
import os
import re
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .. import contract as C
from ..errors import InputError
from .shots_model import (
    DEFAULT_EXPORT_CHUNK,
    DEFAULT_PRESET,
    DEFAULT_RENDER_CHUNK,
    check,
    not_utf8,
)
from .shots_model import shown as _shown

#: A shot's name becomes task ids, OpenJD step names and a folder name: a portable, short identifier.
NAME_PATTERN = re.compile(rf"^[A-Za-z0-9][A-Za-z0-9_-]{{0,{C.SHOT_NAME_MAX - 1}}}$")
#: Where a shot's run folder goes when the shot names none, relative to the shots file.
RUNS_DIR = "runs"

_FORMATS = {".toml": "TOML", ".json": "JSON"}


@dataclass(frozen=True)
class Shot:
    """One shot, with every path absolute and every default filled in: what the plan needs, nothing to look up."""

    name: str
    plate: str
    """A folder of frames, a sequence pattern or a movie file (absolute)."""
    run: str
    """The shot's run folder (absolute): the fit, its exports and, with auto_masks, the found masks."""
    masks: tuple[str, ...] = ()
    auto_masks: bool = False
    auto_parts: bool | None = None
    """The one mask's object split into the parts that move apart when the fit starts: True ``fit --auto-parts``
    (refused where it cannot apply), False ``--no-auto-parts``, None (not given) the fit's default: wherever it
    applies."""
    frames: tuple[int, int] | None = None
    """Inclusive, in the plate's frame numbers; None: every frame."""
    colorspace: str | None = None
    fps: str | None = None
    start_frame: int | None = None
    render: str | None = None
    """A folder for the rendered frames; None: no render tasks."""
    preset: str = DEFAULT_PRESET
    set: tuple[str, ...] = ()
    device: str | None = None
    atlas_size: int | None = None
    export_chunk: int = DEFAULT_EXPORT_CHUNK
    render_chunk: int = DEFAULT_RENDER_CHUNK
    render_format: str | None = None
    preview: bool = True
    follow_flow: bool = True
    """False: the export's UV as fitted (``export --no-follow-flow``); True: the export's default."""


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
        if key in C.SHOT_KEYS and key not in C.SHOT_DEFAULT_KEYS:
            raise InputError(
                file,
                f"'{C.SHOTS_DEFAULTS_KEY}' sets '{key}', which is a shot's own",
                f"move '{key}' into each shot; defaults may hold {', '.join(C.SHOT_DEFAULT_KEYS)}",
            )
    _check_keys(file, f"'{C.SHOTS_DEFAULTS_KEY}'", defaults, C.SHOT_DEFAULT_KEYS)
    entries = data.get(C.SHOTS_LIST_KEY)
    if not isinstance(entries, list) or not entries:
        raise InputError(
            file,
            f"no '{C.SHOTS_LIST_KEY}' list" if entries is None else f"'{C.SHOTS_LIST_KEY}' is not a list of shots",
            f"add one table per shot ([[{C.SHOTS_LIST_KEY}]] in TOML) with at least "
            f"{' and '.join(C.SHOT_REQUIRED_KEYS)}",
        )
    shots = []
    for index, entry in enumerate(entries):
        where = f"shot #{index + 1}"
        if not isinstance(entry, dict):
            raise InputError(file, f"{where} is not a table", f"write each shot as a table of {C.SHOT_KEYS}")
        if isinstance(entry.get("name"), str):
            where = f"shot {entry['name']!r}"
        _check_keys(file, where, entry, C.SHOT_KEYS)
        shots.append(_shot(file, where, {**defaults, **entry}))
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


def _shot(file: Path, where: str, entry: dict[str, Any]) -> Shot:
    """One shot's table (defaults merged) as a Shot, every value checked."""
    for key in C.SHOT_REQUIRED_KEYS:
        if key not in entry:
            raise InputError(file, f"{where}: no '{key}'", f"give every shot a {' and a '.join(C.SHOT_REQUIRED_KEYS)}")
    v = _Values(file, where, entry)
    name: str = v.get("name")
    if not NAME_PATTERN.match(name):
        raise InputError(
            file,
            f"{where}: name {name!r} is not a plain identifier",
            f"use letters, digits, - and _ (at most {C.SHOT_NAME_MAX}, starting with a letter or digit), e.g. sh010",
        )
    folder = file.parent
    plate = v.path("plate", folder)
    _check_plate(file, where, plate)
    masks = tuple(v.path_list("masks", folder))
    for mask in masks:
        if not os.path.isdir(mask):
            raise InputError(file, f"{where}: mask folder {mask} does not exist", "fix 'masks' (relative to this file)")
    auto: bool = v.get("auto_masks", False)
    if auto and masks:
        raise InputError(file, f"{where}: both 'masks' and 'auto_masks'", "drop one: given masks or found ones")
    parts: bool | None = v.get("auto_parts")
    if parts and len(masks) != 1:
        raise InputError(
            file,
            f"{where}: 'auto_parts' splits one object, but the shot has {len(masks)} mask folder(s)",
            "give 'masks' exactly one folder (the whole object), or drop 'auto_parts'",
        )
    preset: str = v.get("preset", DEFAULT_PRESET)
    overrides = tuple(v.get("set", []))
    model = _check_overrides(file, where, preset, overrides)
    if parts and model == "paper":  # the paper preset, or a set model=paper
        raise InputError(
            file,
            f"{where}: 'auto_parts' with the paper model, which fits one background and one foreground layer",
            "use a fast preset (draft, balanced or final) without model=paper, or drop 'auto_parts'",
        )
    device = v.get("device")
    fps = v.rate("fps")
    colorspace = v.get("colorspace")
    if colorspace is not None:
        _check_colorspace(file, where, colorspace)
    atlas_size = v.get("atlas_size")
    run = v.optional_path("run", folder) or _utf8_path(file, where, "run", os.path.join(folder, RUNS_DIR, name))
    render = v.optional_path("render", folder)
    return Shot(
        name=name,
        plate=plate,
        run=run,
        masks=masks,
        auto_masks=auto,
        auto_parts=parts,
        frames=v.frames("frames"),
        colorspace=colorspace,
        fps=fps,
        start_frame=v.get("start_frame"),
        render=render,
        preset=preset,
        set=overrides,
        device=device,
        atlas_size=atlas_size,
        export_chunk=v.get("export_chunk", DEFAULT_EXPORT_CHUNK) or DEFAULT_EXPORT_CHUNK,
        render_chunk=v.get("render_chunk", DEFAULT_RENDER_CHUNK) or DEFAULT_RENDER_CHUNK,
        render_format=v.get("render_format"),
        preview=v.get("preview", True),
        follow_flow=v.get("follow_flow", True),
    )


def _check_plate(file: Path, where: str, plate: str) -> None:
    """The plate exists (a folder or a movie), or is a pattern whose folder exists; what is in it the plan reads."""
    from ..io.clip import is_sequence_pattern

    if os.path.exists(plate):
        return
    if is_sequence_pattern(plate) and os.path.isdir(os.path.dirname(plate)):
        return
    raise InputError(
        file,
        f"{where}: plate {plate} does not exist",
        "fix 'plate' (a folder of frames, a pattern such as plate.####.exr, or a movie; relative to this file)",
    )


def _check_overrides(file: Path, where: str, preset: str, overrides: tuple[str, ...]) -> str:
    """Each ``set`` entry as ``fit --set`` takes it: a known config key with a value of its type; the model the
    shot's fit builds."""
    from ..config import apply_overrides, parse_set_args, preset_config

    try:
        return apply_overrides(preset_config(preset), parse_set_args(list(overrides))).model
    except InputError as exc:
        raise InputError(file, f"{where}: 'set': {exc.problem}", exc.fix) from None


def _check_colorspace(file: Path, where: str, name: str) -> None:
    """The colour space as the workers' fit resolves it (the OCIO config in ``$OCIO``, else the built-in one):
    a name the config does not know fails here, not an hour into the farm."""
    from ..io.colour import resolve

    try:
        resolve(name, option="colorspace")
    except InputError as exc:
        raise InputError(file, f"{where}: 'colorspace' {_shown(name)}: {exc.path}: {exc.problem}", exc.fix) from None


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
            seen = "" if plain else f" (through links: {_shown(mine)} and {_shown(theirs)})"
            raise InputError(
                file,
                f"shot {shot.name!r}: the {what} {_shown(path)} {relation} {whose} {other_what} "
                f"{_shown(other_path)}{seen}",
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


class _Values:
    """A shot's values, each validated by its declaration (engine/farm/shots_model.py) with a one-line error naming
    the shot and the key; paths are made absolute against the shots file's folder."""

    def __init__(self, file: Path, where: str, table: dict[str, Any]) -> None:
        self.file, self.where, self.table = file, where, table

    def get(self, key: str, default: Any = None) -> Any:
        """The value of ``key`` as its declaration validates it; ``default`` when the table does not give it."""
        return check(self.file, self.where, key, self.table[key]) if key in self.table else default

    def path(self, key: str, folder: Path) -> str:
        return _utf8_path(self.file, self.where, key, _absolute(self.get(key), folder))

    def optional_path(self, key: str, folder: Path) -> str | None:
        return self.path(key, folder) if key in self.table else None

    def path_list(self, key: str, folder: Path) -> list[str]:
        return [_utf8_path(self.file, self.where, key, _absolute(p, folder)) for p in self.get(key, [])]

    def rate(self, key: str) -> str | None:
        """fps: a number or a string (``24``, ``23.976``, ``"24000/1001"``), kept as fit --fps takes it."""
        if key not in self.table:
            return None
        text = str(self.get(key))
        from ..io.timing import parse_rate

        try:
            parse_rate(text)  # within timing.RATE_RANGE: a tiny rate would round to 0 fps, a huge one overflow
        except ValueError as exc:
            raise InputError(self.file, f"{self.where}: 'fps': {exc}", 'write e.g. fps = "24000/1001"') from None
        return text

    def frames(self, key: str) -> tuple[int, int] | None:
        """``"1001-1100"`` (or ``"1001:1100"``, or one frame): inclusive plate frame numbers, FIRST <= LAST."""
        if key not in self.table:
            return None
        value = str(self.get(key))
        match = re.fullmatch(r"\s*(\d+)\s*(?:[-:]\s*(\d+)\s*)?", value)
        if match is None:
            raise InputError(
                self.file,
                f"{self.where}: 'frames' is {value!r}",
                'write FIRST-LAST in the plate\'s frame numbers, e.g. frames = "1001-1100"',
            )
        first = int(match.group(1))
        last = int(match.group(2)) if match.group(2) is not None else first
        if first > last:
            raise InputError(
                self.file, f"{self.where}: 'frames' {value!r} is reversed", f'write frames = "{last}-{first}"'
            )
        return first, last


def _utf8_path(file: Path, where: str, key: str, path: str) -> str:
    """``path`` when it is UTF-8 text: a relative path's folder (the shots file's) may not be, as its text was."""
    try:
        path.encode("utf-8")
    except UnicodeEncodeError:
        raise not_utf8(file, where, key, path) from None
    return path


def _absolute(path: str, folder: Path) -> str:
    """``path`` (``~`` expanded) against the shots file's folder, normalised, absolute."""
    return os.path.normpath(os.path.join(folder, os.path.expanduser(path)))


__all__ = ["DEFAULT_EXPORT_CHUNK", "DEFAULT_PRESET", "DEFAULT_RENDER_CHUNK", "Shot", "ShotsFile", "load_shots"]
