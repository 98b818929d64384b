"""A staged export's record (``exports/.vNNN.chunks/stage.json``) and what it was made from. Torch-free: the farm's
plan reads it too, on a submitting machine without the GPU stack.

The stages of one staged export run at different times, on different hosts, and a fit can change between them
(``fit --refine`` or ``--refit`` between the passes of frames 0-3 and those of 4-7). The atlases stage records the
fit it was made from (the SHA-256 of ``checkpoint.pt`` and of ``config.json``); the passes and publish stages check
the fit they load against it and refuse another in one line, so a version never mixes frames of two fits, and the
farm's plan starts a new version rather than continuing one staged from another fit.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field, ValidatorFunctionWrapHandler, model_validator

from .. import contract as C
from ..errors import InputError
from ..fit.run_files import Bool, Int, IntList, IntPair, Kind, NumberList, RunFile, Str, checked, read_record
from ..terms.cli import EXPORT_INTO_ARG, EXPORT_STAGE_ARG, EXPORT_STAGES
from ..terms.export_names import PASS_PRECISION_FULL, PASS_PRECISIONS
from ..terms.run_folder import RUN_CONFIG

#: The record's name in the staging folder (removed when the version is published).
STAGE_RECORD = "stage.json"
#: The record's schema: frames, atlas size, each layer's atlas frame, ``source`` (what it was made from) and, when
#: written by an engine that follows the flow, ``follow_flow`` (bool) and ``follows`` (the layers whose
#: UV corrections are staged beside it: ``staging.FOLLOW_FLOW_DIR``) and, once it was chosen, ``precision`` (the bits
#: the pass files keep: ``terms.export_names.PASS_PRECISIONS``) and ``stmap`` (each pass file holds the STMap copy).
STAGE_SCHEMA = "neural_atlas.export_stage/2"
#: The schema of records written before they said what they were made from: such a stage cannot be continued.
STAGE_SCHEMA_WITHOUT_SOURCE = "neural_atlas.export_stage/1"
#: The run files a stage is made from, by the key their digest has in the record's ``source``.
SOURCE_FILES: dict[str, str] = {"checkpoint_sha256": C.RUN_CHECKPOINT, "config_sha256": RUN_CONFIG}
#: Bytes read at a time while hashing (a checkpoint is tens of MB: never read whole).
HASH_BLOCK = 1 << 20
#: The fix of a record that cannot be read.
DAMAGED_FIX = "delete its folder and stage the export again"


def file_sha256(path: Path) -> str:
    """The SHA-256 of the file at ``path``, hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(HASH_BLOCK):
            digest.update(block)
    return digest.hexdigest()


def fit_source(run_dir: Path) -> dict[str, str]:
    """What an export of ``run_dir`` is made from now: the digest of each of ``SOURCE_FILES``."""
    try:
        return {key: file_sha256(run_dir / name) for key, name in SOURCE_FILES.items()}
    except OSError as exc:
        raise InputError(exc.filename, "cannot be read", "pass the --out folder of a finished `fit`") from None


class LayerFrameRecord(RunFile):
    """A layer's atlas frame as records keep it: the box in atlas units (``atlas_frame.LayerFrame``) and the
    texture's size in texels."""

    atlas_box: Annotated[NumberList, Field(min_length=4, max_length=4)]
    atlas_size: IntPair


class StageLayer(LayerFrameRecord):
    """One layer of a staged export: its name and its atlas frame."""

    name: Str


def _stage_problem(data: dict[str, Any]) -> str | None:
    """What a stage record's fields say of each other (their types are checked already)."""
    if set(data["source"]) != set(SOURCE_FILES):
        return f"its source names {sorted(data['source'])[:4]}, not the digests of {sorted(SOURCE_FILES)}"
    if any(not 0 <= i < len(data["layers"]) for i in data.get("follows", [])):
        return f"it follows layers {data['follows'][:8]} of its {len(data['layers'])}"
    if data.get("precision", PASS_PRECISION_FULL) not in PASS_PRECISIONS:
        return f"its pass precision {str(data['precision'])[:40]!r} is not one of {', '.join(PASS_PRECISIONS)}"
    return None


class StageFile(RunFile):
    """``stage.json`` (``STAGE_SCHEMA``): what the atlases stage decided, which the passes and publish stages
    follow; ``follow_flow`` and ``follows`` are absent from records written before the flow was followed."""

    frames: IntPair  # [first, last] plate frame numbers
    atlas_size: Int
    layers: Annotated[list[StageLayer], Kind("layer list")]
    source: Annotated[dict[str, Str], Kind("dict of str")]  # ``fit_source``: SOURCE_FILES' keys, hex digests
    follow_flow: Bool = False
    follows: IntList = Field(default_factory=list)
    precision: Str = PASS_PRECISION_FULL  # absent from records written before it was chosen: every bit kept
    stmap: Bool = True  # absent from records written before it was a choice: the STMap copy written

    @model_validator(mode="wrap")
    @classmethod
    def values_agree(cls, data: Any, handler: ValidatorFunctionWrapHandler) -> Any:
        return checked(data, handler, _stage_problem)


def read_stage(chunks: Path) -> StageFile | None:
    """A staged export's record (None: no atlases stage finished there), read as ``StageFile`` (the defaults of the
    fields an older record lacks are its own); a damaged one, or one that does not say what it was made from, is
    one line."""
    path = chunks / STAGE_RECORD
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        raise InputError(path, "staged export record is damaged (not JSON)", DAMAGED_FIX) from None
    schema = data.get("schema") if isinstance(data, dict) else None
    if schema == STAGE_SCHEMA_WITHOUT_SOURCE:
        raise InputError(
            path, "this staged export does not record the fit it was made from (an earlier engine staged it)",
            DAMAGED_FIX,
        )  # fmt: skip
    if schema != STAGE_SCHEMA:
        raise InputError(path, f"staged export record of schema {str(schema)[:40]!r}, not {STAGE_SCHEMA}", DAMAGED_FIX)
    record, problem = read_record("staged export record", StageFile, data)
    if record is None:
        raise InputError(path, f"staged export record is damaged: {problem}", DAMAGED_FIX)
    return record


def changed_since(record: StageFile, source: dict[str, str]) -> list[str]:
    """The run files (``SOURCE_FILES``) whose digest in ``source`` is not the one ``record`` was made from."""
    return [SOURCE_FILES[key] for key in SOURCE_FILES if record.source[key] != source[key]]


def other_fit_error(chunks: Path, version: str, changed: list[str], free: str) -> InputError:
    """The one line of a stage asked to continue ``version`` after the fit changed (``changed``: its files that
    did); ``free`` is the version a new staged export would take."""
    return InputError(
        chunks,
        f"{version} was staged from another fit ({' and '.join(changed)} changed since its atlases were made: "
        "a fit --refine or --refit), and one version never mixes frames of two fits",
        f"stage this fit as a new version ({EXPORT_INTO_ARG} {free} {EXPORT_STAGE_ARG} "
        f"{EXPORT_STAGES[0]}; a farm job submitted again takes a new version itself), or delete {chunks.name} "
        f"to stage {version} again from this fit",
    )


def continues_fit(run_dir: Path, chunks: Path) -> bool:
    """Whether the staged export in ``chunks`` may be continued by the fit ``run_dir`` holds now: no atlases stage
    finished there (its atlases stage starts it from this fit), or its record says it was made from this fit. A
    damaged record, or one of another fit, is not continued (the plan leaves it and takes a new version)."""
    try:
        record = read_stage(chunks)
        return record is None or not changed_since(record, fit_source(run_dir))
    except InputError:
        return False


__all__ = [
    "STAGE_RECORD",
    "STAGE_SCHEMA",
    "LayerFrameRecord",
    "StageFile",
    "changed_since",
    "continues_fit",
    "file_sha256",
    "fit_source",
    "other_fit_error",
    "read_stage",
]
