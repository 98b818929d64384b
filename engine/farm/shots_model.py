"""A shot of the shots file, declared once: ``Shot`` names every key with its type, bounds and choices and the
checks no type makes (the plate and the mask folders exist, ``masks`` and ``auto_masks`` exclude each other, the
``set`` overrides and the colour space are the fit's), and the validated model is the shot the plan reads, every
path absolute and every default filled in. ``refusal`` turns pydantic's ``ValidationError`` into the shots file's
one line (the file, the shot, the key, the fix).

The keys are declared in the order they are checked, a check across keys seeing only the keys before it (pydantic's
``info.data``), and a refusal names the first key refused: a file with several mistakes is always refused for the
same one. Values are strict, as TOML and JSON write them: a bool is no number, a float no count, text is not blank,
and a key is given or left out (a JSON null is a value of the wrong type). Text that names something the farm's job
files carry is UTF-8 (``Utf8Text``). Relative paths resolve against the shots file's folder, the validation's
context (``FOLDER``).
"""

from __future__ import annotations

import difflib
import os
import re
import reprlib
import unicodedata
from dataclasses import dataclass
from pathlib import Path
from types import UnionType
from typing import TYPE_CHECKING, Annotated, Any, Literal, Union, get_args, get_origin

from annotated_types import Ge, Interval
from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PlainValidator,
    ValidationError,
    ValidationInfo,
    model_validator,
)
from pydantic.fields import FieldInfo
from pydantic.types import StrictBool, StrictInt, StrictStr
from pydantic_core import PydanticCustomError

from .. import contract as C
from ..errors import InputError
from ..terms.cli import DEFAULT_PRESET
from ..terms.clip import MAX_START_FRAME
from ..terms.export_names import ATLAS_SIZE_RANGE
from ..terms.farm import SHOT_REQUIRED_KEYS

#: What a shot gets for a key neither it nor the defaults give (the preset: ``terms.cli.DEFAULT_PRESET``).
DEFAULT_EXPORT_CHUNK = 50
DEFAULT_RENDER_CHUNK = 50
RenderFormat = Literal["exr", "png", "plate"]
#: ``export --pass-precision`` (``terms.export_names.PASS_PRECISIONS``; a test keeps the two equal).
PassPrecision = Literal["compact", "full"]
#: --device's choices: exactly what the engine's fit and export take (engine/fit/device.py), so the plan refuses
#: what a worker would (a GPU of several is chosen with CUDA_VISIBLE_DEVICES on the worker, not cuda:N).
DEVICES: tuple[str, ...] = ("auto", "cpu", "cuda", "mps")
if TYPE_CHECKING:
    Preset = str
else:  # the contract's presets (the add-on's menu reads them too), as pydantic's choices
    Preset = Literal[tuple(C.PRESET_STEPS)]
#: A shot's name becomes task ids, OpenJD step names and a folder name: a portable, short identifier.
NAME_PATTERN = re.compile(rf"^[A-Za-z0-9][A-Za-z0-9_-]{{0,{C.SHOT_NAME_MAX - 1}}}$")
#: Where a shot's run folder goes when the shot names none, relative to the shots file.
RUNS_DIR = "runs"
#: The validation context's key for the shots file's folder, which relative paths resolve against.
FOLDER = "folder"


@dataclass(frozen=True)
class Refusal:
    """How the refusal of a key's value reads: ``wanted`` (its type in words) and ``example`` (a value of it, in the
    fix) for a value of another type; for a value outside its declared range or choices, ``note`` ends the fix and
    ``suggest`` names the nearest choice."""

    wanted: str = ""
    example: str = ""
    note: str = ""
    suggest: bool = True


def refused(problem: str, fix: str) -> PydanticCustomError:
    """A check's refusal in the words of the one line (after the shot), for ``refusal`` to pass on as they are."""
    return PydanticCustomError("refused", "{problem}", {"problem": problem, "fix": fix})


def _wrong_type() -> PydanticCustomError:
    """A value of another type than a plain validator takes: ``refusal`` words it from the key's ``Refusal``."""
    return PydanticCustomError("wrong_type", "a value of another type")


@dataclass(frozen=True)
class OneOf:
    """A text value's choices, checked once its type (and its encoding) is: a value of another type is refused as
    that, not as a choice."""

    choices: tuple[str, ...]

    def __call__(self, value: str) -> str:
        if value not in self.choices:
            raise PydanticCustomError("choice", "not one of the choices")
        return value


def _not_blank(value: str) -> str:
    if not value.strip():
        raise ValueError("blank")
    return value


def _utf8(value: str, info: ValidationInfo) -> str:
    """Refuse text that is not UTF-8 (a name read from a non-UTF-8 file system, or a relative path's folder): the
    farm's job files (JSON, OpenJD templates, Flamenco's settings) are UTF-8 text and cannot carry it."""
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        raise refused(
            f"'{info.field_name}' {shown(value)} is not UTF-8 text",
            "rename the file or folder with UTF-8 characters (farm job files are UTF-8 text)",
        ) from None
    return value


def _absolute(path: str, info: ValidationInfo) -> str:
    """``path`` (``~`` expanded) against the shots file's folder, normalised, absolute."""
    assert info.context is not None, "validate a Shot with context={FOLDER: the shots file's folder}"
    return _utf8(os.path.normpath(os.path.join(info.context[FOLDER], os.path.expanduser(path))), info)


def _plain_name(name: str) -> str:
    if not NAME_PATTERN.match(name):
        raise refused(
            f"name {name!r} is not a plain identifier",
            f"use letters, digits, - and _ (at most {C.SHOT_NAME_MAX}, starting with a letter or digit), e.g. sh010",
        )
    return name


def _plate_exists(plate: str) -> str:
    """The plate exists (a folder or a movie), or is a pattern whose folder exists; what is in it the plan reads."""
    from ..io.sequences import is_sequence_pattern

    if os.path.exists(plate) or (is_sequence_pattern(plate) and os.path.isdir(os.path.dirname(plate))):
        return plate
    raise refused(
        f"plate {plate} does not exist",
        "fix 'plate' (a folder of frames, a pattern such as plate.####.exr, or a movie; relative to this file)",
    )


def _absolute_all(paths: tuple[str, ...], info: ValidationInfo) -> tuple[str, ...]:
    return tuple(_absolute(path, info) for path in paths)


def _folders_exist(masks: tuple[str, ...]) -> tuple[str, ...]:
    for mask in masks:
        if not os.path.isdir(mask):
            raise refused(f"mask folder {mask} does not exist", "fix 'masks' (relative to this file)")
    return masks


def _not_with_masks(auto: bool, info: ValidationInfo) -> bool:
    if auto and info.data.get("masks"):
        raise refused("both 'masks' and 'auto_masks'", "drop one: given masks or found ones")
    return auto


def _one_object(parts: bool | None, info: ValidationInfo) -> bool | None:
    masks = info.data.get("masks", ())
    if parts and len(masks) != 1:
        raise refused(
            f"'auto_parts' splits one object, but the shot has {len(masks)} mask folder(s)",
            "give 'masks' exactly one folder (the whole object), or drop 'auto_parts'",
        )
    return parts


def _fit_overrides(overrides: tuple[str, ...], info: ValidationInfo) -> tuple[str, ...]:
    """Each ``set`` entry as ``fit --set`` takes it, on the shot's preset: a known config key with a value of its
    type; and the model that builds fits ``auto_parts``."""
    from ..config import apply_overrides, parse_set_args, preset_config

    if "preset" not in info.data:  # refused already
        return overrides
    try:
        model = apply_overrides(preset_config(info.data["preset"]), parse_set_args(list(overrides))).model
    except InputError as exc:
        raise refused(f"'set': {exc.problem}", exc.fix) from None
    if info.data.get("auto_parts") and model == "paper":  # the paper preset, or a set model=paper
        raise refused(
            "'auto_parts' with the paper model, which fits one background and one foreground layer",
            "use a fast preset (draft, balanced or final) without model=paper, or drop 'auto_parts'",
        )
    return overrides


def _rate(value: Any) -> str:
    """fps: a number or a string (``24``, ``23.976``, ``"24000/1001"``), kept as fit --fps takes it; within
    timing.RATE_RANGE (a tiny rate would round to 0 fps, a huge one overflow)."""
    from ..io.timing import parse_rate

    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise _wrong_type()
    try:
        parse_rate(str(value))
    except ValueError as exc:
        raise refused(f"'fps': {exc}", 'write e.g. fps = "24000/1001"') from None
    return str(value)


def _known_colorspace(name: str) -> str:
    """The colour space as the workers' fit resolves it (the OCIO config in ``$OCIO``, else the built-in one): a
    name the config does not know fails here, not an hour into the farm."""
    from ..io.colour import resolve

    try:
        resolve(name, option="colorspace")
    except InputError as exc:
        raise refused(f"'colorspace' {shown(name)}: {exc.path}: {exc.problem}", exc.fix) from None
    return name


def _default_run(run: Any, info: ValidationInfo) -> Any:
    """No ``run``: ``runs/<name>`` beside the shots file."""
    return os.path.join(RUNS_DIR, info.data["name"]) if run is None and "name" in info.data else run


def _frames(value: Any) -> tuple[int, int]:
    """The plate's frame numbers, read as ``--frames`` is (``timing.parse_frames``); one frame may be a number."""
    from ..io.timing import ReversedFrames, parse_frames

    if isinstance(value, bool) or not isinstance(value, int | str):
        raise _wrong_type()
    try:
        return parse_frames(str(value))
    except ReversedFrames as exc:
        raise refused(f"'frames' {str(value)!r} is reversed", f'write frames = "{exc}"') from None
    except ValueError:
        raise refused(
            f"'frames' is {str(value)!r}", 'write FIRST-LAST in the plate\'s frame numbers, e.g. frames = "1001-1100"'
        ) from None


_Text = Annotated[StrictStr, AfterValidator(_not_blank)]
#: Text that names something (a shot, a path, a colour space): not blank, UTF-8.
Utf8Text = Annotated[_Text, AfterValidator(_utf8), Refusal("a non-empty string", '"..."')]
#: A path in the file: absolute once read.
PathText = Annotated[Utf8Text, AfterValidator(_absolute)]
Paths = Annotated[tuple[Utf8Text, ...], AfterValidator(_absolute_all), Refusal("a list of strings", '["a", "b"]')]
Overrides = Annotated[tuple[_Text, ...], Refusal("a list of strings", '["steps=2000"]')]
Device = Annotated[
    Utf8Text,
    AfterValidator(OneOf(DEVICES)),
    Refusal(
        "a non-empty string",
        '"..."',
        note=" (pick one GPU of several with CUDA_VISIBLE_DEVICES on the worker)",
        suggest=False,
    ),
]
Flag = Annotated[StrictBool, Refusal("true or false", "true")]
Chunk = Annotated[StrictInt, Ge(1), Refusal("a whole number", "50")]
StartFrame = Annotated[StrictInt, Interval(ge=0, le=MAX_START_FRAME), Refusal("a whole number", "1001")]
AtlasSize = Annotated[
    StrictInt,
    Interval(ge=ATLAS_SIZE_RANGE[0], le=ATLAS_SIZE_RANGE[1]),
    Refusal("a whole number", str(ATLAS_SIZE_RANGE[0] * 50), note=" (paper: 1000)"),
]
#: fps as fit --fps takes it: ``24``, ``23.976`` or ``"24000/1001"``, kept as text.
Rate = Annotated[str, PlainValidator(_rate), Refusal("a frame rate", '"24000/1001"')]
#: ``"1001-1100"`` (or ``"1001:1100"``, or one frame, also as a number): inclusive, FIRST <= LAST.
FrameRange = Annotated[tuple[int, int], PlainValidator(_frames), Refusal("a FIRST-LAST string", '"1001-1100"')]
#: A JSON null given for a key: a value no key's type takes, refused as a value of the wrong type.
_NULL = object()


class Shot(BaseModel):
    """One ``[[shots]]`` table with the ``[defaults]`` it does not override (any of ``terms.farm.SHOT_DEFAULT_KEYS``):
    the keys of ``contract.SHOT_KEYS``, in the order they are checked. Validated with ``context={FOLDER: the shots
    file's folder}``, it is the shot the plan reads: every path absolute, every default filled in."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: Annotated[Utf8Text, AfterValidator(_plain_name)]
    plate: Annotated[PathText, AfterValidator(_plate_exists)]
    """A folder of frames, a sequence pattern or a movie file."""
    masks: Annotated[Paths, AfterValidator(_folders_exist)] = ()
    auto_masks: Annotated[Flag, AfterValidator(_not_with_masks)] = False
    auto_parts: Annotated[Flag | None, AfterValidator(_one_object)] = None
    """The one mask's object split into the parts that move apart when the fit starts: True ``fit --auto-parts``
    (refused where it cannot apply), False ``--no-auto-parts``, None (not given) the fit's default: wherever it
    applies."""
    preset: Preset = DEFAULT_PRESET
    set: Annotated[Overrides, AfterValidator(_fit_overrides)] = Field(default=(), validate_default=True)
    device: Device | None = None
    fps: Rate | None = None
    colorspace: Annotated[Utf8Text, AfterValidator(_known_colorspace)] | None = None
    atlas_size: AtlasSize | None = None
    run: Annotated[PathText, BeforeValidator(_default_run)] = Field(default=None, validate_default=True)
    """The shot's run folder: the fit, its exports and, with auto_masks, the found masks."""
    render: PathText | None = None
    """A folder for the rendered frames; None: no render tasks."""
    frames: FrameRange | None = None
    """Inclusive, in the plate's frame numbers; None: every frame."""
    start_frame: StartFrame | None = None
    export_chunk: Chunk = DEFAULT_EXPORT_CHUNK
    render_chunk: Chunk = DEFAULT_RENDER_CHUNK
    render_format: RenderFormat | None = None
    preview: Flag = True
    follow_flow: Flag = True
    """False: the export's UV as fitted (``export --no-follow-flow``); True: the export's default."""
    pass_precision: PassPrecision | None = None
    """``export --pass-precision``: the bits the pass files keep; None: the export's default (compact)."""
    stmap: Flag = False
    """True: ``export --stmap`` (an STMap copy of each layer's UV in the pass files, for Nuke artists)."""

    @model_validator(mode="before")
    @classmethod
    def _given(cls, table: Any) -> Any:
        """A key is given or left out: a null given is a value no type takes (the defaults are for keys left out)."""
        return {key: _NULL if value is None else value for key, value in table.items()}


@dataclass(frozen=True)
class _Declared:
    """What a key's refusal needs to say: its refusal's words, its bounds, its choices."""

    refusal: Refusal
    low: Any
    high: Any
    choices: tuple[str, ...]


def _declared(info: FieldInfo) -> _Declared:
    """A model field's declaration, through ``| None``, as its refusal needs it."""
    kind, rules = info.annotation, list(info.metadata)
    if get_origin(kind) in (Union, UnionType):  # X | None: X's declaration
        kind = next(arm for arm in get_args(kind) if arm is not type(None))
        if get_origin(kind) is Annotated:
            kind, *more = get_args(kind)
            rules = [*more, *rules]
    refusal = next((r for r in reversed(rules) if isinstance(r, Refusal)), Refusal())
    low = next((r.ge for r in rules if getattr(r, "ge", None) is not None), None)
    high = next((r.le for r in rules if getattr(r, "le", None) is not None), None)
    one_of = [r.func for r in rules if isinstance(r, AfterValidator) and isinstance(r.func, OneOf)]
    choices = get_args(kind) if get_origin(kind) is Literal else ()
    return _Declared(refusal, low, high, one_of[0].choices if one_of else choices)


#: Every key's declaration, as its refusal needs it.
_KEYS: dict[str, _Declared] = {key: _declared(info) for key, info in Shot.model_fields.items()}


def refusal(file: Path, where: str, table: dict[str, Any], exc: ValidationError) -> InputError:
    """The one line for the first key of ``table`` (a shot ``where`` of ``file``) that ``Shot`` refuses: a required
    key left out first; then, of the first key refused, a value of another type (before text that is not UTF-8: a
    list's every item has its type checked first), a check's own words, a number outside its bounds, a value
    outside its choices."""
    errors = exc.errors()
    missing = [e for e in errors if e["type"] == "missing"]
    if missing:
        return InputError(
            file, f"{where}: no '{missing[0]['loc'][0]}'", f"give every shot a {' and a '.join(SHOT_REQUIRED_KEYS)}"
        )
    key = str(errors[0]["loc"][0])
    error = sorted((e for e in errors if e["loc"][0] == key), key=lambda e: e["type"] == "refused")[0]
    declared, value = _KEYS[key], table.get(key)
    if error["type"] == "refused":
        return InputError(file, f"{where}: {error['ctx']['problem']}", error["ctx"]["fix"])
    if declared.choices and error["type"] in ("choice", "literal_error", "string_unicode"):
        close = difflib.get_close_matches(str(value), declared.choices, n=1) if declared.refusal.suggest else []
        hint = f"did you mean {close[0]!r}? " if close else ""
        return InputError(
            file,
            f"{where}: '{key}' is {value!r}",
            f"{hint}use one of {', '.join(declared.choices)}{declared.refusal.note}",
        )
    if error["type"] == "greater_than_equal":
        return InputError(file, f"{where}: '{key}' is {value}", f"give {key} a number >= {declared.low}")
    if error["type"] == "less_than_equal":
        bounds = f"{declared.low}..{declared.high}{declared.refusal.note}"
        return InputError(file, f"{where}: '{key}' is {value}", f"give {key} {bounds}")
    return InputError(
        file,
        f"{where}: '{key}' is {type(value).__name__} {_SHORT.repr(value)}, not {declared.refusal.wanted}",
        f"write e.g. {key} = {declared.refusal.example}",
    )


#: Values in messages: long or deeply nested ones cut short, so the message stays one short line.
_SHORT = reprlib.Repr()
_SHORT.maxlevel, _SHORT.maxstring, _SHORT.maxother = 3, 80, 80


def shown(text: str) -> str:
    """``text`` for a one-line message: control characters (a newline in a folder's name) and bytes that are not
    UTF-8 written as escapes, everything else as it is."""
    text = text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    return "".join(f"\\x{ord(c):02x}" if unicodedata.category(c) == "Cc" else c for c in text)


__all__ = [
    "DEFAULT_EXPORT_CHUNK",
    "DEFAULT_RENDER_CHUNK",
    "DEVICES",
    "FOLDER",
    "RUNS_DIR",
    "Shot",
    "refusal",
    "shown",
]
