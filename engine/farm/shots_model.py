"""The shots file's tables, each declared once: ``ShotDefaults`` (the ``[defaults]`` table) and ``ShotTable`` (one
``[[shots]]`` entry) as pydantic models naming every key with its type, bounds and choices, and ``check``, which
validates one key's value against its declaration and turns pydantic's ``ValidationError`` into the shots file's
one-line message (``refusal``).

engine/farm/shots.py reads a shot one key at a time, in a fixed order that mixes these declared checks with what no
declaration says (the plate and the mask folders exist, ``masks`` and ``auto_masks`` exclude each other), so a file
with several mistakes is always refused for the same one first. Values are strict, as TOML and JSON write them: a
bool is no number, a float no count, text is not blank, and a key is given or left out (a JSON null is a value of
the wrong type). Text that names something the farm's job files carry is UTF-8 (``Utf8Text``).
"""

from __future__ import annotations

import difflib
import reprlib
import unicodedata
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, get_args, get_origin

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, TypeAdapter, ValidationError
from pydantic.fields import FieldInfo
from pydantic.types import StrictBool, StrictFloat, StrictInt, StrictStr
from pydantic_core import ErrorDetails, PydanticCustomError

from .. import contract as C
from ..errors import InputError

#: What a shot gets for a key neither it nor the defaults give.
DEFAULT_PRESET = "balanced"
DEFAULT_EXPORT_CHUNK = 50
DEFAULT_RENDER_CHUNK = 50
RenderFormat = Literal["exr", "png", "plate"]
#: render --format's choices.
RENDER_FORMATS: tuple[str, ...] = get_args(RenderFormat)
#: --device's choices: exactly what the engine's fit and export take (engine/fit/device.py), so the plan refuses
#: what a worker would (a GPU of several is chosen with CUDA_VISIBLE_DEVICES on the worker, not cuda:N).
DEVICES: tuple[str, ...] = ("auto", "cpu", "cuda", "mps")
if TYPE_CHECKING:
    Preset = str
else:  # the contract's presets (the add-on's menu reads them too), as pydantic's choices
    Preset = Literal[tuple(C.PRESET_STEPS)]


@dataclass(frozen=True)
class Refusal:
    """How the refusal of a key's value reads: ``wanted`` (its type in words) and ``example`` (a value of it, in the
    fix) for a value of another type; for a value outside its declared range or choices, ``note`` ends the fix and
    ``suggest`` names the nearest choice."""

    wanted: str = ""
    example: str = ""
    note: str = ""
    suggest: bool = True


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


def _utf8(value: str) -> str:
    """Refuse text that is not UTF-8 (a name read from a non-UTF-8 file system): the farm's job files (JSON,
    OpenJD templates, Flamenco's settings) are UTF-8 text and cannot carry it."""
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:
        raise PydanticCustomError("utf8", "not UTF-8 text") from None
    return value


_Text = Annotated[StrictStr, AfterValidator(_not_blank)]
#: Text that names something (a shot, a path, a colour space): not blank, UTF-8.
Utf8Text = Annotated[_Text, AfterValidator(_utf8), Refusal("a non-empty string", '"..."')]
Paths = Annotated[list[Utf8Text], Refusal("a list of strings", '["a", "b"]')]
Overrides = Annotated[list[_Text], Refusal("a list of strings", '["steps=2000"]')]
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
Chunk = Annotated[StrictInt, Field(ge=1), Refusal("a whole number", "50")]
StartFrame = Annotated[StrictInt, Field(ge=0, le=C.MAX_START_FRAME), Refusal("a whole number", "1001")]
AtlasSize = Annotated[
    StrictInt,
    Field(ge=C.ATLAS_SIZE_RANGE[0], le=C.ATLAS_SIZE_RANGE[1]),
    Refusal("a whole number", str(C.ATLAS_SIZE_RANGE[0] * 50), note=" (paper: 1000)"),
]
#: fps: a number or a string (``24``, ``23.976``, ``"24000/1001"``), kept as fit --fps takes it.
Rate = Annotated[StrictInt | StrictFloat | StrictStr, Refusal("a frame rate", '"24000/1001"')]
#: ``"1001-1100"`` (or ``"1001:1100"``, or one frame, also as a number).
FrameRange = Annotated[StrictInt | StrictStr, Refusal("a FIRST-LAST string", '"1001-1100"')]


class ShotDefaults(BaseModel):
    """``[defaults]``: the keys a shot takes from the file when it does not give them (``contract.SHOT_DEFAULT_KEYS``;
    a shot's own value wins). A key left out has no value; the shot's default is what ``Shot`` says."""

    model_config = ConfigDict(extra="forbid")

    preset: Preset = DEFAULT_PRESET
    set: Overrides = Field(default_factory=list)
    device: Annotated[Device, Field(default=None)]
    atlas_size: Annotated[AtlasSize, Field(default=None)]
    export_chunk: Chunk = DEFAULT_EXPORT_CHUNK
    render_chunk: Chunk = DEFAULT_RENDER_CHUNK
    render_format: Annotated[RenderFormat, Field(default=None)]
    preview: Flag = True
    follow_flow: Flag = True


class ShotTable(ShotDefaults):
    """One ``[[shots]]`` table: its own keys (``contract.SHOT_KEYS``) besides the defaults'."""

    name: Utf8Text
    plate: Utf8Text
    masks: Paths = Field(default_factory=list)
    auto_masks: Flag = False
    auto_parts: Annotated[Flag, Field(default=None)]
    frames: Annotated[FrameRange, Field(default=None)]
    colorspace: Annotated[Utf8Text, Field(default=None)]
    fps: Annotated[Rate, Field(default=None)]
    start_frame: Annotated[StartFrame, Field(default=None)]
    run: Annotated[Utf8Text, Field(default=None)]
    render: Annotated[Utf8Text, Field(default=None)]


#: The declarations name the contract's keys, no more, no fewer (the add-on writes the file from the contract's).
if set(ShotDefaults.model_fields) != set(C.SHOT_DEFAULT_KEYS) or set(ShotTable.model_fields) != set(C.SHOT_KEYS):
    raise ImportError("the shots file's declared keys differ from contract.SHOT_KEYS")


@dataclass(frozen=True)
class _Declared:
    """One key's declaration, ready to validate a value: its validator, its refusal's words, its bounds, its
    choices."""

    check: TypeAdapter[Any]
    refusal: Refusal
    low: Any
    high: Any
    choices: tuple[str, ...]


def _declared(info: FieldInfo) -> _Declared:
    """A model field's declaration as one validator (its type with every rule it is annotated with) and what its
    refusal needs to say."""
    rules = list(info.metadata)
    declared: Any = Annotated[(info.annotation, *rules)] if rules else info.annotation
    refusal = next((r for r in reversed(rules) if isinstance(r, Refusal)), Refusal())
    low = next((r.ge for r in rules if getattr(r, "ge", None) is not None), None)
    high = next((r.le for r in rules if getattr(r, "le", None) is not None), None)
    one_of = [r.func for r in rules if isinstance(r, AfterValidator) and isinstance(r.func, OneOf)]
    choices = get_args(info.annotation) if get_origin(info.annotation) is Literal else ()
    return _Declared(TypeAdapter(declared), refusal, low, high, one_of[0].choices if one_of else choices)


#: Every key's declaration, validated one value at a time.
_KEYS: dict[str, _Declared] = {key: _declared(info) for key, info in ShotTable.model_fields.items()}


def check(file: Path, where: str, key: str, value: Any) -> Any:
    """``value`` of ``key`` as its declaration validates it, or the one-line ``InputError`` of ``refusal``."""
    try:
        return _KEYS[key].check.validate_python(value)
    except ValidationError as exc:
        raise refusal(file, where, key, value, exc.errors()) from None


def refusal(file: Path, where: str, key: str, value: Any, errors: list[ErrorDetails]) -> InputError:
    """The one line for ``value`` of ``key`` that its declaration refuses (the adapter from pydantic's errors): a
    value of another type (before text that is not UTF-8: a list's every item has its type checked first), then
    text that is not UTF-8, a number outside its bounds, a value outside its choices."""
    declared = _KEYS[key]
    error = sorted(errors, key=lambda e: e["type"] == "utf8")[0]
    if declared.choices and error["type"] in ("choice", "literal_error", "string_unicode"):
        close = difflib.get_close_matches(str(value), declared.choices, n=1) if declared.refusal.suggest else []
        hint = f"did you mean {close[0]!r}? " if close else ""
        return InputError(
            file,
            f"{where}: '{key}' is {value!r}",
            f"{hint}use one of {', '.join(declared.choices)}{declared.refusal.note}",
        )
    if error["type"] == "utf8":
        return not_utf8(file, where, key, error["input"])
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


def not_utf8(file: Path, where: str, key: str, text: str) -> InputError:
    """The one line for ``text`` of ``key`` that is not UTF-8."""
    return InputError(
        file,
        f"{where}: '{key}' {shown(text)} is not UTF-8 text",
        "rename the file or folder with UTF-8 characters (farm job files are UTF-8 text)",
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
    "DEFAULT_PRESET",
    "DEFAULT_RENDER_CHUNK",
    "DEVICES",
    "RENDER_FORMATS",
    "ShotDefaults",
    "ShotTable",
    "check",
    "not_utf8",
    "refusal",
    "shown",
]
