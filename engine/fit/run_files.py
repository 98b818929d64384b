"""The run folder's JSON files, each declared once: ``config.json``, ``clip.json``, ``metrics.json`` and
``scene.json`` as pydantic models, and the one check every read and write of them goes through
(``validate_run_file``), whose refusal is one line.

Each file carries ``{"schema": <its version>}`` (``terms.run_folder.RUN_*_SCHEMA``), bumped whenever its shape changes;
a reader refuses any other version (the run was made by another engine: fit again). engine/fit/run_folder.py is the one
module that reads and writes them. A model names every key of its file with its type (strict: a bool is not a number, a
list is not a tuple), refuses keys it does not name, and checks what its fields say of each other; the add-on never
reads these files, so the contract it imports stays standard-library only. The shapes:

- ``terms.run_folder.RUN_CONFIG``: ``{"schema": 1, "config": {FitConfig field: value}}`` (engine/config.py documents and
  checks every field).
- ``terms.run_folder.RUN_CLIP``: ``ClipFile``. Everything ``export`` needs besides the checkpoint: it never decodes the
  plate. "frame_range" is in positions (what ``open_clip`` takes); "frame_numbers" are the plate's own numbers (what
  --frames says).
- ``contract.RUN_METRICS``: ``MetricsFile``.
- ``terms.run_folder.SCENE_FILE``: ``SceneFile`` (``terms.manifest.validate_scene`` checks the copy in a manifest).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Annotated, Any, TypeVar

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    StrictFloat,
    StrictInt,
    StrictStr,
    ValidationError,
    ValidatorFunctionWrapHandler,
    model_validator,
)
from pydantic_core import PydanticCustomError

from .. import contract as C
from ..terms.colour import COLOUR_SOURCE_ASKED, COLOUR_SOURCES, valid_colour_record
from ..terms.manifest import MANIFEST_QUOTE_CHARS, timing_problem
from ..terms.run_folder import (
    BG_MOTIONS,
    FLOW_KEY_PATTERN,
    RUN_CLIP,
    RUN_CLIP_SCHEMA,
    RUN_CONFIG,
    RUN_CONFIG_SCHEMA,
    RUN_FILE_DAMAGED_FIX,
    RUN_FILE_OTHER_VERSION_FIX,
    RUN_METRICS_SCHEMA,
    RUN_SCENE_SCHEMA,
    SCENE_FILE,
    SCENE_LAYERS_AUTO,
    SCENE_LAYERS_GIVEN,
    SCENE_LAYERS_NONE,
)


@dataclass(frozen=True)
class Kind:
    """A field's type in the words a refusal uses: "str", "int", "number" (int or float), "bool", "dict",
    "<type> list", "<type> pair" (a list of two), and "... or null"."""

    words: str


Str = Annotated[StrictStr, Kind("str")]
StrOrNull = Annotated[StrictStr | None, Kind("str or null")]
Int = Annotated[StrictInt, Kind("int")]
Number = Annotated[StrictInt | StrictFloat, Kind("number")]
NumberOrNull = Annotated[StrictInt | StrictFloat | None, Kind("number or null")]
Bool = Annotated[StrictBool, Kind("bool")]
Dict = Annotated[dict[str, Any], Kind("dict")]
StrList = Annotated[list[StrictStr], Kind("str list")]
StrOrNullList = Annotated[list[StrictStr | None], Kind("str or null list")]
IntList = Annotated[list[StrictInt], Kind("int list")]
NumberList = Annotated[list[StrictInt | StrictFloat], Kind("number list")]
_Pair = Annotated[list[StrictInt], Field(min_length=2, max_length=2)]
IntPair = Annotated[_Pair, Kind("int pair")]
IntPairOrNull = Annotated[_Pair | None, Kind("int pair or null")]

#: The scene analysis's ``components`` values (engine/config.py's ``components`` field).
RUN_SCENE_COMPONENTS: tuple[str, ...] = ("auto", "all")
RUN_SCENE_LAYERS_SOURCES: tuple[str, ...] = (SCENE_LAYERS_GIVEN, SCENE_LAYERS_AUTO, SCENE_LAYERS_NONE)


class RunFileError(ValueError):
    """A run-folder file that does not follow its schema: ``problem`` and ``fix``, one line each (the engine
    adds the file's path, as every one-line error does)."""

    def __init__(self, problem: str, fix: str) -> None:
        super().__init__(f"{problem} — {fix}")
        self.problem = problem
        self.fix = fix


def _problem(text: str) -> PydanticCustomError:
    """What a record's values say of each other, as the error its model raises (``validate_run_file`` unwraps it)."""
    return PydanticCustomError("run_file", "{problem}", {"problem": text})


def checked(data: Any, handler: ValidatorFunctionWrapHandler, check: Callable[[dict[str, Any]], str | None]) -> Any:
    """A model's check of its fields against each other, run on the file's own values once every field has its
    type (a refusal of a type comes first, as it names the key)."""
    model = handler(data)
    problem = check(data)
    if problem is not None:
        raise _problem(problem)
    return model


class RunFile(BaseModel):
    """A run file's keys besides "schema" (checked first, on its own: another version is another fix)."""

    model_config = ConfigDict(extra="forbid", strict=True)


#: A run file's model (``read_record``'s answer has its type).
_Record = TypeVar("_Record", bound=RunFile)


class ConfigFile(RunFile):
    """``config.json``: the fit's config (engine/config.py checks its fields: ``FitConfig.from_json``)."""

    config: Dict


def _clip_problem(data: dict[str, Any]) -> str | None:
    """What the clip record's fields say of each other (their types are checked already)."""
    count = len(data["frame_numbers"])
    first, last = data["frame_range"]
    problem = None
    if count < 1 or last - first + 1 != count:
        problem = f"clip record: frame_range {first}..{last} does not span its {count} frames"
    elif data["frame_files"] and len(data["frame_files"]) != count:
        problem = f"clip record lists {len(data['frame_files'])} frame files for {count} frames"
    elif data["kind"] not in C.CLIP_KINDS or not valid_colour_record(data["colorspace"], data.get("colour_config")):
        problem = f"clip record: unknown kind or colour space {data['kind']!r}, {data['colorspace']!r}"
    elif data.get("colour_source", COLOUR_SOURCE_ASKED) not in COLOUR_SOURCES:
        problem = f"clip record: unknown colour_source {data['colour_source'][:MANIFEST_QUOTE_CHARS]!r}"
    elif data["layers"] < 1 or min(data["native_size"] + data["working_size"]) < 1:
        problem = "clip record: layers and sizes must be positive"
    elif any(len(data.get(f"{k}_relative", data[k])) != len(data[k]) for k in ("frame_files", "masks")):
        problem = "clip record: its relative paths do not match its frame files and masks"
    elif data.get("flow_key") is not None and not re.fullmatch(FLOW_KEY_PATTERN, data["flow_key"]):
        problem = "clip record: flow_key is not the name of a flow cache file (64 hex digits)"
    else:
        problem = timing_problem(data)
        problem = problem and f"clip record: {problem}"
    return problem


class ClipFile(RunFile):
    """``clip.json`` (schema 2): what was fitted. Paths are absolute; the optional fields (a record without them is
    of square pixels, no exact rate, no timecode, a movie numbered from 0) come after the others."""

    source: Str
    kind: Str  # "sequence" | "movie" (contract.CLIP_KINDS)
    frame_range: IntPair  # [first, last]: inclusive positions in the source
    frame_numbers: IntList
    frame_files: StrList  # [] for a movie
    native_size: IntPair  # [W, H]
    working_size: IntPair  # [W, H]
    fps: NumberOrNull
    colorspace: Str
    """The plate's OCIO colour space; "sRGB"|"linear" in runs made before colour management."""
    masks: StrList  # folders
    scribbles: StrOrNull
    layers: Int  # background + foreground layers of the model
    fingerprint: Str  # hash of the fitted frames: a resume refuses a changed clip
    colour_config: Any = None
    """The OCIO config that names "colorspace" ($OCIO's path or "ocio://default"); absent in older runs (see
    contract.LEGACY_COLORSPACES). Checked with the colour space (``terms.colour.valid_colour_record``): no type of its
    own, so not among RUN_CLIP_OPTIONAL_FIELDS."""
    rate: IntPairOrNull = None  # exact frame rate [num, den] (24000/1001)
    pixel_aspect: Number = 1.0
    timecode: StrOrNull = None  # SMPTE, of the first fitted frame
    start_frame: Int = 0  # a movie's number of its first frame
    colour_source: Str = COLOUR_SOURCE_ASKED  # how "colorspace" was decided: one of terms.colour.COLOUR_SOURCES
    # the paths relative to the run folder ("/" separated; null: none, another drive), beside the absolute ones: a
    # run folder moved or mounted elsewhere with its plate reads the plate there (engine/fit/run_folder.py)
    source_relative: StrOrNull = None
    frame_files_relative: StrOrNullList = Field(default_factory=list)  # absent from records before they were kept
    masks_relative: StrOrNullList = Field(default_factory=list)
    scribbles_relative: StrOrNull = None
    scribbles_fingerprint: StrOrNull = None  # of the strokes read at working size: a resume keeps to them
    flow_key: StrOrNull = None  # the fit's flow in flow_cache/ (a SHA-256 in hex); absent from older records

    @model_validator(mode="wrap")
    @classmethod
    def values_agree(cls, data: Any, handler: ValidatorFunctionWrapHandler) -> Any:
        return checked(data, handler, _clip_problem)


class MetricsFile(RunFile):
    """``metrics.json``: the finished fit's measures."""

    psnr: Number
    mse: Number
    alpha_iou: NumberList  # one per mask
    steps: Int
    train_seconds: Number
    seconds_per_step: Number
    preset: Str
    model: Str
    device: Str
    working_size: IntPair
    frames: Int
    engine_version: Str
    torch_version: Str


def _scene_problem(data: dict[str, Any]) -> str | None:
    """What the scene analysis's values must be (their types are checked already): known choices, counts that
    can be, and one line of text or a number per reason and measurement."""
    problem = None
    if data["components"] not in RUN_SCENE_COMPONENTS:
        problem = f"scene analysis: unknown components {data['components']!r}"
    elif data["background_motion"] not in BG_MOTIONS:
        problem = f"scene analysis: unknown background_motion {data['background_motion']!r}"
    elif data["layers_source"] not in RUN_SCENE_LAYERS_SOURCES:
        problem = f"scene analysis: unknown layers_source {data['layers_source']!r}"
    elif data["num_layers"] < 1 or data["scribbles"] < 0:
        problem = "scene analysis: num_layers must be positive and scribbles not negative"
    elif not all(isinstance(v, str) for v in data["reasons"].values()):
        problem = "scene analysis: a reason is not text"
    elif not all(v is None or _is_number(v) for v in data["measured"].values()):
        problem = "scene analysis: a measurement is not a number or null"
    return problem


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


class SceneFile(RunFile):
    """``scene.json``: the scene analysis of the fit (engine.data.scene_analysis.SceneAnalysis;
    terms.run_folder.SCENE_FILE says what each field means)."""

    components: Str  # RUN_SCENE_COMPONENTS
    num_layers: Int
    layers_source: Str  # RUN_SCENE_LAYERS_SOURCES
    background_motion: Str  # terms.run_folder.BG_MOTIONS
    flow: Bool
    scribbles: Int
    alpha_network: Bool
    active_terms: StrList
    reasons: Dict  # {decision: one line}
    measured: Dict  # {name: number|null}
    overrides: StrList

    @model_validator(mode="wrap")
    @classmethod
    def values_agree(cls, data: Any, handler: ValidatorFunctionWrapHandler) -> Any:
        return checked(data, handler, _scene_problem)


#: Each run file's model.
RUN_FILE_MODELS: dict[str, type[RunFile]] = {
    RUN_CONFIG: ConfigFile,
    RUN_CLIP: ClipFile,
    C.RUN_METRICS: MetricsFile,
    SCENE_FILE: SceneFile,
}
RUN_FILE_SCHEMAS: dict[str, int] = {
    RUN_CONFIG: RUN_CONFIG_SCHEMA,
    RUN_CLIP: RUN_CLIP_SCHEMA,
    C.RUN_METRICS: RUN_METRICS_SCHEMA,
    SCENE_FILE: RUN_SCENE_SCHEMA,
}
#: How each file is named in messages.
RUN_FILE_WHAT: dict[str, str] = {
    RUN_CONFIG: "config",
    RUN_CLIP: "clip record",
    C.RUN_METRICS: "metrics",
    SCENE_FILE: "scene analysis",
}


def _kind(model: type[RunFile], key: str) -> str:
    """The words of a field's type (its ``Kind``)."""
    return next(m.words for m in model.model_fields[key].metadata if isinstance(m, Kind))


def _field_kinds(model: type[RunFile], required: bool) -> dict[str, str]:
    """The fields of ``model`` that are (or are not) required and have a type, with its words."""
    fields = model.model_fields.items()
    return {k: _kind(model, k) for k, f in fields if f.is_required() == required and _has_kind(f.metadata)}


def _has_kind(metadata: list[Any]) -> bool:
    return any(isinstance(m, Kind) for m in metadata)


#: Each file's required keys with their types in words, and clip.json's optional ones (checked when present).
RUN_FILE_FIELDS: dict[str, dict[str, str]] = {name: _field_kinds(m, True) for name, m in RUN_FILE_MODELS.items()}
RUN_CLIP_OPTIONAL_FIELDS: dict[str, str] = _field_kinds(ClipFile, False)


def validate_run_file(name: str, data: Any) -> dict[str, Any]:
    """Check a decoded run-folder file (``RUN_CONFIG``, ``RUN_CLIP``, ``RUN_METRICS`` or ``SCENE_FILE``) against its
    schema; returns it as it is, or raises RunFileError naming the first thing wrong (the version, then each key in
    the model's order, then a key it does not name, then what the values say of each other)."""
    what = RUN_FILE_WHAT[name]
    if not isinstance(data, dict):
        raise RunFileError(f"{what} is not a JSON object", RUN_FILE_DAMAGED_FIX)
    version = data.get("schema")
    if version != RUN_FILE_SCHEMAS[name]:
        problem = f"{what} schema {version!r} is not supported (this engine writes {RUN_FILE_SCHEMAS[name]})"
        raise RunFileError(problem, RUN_FILE_OTHER_VERSION_FIX)
    wrong = record_problem(what, RUN_FILE_MODELS[name], data)
    if wrong is not None:
        raise RunFileError(wrong, RUN_FILE_DAMAGED_FIX)
    return data


def read_record(what: str, model: type[_Record], data: dict[str, Any]) -> tuple[_Record | None, str | None]:
    """A decoded record (``data``, its "schema" left out) read as its ``model``: (the record, None), or (None, the
    first thing wrong as one line naming the record as ``what``: the one adapter from a validation error to the
    engine's words)."""
    try:
        return model.model_validate({k: v for k, v in data.items() if k != "schema"}), None
    except ValidationError as exc:
        return None, _one_line(what, model, data, exc)


def record_problem(what: str, model: type[RunFile], data: dict[str, Any]) -> str | None:
    """``read_record``'s line of what is wrong (None: nothing)."""
    return read_record(what, model, data)[1]


def _one_line(what: str, model: type[RunFile], data: dict[str, Any], exc: ValidationError) -> str:
    """The refusal of a file as one line: the first error, a key the model does not name only when nothing else is
    wrong."""
    errors = exc.errors(include_url=False)
    error = next((e for e in errors if e["type"] != "extra_forbidden"), errors[0])
    if error["type"] == "run_file":
        return str(error["ctx"]["problem"])
    key = str(error["loc"][0])
    if error["type"] == "missing":  # a nested record names its whole path: layers.Foreground.atlas_size
        return f"{what} has no {'.'.join(str(part) for part in error['loc'])!r}"
    if error["type"] == "extra_forbidden":
        return f"{what} has an unknown key {key[:MANIFEST_QUOTE_CHARS]!r}"
    kind = _kind(model, key)
    return f"{what} {key!r} is not {'an' if kind[:1] in 'aeiou' else 'a'} {kind}: {data[key]!r}"


__all__ = [
    "RUN_FILE_MODELS",
    "RunFile",
    "RunFileError",
    "checked",
    "read_record",
    "record_problem",
    "validate_run_file",
]
