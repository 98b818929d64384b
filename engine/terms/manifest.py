"""The manifest (``manifest.json``, the one file an export is read through): its fields, their types and what they
must say of each other, checked in one pass (``validate_manifest``) so that what passes is safe to read."""

from __future__ import annotations

import json
import math
import os
import re
from typing import Any

from .cli import CLI_MODULE
from .clip import CLIP_KINDS
from .colour import COLOUR_SOURCE_ASKED, COLOUR_SOURCES, valid_colour_record
from .export_names import PASS_PRECISION_FULL, PASS_PRECISIONS, ROLE_BACKGROUND, ROLE_FOREGROUND, UV_CHANNELS
from .run_folder import BG_MOTIONS, SCENE_FIELDS, SCENE_KEYS

MANIFEST_NAME = "manifest.json"
#: Version of manifest.json; the add-on refuses a manifest whose version it does not know.
MANIFEST_VERSION = 1
MANIFEST_TAG = "neural_atlas_manifest"  # {"neural_atlas_manifest": MANIFEST_VERSION, ...}
#: Keys every manifest has (validated by ``validate_manifest``, types included). Paths inside are relative to the
#: manifest's folder, so a run folder moved or mounted elsewhere keeps working (the plate's paths are absolute only
#: where no relative path exists, e.g. on another Windows drive); edit layers must stay inside the run folder
#: (``resolve_manifest_write_path``). Shape:
#: {"neural_atlas_manifest": 1, "engine_version": str, "run_dir": str (the run folder, relative), "created":
#:  ISO-8601 str,
#:  "clip": {"source": str, "kind": "sequence"|"movie", "frame_files": [str] ([] for a movie), "frame_numbers":
#:           [int] (ascending), "first_frame": int, "last_frame": int, "fps": float|None, "resolution": [W, H],
#:           "working_resolution": [W, H], "colorspace": str (the plate's OCIO colour space; "sRGB"|"linear" in
#:           older manifests), "colour_config": str (optional: its OCIO config; absent = LEGACY_COLORSPACES),
#:           "colour_source": str (optional: how the colour space was decided, one of COLOUR_SOURCES),
#:           "masks": [str] (the fit's mask folders; optional), and optional, the plate's timing
#:           (MANIFEST_OPTIONAL_FIELDS; absent: none stated): "rate": [num, den]|None (the exact frame rate, 24000/1001
#:           for 23.976; "fps" is its float), "pixel_aspect": number (2.0: 2x anamorphic), "timecode": str|None (SMPTE
#:           "HH:MM:SS:FF" of first_frame), "start_frame": int (a movie's number of its first frame: frame_numbers are
#:           start_frame + the frame's index), "source_absolute": str and "frame_files_absolute": [str] (optional:
#:           the same plate paths, absolute as at export; where the relative ones name nothing, a run folder moved
#:           alone, ``resolve_plate_path`` takes these)},
#:  "passes": {"dir": str, "pattern": "atlas.{frame:04d}.exr" (padded as the plate's frames: ``pass_pattern``),
#:             "blender_pattern": "atlas.####.exr" (the same for Blender: ``blender_pattern``),
#:             "frames": [int] (plate frame numbers exported, each one of the clip's), "exr_layer": "Atlas",
#:             "resolution": [W, H] (the clip's), "precision": one of PASS_PRECISIONS (optional, absent: "full":
#:             the bits the pass files keep)},
#:  "layers": [{"name": str (unique), "index": int (its position; 0 is the background), "role":
#:              "background"|"foreground", "uv_pass": str, "alpha_pass": str, "uv_channels": [3 str] (u, v,
#:              coverage: UV_CHANNELS, or LEGACY_UV_CHANNELS in older exports),
#:              "alpha_channels": [str], "atlas_exr": str, "atlas_png": str, "atlas_size": [W, H], "edit_layer": str,
#:              "atlas_box": [u0, v0, u1, v1],
#:              "channels": [full EXR channel names, e.g. "Atlas.UVForeground.U"] (optional: derivable),
#:              "stmap_pass": "STMap<Layer>", "stmap_channels": [4 full EXR channel names] (optional: an export
#:              made without ``export --stmap`` has neither, nor STMap layers in its pass files),
#:              "follows_flow": bool (optional, absent: false: its UV was averaged along optical flow,
#:              ``export --follow-flow``)}],
#:  "fit": {"preset": str, "model": str, "steps": int, "train_seconds": float, "psnr": float|None,
#:          "alpha_iou": [float]|None (optional)},
#:  "scene": the run's SCENE_FILE (every export writes it; checked by ``validate_scene`` when present)}
#: Field types, in the words of ``_is_type``, per section ("" is the top level).
MANIFEST_FIELDS: dict[str, dict[str, str]] = {
    "": {"engine_version": "str", "run_dir": "str", "created": "str"},
    "clip": {
        "source": "str",
        "kind": "str",
        "frame_files": "str list",
        "frame_numbers": "int list",
        "first_frame": "int",
        "last_frame": "int",
        "fps": "number or null",
        "resolution": "int pair",
        "colorspace": "str",
    },
    "passes": {
        "dir": "str",
        "pattern": "str",
        "blender_pattern": "str",
        "frames": "int list",
        "exr_layer": "str",
        "resolution": "int pair",
    },
    "fit": {"preset": "str", "model": "str", "steps": "int", "train_seconds": "number", "psnr": "number or null"},
}
#: Fields a manifest may leave out, checked when present.
MANIFEST_OPTIONAL_FIELDS: dict[str, dict[str, str]] = {
    "clip": {
        "working_resolution": "int pair",
        "masks": "str list",
        "colour_config": "str",
        "colour_source": "str",
        "rate": "int pair or null",
        "pixel_aspect": "number",
        "timecode": "str or null",
        "start_frame": "int",
        "source_absolute": "str",
        "frame_files_absolute": "str list",
    },
    "passes": {"precision": "str"},
    "fit": {"alpha_iou": "number list or null"},
}
MANIFEST_LAYER_FIELDS: dict[str, str] = {
    "name": "str",
    "index": "int",
    "role": "str",
    "uv_pass": "str",
    "alpha_pass": "str",
    "uv_channels": "str list",
    "alpha_channels": "str list",
    "atlas_exr": "str",
    "atlas_png": "str",
    "atlas_size": "int pair",
    "edit_layer": "str",
    "atlas_box": "number list",
}
MANIFEST_OPTIONAL_LAYER_FIELDS: dict[str, str] = {
    "channels": "str list",
    "stmap_pass": "str",
    "stmap_channels": "str list",
    "follows_flow": "bool",
}
MANIFEST_KEYS: tuple[str, ...] = (*MANIFEST_FIELDS[""], "clip", "passes", "layers", "fit")
MANIFEST_CLIP_KEYS: tuple[str, ...] = tuple(MANIFEST_FIELDS["clip"])
MANIFEST_PASSES_KEYS: tuple[str, ...] = tuple(MANIFEST_FIELDS["passes"])
MANIFEST_LAYER_KEYS: tuple[str, ...] = tuple(MANIFEST_LAYER_FIELDS)
MANIFEST_FIT_KEYS: tuple[str, ...] = tuple(MANIFEST_FIELDS["fit"])
#: The largest image side a manifest may give (plate, passes, atlases): it bounds what a reader allocates.
MANIFEST_MAX_SIDE = 1 << 16
#: A value quoted in a manifest error is cut to this many characters (the message stays one short line); a path
#: written through gets more, so the file it names shows.
MANIFEST_QUOTE_CHARS = 40
MANIFEST_QUOTE_PATH_CHARS = 120
#: Channels of a UV pass (u, v, and Z: the layer's alpha where its atlas covers the pixel).
MANIFEST_UV_CHANNEL_COUNT = len(UV_CHANNELS)
#: An atlas box is four numbers: u0, v0, u1, v1.
MANIFEST_BOX_NUMBERS = 4
#: A layer's name is a plain identifier (what ``layer_name`` makes): it becomes file names (``edits/<name>.png``),
#: channel names and node names in Blender and Nuke, where a bracket, quote or newline would be code or a path.
MANIFEST_LAYER_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
#: The longest layer name a manifest may give (a file name and a node name are made of it).
MANIFEST_LAYER_NAME_MAX = 64


class ManifestError(ValueError):
    """A manifest that does not follow this contract (message names what is wrong)."""


def _quote(value: Any, limit: int = MANIFEST_QUOTE_CHARS) -> str:
    """``value`` as a message quotes it: repr, cut to ``limit`` characters (a path keeps its end, the file)."""
    text = repr(value)
    if len(text) <= limit:
        return text
    return "..." + text[3 - limit :] if isinstance(value, str) else text[: limit - 3] + "..."


def _a(kind: str) -> str:
    return f"an {kind}" if kind[0] in "aeiou" else f"a {kind}"


def _check_fields(where: str, record: Any, fields: dict[str, str], optional: dict[str, str]) -> dict[str, Any]:
    """``record`` (the manifest's part ``where``: "clip", "layer 0", "" for the top) is an object holding every key
    of ``fields`` (and maybe those of ``optional``) with its type."""
    name = f"manifest {where}".rstrip()
    if not isinstance(record, dict):
        raise ManifestError(f"{name} is not an object")
    for key, kind in (*fields.items(), *optional.items()):
        if key not in record:
            if key in fields:
                raise ManifestError(f"{name} has no {key!r}")
            continue
        if not _is_type(record[key], kind):
            raise ManifestError(f"{name} field {key!r} is not {_a(kind)}: {_quote(record[key])}")
    return record


def _check_size(where: str, size: list[int], limit: int = MANIFEST_MAX_SIDE) -> None:
    if not all(1 <= side <= limit for side in size):
        raise ManifestError(f"manifest {where} {_quote(size)} is not two sides in 1..{limit}")


def _check_clip(clip: dict[str, Any]) -> None:
    """The clip's fields agree with each other: known kind and colour space, frames ascending, one file each."""
    numbers = clip["frame_numbers"]
    if clip["kind"] not in CLIP_KINDS or not valid_colour_record(clip["colorspace"], clip.get("colour_config")):
        raise ManifestError(
            f"manifest 'clip' has unknown kind or colour space {_quote([clip['kind'], clip['colorspace']])}"
        )
    if clip.get("colour_source", COLOUR_SOURCE_ASKED) not in COLOUR_SOURCES:
        raise ManifestError(f"manifest 'clip' has unknown colour_source {_quote(clip['colour_source'])}")
    if not numbers or numbers[0] < 0 or numbers != sorted(set(numbers)):
        raise ManifestError("manifest 'clip' frame_numbers are not ascending frame numbers >= 0")
    if (clip["first_frame"], clip["last_frame"]) != (numbers[0], numbers[-1]):
        raise ManifestError("manifest 'clip' first_frame and last_frame are not its first and last frame numbers")
    if clip["kind"] == CLIP_KINDS[0] and len(clip["frame_files"]) != len(numbers):
        raise ManifestError(f"manifest 'clip' lists {len(clip['frame_files'])} frame files for {len(numbers)} frames")
    if not clip["source"] or not all(clip["frame_files"]):
        raise ManifestError("manifest 'clip' has an empty path")
    fps = clip["fps"]
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise ManifestError(f"manifest 'clip' fps {_quote(fps)} is not a positive number")
    problem = timing_problem(clip)
    if problem is not None:
        raise ManifestError(f"manifest 'clip' {problem}")
    _check_size("'clip' resolution", clip["resolution"])
    if "working_resolution" in clip:
        _check_size("'clip' working_resolution", clip["working_resolution"])


#: A pass file pattern as the engine writes it: a name with one ``{frame:0Nd}`` token (``pass_pattern``), padded to
#: at most PASS_PATTERN_MAX_DIGITS digits; anything else (a width of a billion digits would take gigabytes to
#: format) does not name a pass file.
PASS_PATTERN_TOKEN = re.compile(r"[^{}%]*\{frame:0?(\d{1,3})d\}[^{}%]*")
PASS_PATTERN_MAX_DIGITS = 10


def _check_passes(passes: dict[str, Any], clip: dict[str, Any]) -> None:
    """Every exported frame is one of the clip's, the passes are the clip's size, and the pattern names a file."""
    frames = passes["frames"]
    if not frames:
        raise ManifestError("manifest 'passes' lists no frames")
    known = set(clip["frame_numbers"])
    unknown = [f for f in frames if f not in known]
    if unknown or len(set(frames)) != len(frames):
        raise ManifestError(f"manifest 'passes' frames {_quote(unknown or frames)} are not distinct frames of the clip")
    if passes["resolution"] != clip["resolution"]:
        raise ManifestError("manifest 'passes' resolution is not the clip's")
    token = PASS_PATTERN_TOKEN.fullmatch(passes["pattern"])
    name = ""
    if token is not None and int(token.group(1) or 1) <= PASS_PATTERN_MAX_DIGITS:  # checked before it is formatted
        name = passes["pattern"].format(frame=frames[0])
    if not name or os.path.basename(name) != name or name in (os.curdir, os.pardir) or "\\" in name:
        raise ManifestError(f"manifest 'passes' pattern {_quote(passes['pattern'])} does not name a pass file")
    if not passes["dir"] or not passes["exr_layer"]:
        raise ManifestError("manifest 'passes' has an empty dir or exr_layer")
    if passes.get("precision", PASS_PRECISION_FULL) not in PASS_PRECISIONS:
        raise ManifestError(f"manifest 'passes' has unknown precision {_quote(passes['precision'])}")


def is_layer_name(name: str) -> bool:
    """Whether ``name`` may name a layer (``MANIFEST_LAYER_NAME``): the engine's own names always do."""
    return len(name) <= MANIFEST_LAYER_NAME_MAX and MANIFEST_LAYER_NAME.fullmatch(name) is not None


def _check_layer(i: int, layer: Any) -> dict[str, Any]:
    where = f"layer {i}"
    _check_fields(where, layer, MANIFEST_LAYER_FIELDS, MANIFEST_OPTIONAL_LAYER_FIELDS)
    if layer["role"] not in (ROLE_BACKGROUND, ROLE_FOREGROUND):
        raise ManifestError(f"manifest {where} has unknown role {_quote(layer['role'])}")
    if layer["index"] != i:
        raise ManifestError(f"manifest {where} has index {_quote(layer['index'])}")
    if (layer["role"] == ROLE_BACKGROUND) != (i == 0):
        raise ManifestError(f"manifest {where} is a {layer['role']} layer (layer 0 is the background, only it)")
    texts = [layer[k] for k in ("name", "uv_pass", "alpha_pass", "atlas_exr", "atlas_png", "edit_layer")]
    if not all(texts) or not all(layer["uv_channels"] + layer["alpha_channels"]):
        raise ManifestError(f"manifest {where} has an empty name, pass, channel or path")
    if not is_layer_name(layer["name"]):
        raise ManifestError(
            f"manifest {where} name {_quote(layer['name'])} is not a plain name (letters, digits and _, "
            f"at most {MANIFEST_LAYER_NAME_MAX})"
        )
    if len(layer["uv_channels"]) != MANIFEST_UV_CHANNEL_COUNT or not layer["alpha_channels"]:
        raise ManifestError(f"manifest {where} does not name {MANIFEST_UV_CHANNEL_COUNT} UV channels and an alpha one")
    _check_size(f"{where} atlas_size", layer["atlas_size"])
    box = layer["atlas_box"]
    if len(box) != MANIFEST_BOX_NUMBERS or not all(math.isfinite(b) for b in box):
        raise ManifestError(f"manifest {where} atlas_box {_quote(box)} is not four finite numbers")
    return layer


def validate_manifest(data: Any) -> dict[str, Any]:
    """Check a decoded manifest against the schema above, the type of every field included; returns it, or raises
    ManifestError (one line). What passes is safe for the engine and the add-on to read without further checks."""
    if not isinstance(data, dict):
        raise ManifestError("manifest is not a JSON object")
    version = data.get(MANIFEST_TAG)
    if version != MANIFEST_VERSION or isinstance(version, bool):
        raise ManifestError(
            f"manifest version {_quote(version)} is not supported (this engine reads {MANIFEST_VERSION})"
        )
    _check_fields("", data, MANIFEST_FIELDS[""], {})
    for key in MANIFEST_KEYS:
        if key not in data:
            raise ManifestError(f"manifest has no {key!r}")
    for section in ("clip", "passes", "fit"):
        _check_fields(repr(section), data[section], MANIFEST_FIELDS[section], MANIFEST_OPTIONAL_FIELDS.get(section, {}))
    _check_clip(data["clip"])
    _check_passes(data["passes"], data["clip"])
    layers = data["layers"]
    if not isinstance(layers, list) or not layers:
        raise ManifestError("manifest has no layers")
    names = [_check_layer(i, layer)["name"] for i, layer in enumerate(layers)]
    if len(set(names)) != len(names):
        raise ManifestError(f"manifest layer names {_quote(names)} are not unique")
    if data["fit"]["steps"] < 0:
        raise ManifestError("manifest 'fit' steps is negative")
    if "scene" in data:
        validate_scene(data["scene"], len(layers))
    return data


def validate_scene(scene: Any, num_layers: int | None = None) -> dict[str, Any]:
    """Check a scene analysis record (SCENE_FILE, or a manifest's "scene"); raises ManifestError (one line)."""
    if not isinstance(scene, dict):
        raise ManifestError("manifest 'scene' is not an object")
    for key in SCENE_KEYS:
        if key not in scene:
            raise ManifestError(f"manifest 'scene' has no {key!r}")
    if scene["background_motion"] not in BG_MOTIONS:
        raise ManifestError(f"manifest 'scene' has unknown background_motion {_quote(scene['background_motion'])}")
    if num_layers is not None and scene["num_layers"] != num_layers:
        raise ManifestError(
            f"manifest 'scene' says {_quote(scene['num_layers'])} layers but the manifest has {num_layers}"
        )
    if not isinstance(scene["active_terms"], list) or not isinstance(scene["reasons"], dict):
        raise ManifestError("manifest 'scene' active_terms is not a list or reasons is not an object")
    for key, kind in SCENE_FIELDS.items():
        if not _is_type(scene[key], kind):
            raise ManifestError(f"manifest 'scene' field {key!r} is not {_a(kind)}: {_quote(scene[key])}")
    return scene


def load_manifest(path: str) -> dict[str, Any]:
    """Read and validate ``manifest.json``; errors are one line naming the file and the fix."""
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except FileNotFoundError:
        raise ManifestError(f"{path}: no manifest here — run `python -m {CLI_MODULE} export RUN_DIR` first") from None
    except (OSError, ValueError, RecursionError) as exc:  # not JSON, not UTF-8, nested beyond the parser
        raise ManifestError(f"{path}: cannot be read ({type(exc).__name__}) — export the run again") from None
    try:
        return validate_manifest(data)
    except ManifestError as exc:
        raise ManifestError(f"{path}: {exc} — export the run again with this engine") from None


#: A timecode as the engine records it: ``HH:MM:SS:FF``, ``;`` before the frames for drop-frame.
TIMECODE_PATTERN = r"^\d{2}:[0-5]\d:[0-5]\d[:;]\d{2,3}$"


def timing_problem(clip: dict[str, Any]) -> str | None:
    """What is wrong with a clip record's (or a manifest clip's) optional timing fields, or None: a rate of two
    positive integers, a finite positive pixel aspect ratio, a timecode ``HH:MM:SS:FF`` and a start frame >= 0."""
    rate = clip.get("rate")
    aspect = clip.get("pixel_aspect", 1.0)
    timecode = clip.get("timecode")
    if rate is not None and not (len(rate) == 2 and rate[0] > 0 and rate[1] > 0):
        return f"rate {rate!r} is not a positive fraction [num, den]"
    if not (math.isfinite(aspect) and aspect > 0):
        return f"pixel_aspect {aspect!r} is not a positive number"
    if timecode is not None and re.match(TIMECODE_PATTERN, timecode) is None:
        return f"timecode {timecode[:MANIFEST_QUOTE_CHARS]!r} is not HH:MM:SS:FF"
    if clip.get("start_frame", 0) < 0:
        return "start_frame is negative"
    return None


def _is_type(value: Any, kind: str) -> bool:
    """Whether ``value`` is of ``kind``, a type in words: "str", "int", "number" (int or float), "bool", "dict",
    "<type> list", "<type> pair" (a list of two), and "... or null"."""
    if kind.endswith(" or null"):
        return value is None or _is_type(value, kind[: -len(" or null")])
    if kind.endswith(" list") or kind.endswith(" pair"):
        item = kind.rsplit(" ", 1)[0]
        ok = isinstance(value, list) and all(_is_type(v, item) for v in value)
        return ok and (kind.endswith(" list") or len(value) == 2)
    if kind == "number":
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind == "int":
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, {"str": str, "bool": bool, "dict": dict}[kind])


#: What ``engine.contract`` re-exports from this module (its own names, not its imports).
__all__ = [
    "MANIFEST_BOX_NUMBERS",
    "MANIFEST_CLIP_KEYS",
    "MANIFEST_FIELDS",
    "MANIFEST_FIT_KEYS",
    "MANIFEST_KEYS",
    "MANIFEST_LAYER_FIELDS",
    "MANIFEST_LAYER_KEYS",
    "MANIFEST_LAYER_NAME",
    "MANIFEST_LAYER_NAME_MAX",
    "MANIFEST_MAX_SIDE",
    "MANIFEST_NAME",
    "MANIFEST_OPTIONAL_FIELDS",
    "MANIFEST_OPTIONAL_LAYER_FIELDS",
    "MANIFEST_PASSES_KEYS",
    "MANIFEST_QUOTE_CHARS",
    "MANIFEST_QUOTE_PATH_CHARS",
    "MANIFEST_TAG",
    "MANIFEST_UV_CHANNEL_COUNT",
    "MANIFEST_VERSION",
    "PASS_PATTERN_MAX_DIGITS",
    "PASS_PATTERN_TOKEN",
    "TIMECODE_PATTERN",
    "ManifestError",
    "is_layer_name",
    "load_manifest",
    "timing_problem",
    "validate_manifest",
    "validate_scene",
]
