"""The manifest's shape as a JSON Schema (``manifest.schema.json`` beside this module), for readers that are not the
engine or the add-on: pipeline tools, validators in other languages, editors that complete a hand edit.

The shape is declared once here as pydantic models, mirroring ``terms.manifest.validate_manifest`` (the standard-library
check the engine and the add-on read every manifest through, which stays the authority) as far as JSON Schema can
say it: every field's type (strict: a bool is not a number, a float is not an int), which fields are required,
enumerations, bounds, lengths and patterns. Keys the contract does not name are allowed, as ``validate_manifest``
allows them. What only a check across fields can say (the clip's frame numbers ascending, ``passes.frames`` among
them, a layer's ``index`` its position, unique layer names, ...) is left to ``validate_manifest``: a manifest the
schema accepts may still be refused there, never the other way round (tests/engine/export/test_manifest_schema.py
lists the differences).

The file is generated, never edited: ``python -m engine.export.manifest_schema`` writes it again after a change to
the models, and a test fails while the file and the models disagree.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, Field
from pydantic.json_schema import GenerateJsonSchema, JsonSchemaValue
from pydantic_core import core_schema

from ..terms.colour import COLOUR_NAME_MAX
from ..terms.manifest import (
    MANIFEST_BOX_NUMBERS,
    MANIFEST_LAYER_NAME,
    MANIFEST_LAYER_NAME_MAX,
    MANIFEST_MAX_SIDE,
    MANIFEST_UV_CHANNEL_COUNT,
    MANIFEST_VERSION,
    TIMECODE_PATTERN,
)

#: The schema's file, shipped with the engine (pyproject.toml's package-data).
SCHEMA_PATH = Path(__file__).with_name("manifest.schema.json")
#: The JSON Schema dialect the file is written in (pydantic's output is draft 2020-12).
SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"
#: The schema's identifier: a name, not an address to fetch (the file ships with the engine); it carries the
#: manifest's version, so a schema for another version is another schema.
SCHEMA_ID = f"urn:neural-atlas:manifest:{MANIFEST_VERSION}"
SCHEMA_TITLE = "Neural Atlas export manifest (manifest.json)"
#: Model config of every part: strict types, as ``validate_manifest``'s; other keys allowed, as there; a field's
#: docstring is its description in the schema.
_PART = ConfigDict(strict=True, extra="allow", use_attribute_docstrings=True)


def _absent() -> Any:
    """A field a manifest may leave out; when present it must have its type (null is not "absent")."""
    return Field(default=None)


def _not_bool(value: Any) -> Any:
    """JSON's true is not the number 1 (a lax literal would take it for one)."""
    if isinstance(value, bool):
        raise ValueError("a bool is not a number")
    return value


def _distinct(values: list[int]) -> list[int]:
    """What JSON Schema's ``uniqueItems`` says (the schema carries the keyword; this is its check here)."""
    if len(set(values)) != len(values):
        raise ValueError("items are not distinct")
    return values


Text = Annotated[str, Field(min_length=1)]
#: A side of an image (plate, passes, atlas): it bounds what a reader allocates.
Side = Annotated[int, Field(ge=1, le=MANIFEST_MAX_SIDE)]
Size = Annotated[list[Side], Field(min_length=2, max_length=2)]
FrameNumber = Annotated[int, Field(ge=0)]
Frames = Annotated[
    list[FrameNumber], Field(min_length=1, json_schema_extra={"uniqueItems": True}), AfterValidator(_distinct)
]
Finite = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
Rate = Annotated[list[Annotated[int, Field(gt=0)]], Field(min_length=2, max_length=2)]
ColourName = Annotated[str, Field(min_length=1, max_length=COLOUR_NAME_MAX)]
LayerName = Annotated[str, Field(pattern=f"^{MANIFEST_LAYER_NAME.pattern}$", max_length=MANIFEST_LAYER_NAME_MAX)]


class Clip(BaseModel):
    """The plate the export was made from; paths relative to the manifest's folder."""

    model_config = _PART

    source: Text
    kind: Literal["sequence", "movie"]
    frame_files: list[Text]
    """One per frame of a sequence, in frame_numbers' order; [] for a movie."""
    frame_numbers: Frames
    """The plate's own frame numbers, ascending."""
    first_frame: FrameNumber
    last_frame: FrameNumber
    fps: Positive | None
    resolution: Size
    """[width, height] of the plate."""
    colorspace: ColourName
    """The plate's OCIO colour space ("sRGB" or "linear" where there is no colour_config)."""
    working_resolution: Size = _absent()
    masks: list[str] = _absent()
    colour_config: ColourName = _absent()
    colour_source: Literal["asked", "file", "rules", "format", "assumed"] = _absent()
    """How the colour space was decided (absent: asked)."""
    rate: Rate | None = None
    """The exact frame rate [num, den] (24000/1001 for 23.976)."""
    pixel_aspect: Positive = _absent()
    timecode: Annotated[str, Field(pattern=TIMECODE_PATTERN)] | None = None
    """SMPTE timecode of first_frame, HH:MM:SS:FF (";" before the frames: drop-frame)."""
    start_frame: FrameNumber = _absent()
    """A movie's number of its first frame."""
    source_absolute: str = _absent()
    """source, absolute as at export: read where the relative path names nothing (a run folder moved alone)."""
    frame_files_absolute: list[str] = _absent()


class Passes(BaseModel):
    """The per-frame EXR pass files, in the folder ``dir`` beside the manifest."""

    model_config = _PART

    dir: Text
    """The pass files' folder, relative to the manifest's."""
    pattern: Text
    """A file name with Python's {frame:04d} for the plate's frame number (atlas.{frame:04d}.exr)."""
    blender_pattern: str
    """The same name in Blender's words (atlas.####.exr)."""
    frames: Frames
    """The plate frame numbers exported, each one of the clip's."""
    exr_layer: Text
    resolution: Size
    """[width, height]: the clip's."""
    precision: Literal["compact", "full"] = _absent()
    """The bits the pass files keep (absent: full): compact rounds alpha and coverage to half float's precision
    and u, v to multiples of 2^-17, in float32 channels."""


class Layer(BaseModel):
    """One layer of the decomposition; layer 0 is the background, the only one."""

    model_config = _PART

    name: LayerName
    """A plain identifier, unique in the manifest (it names files and nodes)."""
    index: Annotated[int, Field(ge=0)]
    """Its position in "layers"."""
    role: Literal["background", "foreground"]
    uv_pass: Text
    alpha_pass: Text
    uv_channels: Annotated[
        list[Text], Field(min_length=MANIFEST_UV_CHANNEL_COUNT, max_length=MANIFEST_UV_CHANNEL_COUNT)
    ]
    """u, v and coverage."""
    alpha_channels: Annotated[list[Text], Field(min_length=1)]
    atlas_exr: Text
    atlas_png: Text
    atlas_size: Size
    edit_layer: Text
    atlas_box: Annotated[list[Finite], Field(min_length=MANIFEST_BOX_NUMBERS, max_length=MANIFEST_BOX_NUMBERS)]
    """[u0, v0, u1, v1]: the atlas's frame in model atlas units."""
    channels: list[str] = _absent()
    """The layer's full EXR channel names (Atlas.UVForeground.U, ...)."""
    stmap_channels: list[str] = _absent()
    """The full channel names of the layer's STMap (stmap_pass)."""
    stmap_pass: str = _absent()
    """STMap<Layer>; exports made before the STMap layers have neither it nor stmap_channels."""
    follows_flow: bool = _absent()
    """True: the layer's UV was averaged along optical flow (export --follow-flow); absent: false."""


class Fit(BaseModel):
    """How the export's fit was made."""

    model_config = _PART

    preset: str
    model: str
    steps: Annotated[int, Field(ge=0)]
    train_seconds: float
    psnr: float | None
    alpha_iou: list[float] | None = None


class Scene(BaseModel):
    """The run's scene analysis (RUN_DIR/scene.json) as the export found it."""

    model_config = _PART

    components: str
    num_layers: Annotated[int, Field(ge=1)]
    """The manifest's number of layers."""
    layers_source: str
    background_motion: Literal["static", "pan_zoom", "deformable"]
    flow: bool
    active_terms: list[str]
    reasons: dict[str, Any]


class Manifest(BaseModel):
    """An export's manifest.json: everything a reader needs to use the export's passes and atlases."""

    model_config = _PART

    # terms.manifest.MANIFEST_TAG and MANIFEST_VERSION, written out as a type checker wants them (the tests compare)
    version: Annotated[Literal[1], BeforeValidator(_not_bool)] = Field(alias="neural_atlas_manifest")
    """The manifest's version: a reader refuses one it does not know."""
    engine_version: str
    run_dir: str
    """The run folder, relative to the manifest's folder."""
    created: str
    """When the export was made (ISO 8601)."""
    clip: Clip
    passes: Passes
    layers: Annotated[list[Layer], Field(min_length=1)]
    fit: Fit
    scene: Scene = _absent()


class _SchemaWords(GenerateJsonSchema):
    """pydantic's JSON Schema less what would mislead a reader of the file: a title per field (the key says it) and
    the null default of a field a manifest may leave out (absent is not null)."""

    def field_title_should_be_set(self, schema: Any) -> bool:
        return False

    def default_schema(self, schema: core_schema.WithDefaultSchema) -> JsonSchemaValue:
        return self.generate_inner(schema["schema"])


def manifest_schema() -> dict[str, Any]:
    """The manifest's JSON Schema, as the file holds it."""
    body = Manifest.model_json_schema(by_alias=True, schema_generator=_SchemaWords)
    return {"$schema": SCHEMA_DIALECT, "$id": SCHEMA_ID, **body, "title": SCHEMA_TITLE}


def schema_text() -> str:
    """The file's text: indented, keys in the models' order, one newline at the end."""
    return json.dumps(manifest_schema(), indent=2, ensure_ascii=False) + "\n"


def write_schema(path: Path = SCHEMA_PATH) -> Path:
    """Write the schema file (``path``) from the models."""
    path.write_text(schema_text(), encoding="utf-8")
    return path


if __name__ == "__main__":
    sys.stdout.write(f"{write_schema()}\n")
