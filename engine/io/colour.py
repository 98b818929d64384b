"""Colour through OpenColorIO: the one place where colour spaces are named, resolved and converted.

Every conversion is an OCIO transform run by the pinned OpenImageIO (``ImageBufAlgo.colorconvert``), so the engine
decodes a file exactly as any OCIO application with the same config does (Blender included). The config is
``$OCIO`` when it is set (its file rules give a plate's default colour space), else OpenImageIO's built-in one
(``ocio://default``: the ACES CG config, ``cg-config-v2.2.0_aces-v1.3_ocio-v2.4`` in the pinned OpenImageIO's
OpenColorIO 2.4, with "ACEScg", "ACEScct", "sRGB Encoded Rec.709 (sRGB)", "Linear Rec.709 (sRGB)", "Raw", ...). A
name the user gives is resolved through the config, aliases included (``srgb_tx``, ``lin_ap1``); a typo is a
one-line error listing the close names.

Without ``--colorspace`` the plate's own header decides where it can (``decide_colorspace``): an EXR's
``oiio:ColorSpace`` tag, $OCIO's file rules, ACES chromaticities, a DPX's transfer. What nothing in the file says is
assumed by file type, and said: the decision carries its source (``terms.colour.COLOUR_SOURCES``, recorded in the run
and its manifests) and, when assumed, one ``note:`` line for the fit to print.

Three spaces have fixed roles (see docs/colour.md):

- ``SCENE_LINEAR`` ("Linear Rec.709 (sRGB)"): Blender's scene-linear space, so the space of edit layers, atlas
  EXRs and the edit composite, like Blender's compositor.
- ``WORKING_ENCODING`` ("sRGB Encoded Rec.709 (sRGB)"): what the fit compares, the sRGB encoding of scene-linear
  Rec.709 (perceptually even errors; values the atlases can hold are in [0, 1]).
- ``RAW`` ("Raw"): data (UV and alpha passes, masks), never converted.

The array API (``srgb_to_linear``, ``linear_to_srgb``, ``to_linear``, ``from_linear``, ``convert``) takes and
returns float32 arrays whose last axis is RGB; any leading shape works.
"""

from __future__ import annotations

import difflib
import functools
import os
from dataclasses import dataclass

import numpy as np
import OpenEXR
import OpenImageIO as oiio

from .. import contract as C
from ..errors import InputError
from ..terms.colour import (
    COLOUR_BUILTIN_CONFIG,
    COLOUR_NAME_MAX,
    COLOUR_SOURCE_ASSUMED,
    COLOUR_SOURCE_FILE,
    COLOUR_SOURCE_FORMAT,
    COLOUR_SOURCE_RULES,
    EXR_COLORSPACE_ATTRIBUTE,
    SRGB_GAMMA,
    SRGB_LINEAR_CUTOFF,
    SRGB_OFFSET,
    SRGB_SCALE,
    SRGB_SLOPE,
)
from .images import native_path

#: OpenImageIO's built-in config (the ACES CG config), used when ``$OCIO`` is not set.
BUILTIN_CONFIG = COLOUR_BUILTIN_CONFIG
SCENE_LINEAR = C.COLOUR_SCENE_LINEAR
WORKING_ENCODING = C.COLOUR_SRGB
SRGB = C.COLOUR_SRGB
RAW = C.COLOUR_RAW
#: Names (or aliases) of the fixed-role spaces in configs that are not the built-in one (Blender's own config
#: calls them "Linear Rec.709" and "sRGB", older ACES configs "Utility - Linear - sRGB" ...): tried in order.
_ROLE_NAMES: dict[str, tuple[str, ...]] = {
    SCENE_LINEAR: (SCENE_LINEAR, "lin_rec709_srgb", "lin_rec709", "Linear Rec.709", "Utility - Linear - sRGB"),
    SRGB: (SRGB, "srgb_tx", "sRGB - Texture", "Utility - sRGB - Texture", "sRGB"),
    RAW: (RAW, "Non-Color", "Utility - Raw", "raw", "none"),
}
#: EXR chromaticities (rx, ry, gx, gy, bx, by, wx, wy) that name a scene-linear ACES space in a float plate.
_ACES_CHROMATICITIES: dict[str, tuple[float, ...]] = {
    "ACEScg": (0.713, 0.293, 0.165, 0.830, 0.128, 0.044, 0.32168, 0.33767),
    "ACES2065-1": (0.7347, 0.2653, 0.0, 1.0, 0.0001, -0.077, 0.32168, 0.33767),
}
#: Rec.709 primaries and D65 white (what scene-linear Rec.709 EXRs are tagged with).
REC709_CHROMATICITIES: tuple[float, ...] = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
#: DPX transfer characteristics that mean a log (printing density) encoding, not the sRGB curve.
LOG_DPX_TRANSFERS = ("Printing density", "Logarithmic")
_CONFIG_FIX = "point $OCIO at a valid OCIO config, or unset it to use the built-in ACES config"
_CONFIG_PARSE_FIX = (
    "correct the config where the error says, point $OCIO at a valid one, or unset $OCIO to use the "
    "built-in ACES config"
)
#: Where OCIO's "Loading the OCIO profile '<path>' failed. " ends and the parser's reason begins.
_OCIO_PREAMBLE_END = "failed. "


def active_config() -> str:
    """The config in use: ``$OCIO`` when set, else the built-in one (what a run records)."""
    return os.environ.get("OCIO", "").strip() or BUILTIN_CONFIG


#: ``ColorConfig.configname()`` of OpenImageIO's own minimal config, which it takes in place of one it cannot use.
OIIO_BUILT_IN = "built-in"


@functools.lru_cache(maxsize=8)
def _load(name: str) -> oiio.ColorConfig:
    """The config ``name``. OpenImageIO answers a config it cannot parse with its own minimal built-in one and an
    error it keeps to itself: taking that would convert with the wrong spaces while the run records ``name``."""
    config = oiio.ColorConfig(name)
    error = config.geterror()
    if error or config.getNumColorSpaces() < 1:
        raise InputError(name, f"cannot load this OCIO config ({_config_reason(error)})", _CONFIG_PARSE_FIX)
    if config.configname() == OIIO_BUILT_IN:  # no error said, and yet not this config (one of data spaces only)
        raise InputError(
            name,
            "OpenImageIO cannot use this OCIO config (its colour spaces are all data) and would take its own built-in "
            "one",
            "add a colour space that is not data to it, point $OCIO at another config, or unset $OCIO",
        )
    return config


def _config_reason(error: str) -> str:
    """The parser's own words (a YAML error names its line) without OCIO's preamble, which repeats the path."""
    reason = error.rsplit(_OCIO_PREAMBLE_END, 1)[-1] if error else "no colour spaces"
    return " ".join(reason.split())


def load_config(name: str | None = None) -> oiio.ColorConfig:
    """The OCIO config ``name`` (default: ``active_config()``); a missing or broken one is a one-line error."""
    name = name or active_config()
    if not name.startswith("ocio://") and not os.path.isfile(name):
        fix = "put the OCIO config back at this path (the run and its exports name it), or fit again"
        raise InputError(name, "OCIO config does not exist", fix if name != active_config() else _CONFIG_FIX)
    return _load(name)


@functools.lru_cache(maxsize=8)
def _names(config_name: str) -> dict[str, str]:
    """Every name and alias of the config, lower-cased -> the colour space's name."""
    config = _load(config_name)
    found: dict[str, str] = {}
    for name in config.getColorSpaceNames():
        for key in (name, *config.getAliases(name)):
            found.setdefault(key.lower(), name)
    for role in config.getRoles():
        space = config.getColorSpaceNameByRole(role)
        if space:
            found.setdefault(role.lower(), space)
    return found


def resolve(name: str, config: str | None = None, option: str = "--colorspace") -> str:
    """The config's name of the colour space ``name`` (a name, an alias or a role, any case); a name the config
    does not know is a one-line error listing the close ones."""
    config = config or active_config()
    load_config(config)
    names = _names(config)
    found = names.get(name.strip().lower())
    if found is None and name.strip() in C.LEGACY_COLORSPACES:  # the engine's own earlier names: "sRGB", "linear"
        found = names.get(C.LEGACY_COLORSPACES[name.strip()].lower())
    if found is not None:
        return found
    spaces = _load(config).getColorSpaceNames()
    close = difflib.get_close_matches(name, spaces, n=4, cutoff=0.4) or difflib.get_close_matches(
        name.lower(), list(names), n=4, cutoff=0.5
    )
    hint = ", ".join(repr(names.get(c, c)) for c in dict.fromkeys(close)) or ", ".join(repr(s) for s in spaces[:6])
    raise InputError(config, f"has no colour space {name!r}", f"give {option} one of its names, e.g. {hint}")


def role_space(role: str, config: str | None = None) -> str:
    """The config's space for one of the fixed roles (``SCENE_LINEAR``, ``SRGB``, ``RAW``)."""
    config = config or active_config()
    load_config(config)
    names = _names(config)
    for candidate in _ROLE_NAMES[role]:
        if candidate.lower() in names:
            return names[candidate.lower()]
    raise InputError(config, f"OCIO config has no space for {role!r}", _CONFIG_FIX)


def recorded_space(colorspace: str, config: str | None) -> tuple[str, str]:
    """(colour space, config) of a run or manifest record. Records made before colour management named only
    "sRGB" or "linear" and no config: they mean the built-in config's sRGB and scene-linear Rec.709."""
    if config is None:
        return C.LEGACY_COLORSPACES.get(colorspace, colorspace), BUILTIN_CONFIG
    return colorspace, config


def is_data(colorspace: str, config: str | None = None) -> bool:
    """Whether the space holds data (Raw, Non-Color): its values are never converted."""
    config = config or active_config()
    return bool(load_config(config).equivalent(colorspace, role_space(RAW, config)))


def is_linear(colorspace: str, config: str | None = None) -> bool:
    """Whether the space is scene-linear (an EXR written in it holds light, not code values): its transform to
    scene-linear Rec.709 scales with the light (a matrix), which a log or gamma curve does not."""
    config = config or active_config()
    probe = np.array([[0.02, 0.18, 0.5], [0.04, 0.36, 1.0]], np.float32)
    out = convert(probe, colorspace, role_space(SCENE_LINEAR, config), config)
    return bool(np.allclose(out[1], 2.0 * out[0], rtol=1e-4, atol=1e-7))


def convert(pixels: np.ndarray, src: str, dst: str, config: str | None = None) -> np.ndarray:
    """``pixels`` (float32, RGB in the last axis) converted from colour space ``src`` to ``dst`` by OCIO. The same
    space (or an equivalent one) returns the float32 input itself, untouched (no copy of a whole clip); alpha
    channels are not passed here."""
    x = np.asarray(pixels, dtype=np.float32)
    config = config or active_config()
    cfg = load_config(config)
    if src == dst or cfg.equivalent(src, dst):
        return x
    shape = x.shape
    if shape[-1] != 3:
        raise ValueError(f"colour conversion needs RGB in the last axis, got shape {shape}")
    flat = np.ascontiguousarray(x.reshape(1, -1, 3)) if x.ndim != 3 else np.ascontiguousarray(x)
    if flat.size == 0:
        return x
    out = oiio.ImageBufAlgo.colorconvert(oiio.ImageBuf(flat), src, dst, False, colorconfig=config)
    if out.has_error:
        raise InputError(config, f"OCIO cannot convert {src!r} to {dst!r} ({out.geterror()})", _CONFIG_FIX)
    return np.asarray(out.get_pixels(oiio.FLOAT), dtype=np.float32).reshape(shape)


def _per_value(x: np.ndarray, src: str, dst: str) -> np.ndarray:
    """A per-channel transform (same primaries: a curve only) over an array of any shape."""
    a = np.asarray(x, dtype=np.float32)
    if a.ndim and a.shape[-1] == 3:
        return convert(a, src, dst, BUILTIN_CONFIG)
    flat = a.reshape(-1)
    pad = (-flat.size) % 3
    rgb = np.concatenate((flat, np.zeros(pad, np.float32))).reshape(-1, 3)
    return convert(rgb, src, dst, BUILTIN_CONFIG).reshape(-1)[: flat.size].reshape(a.shape)


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """sRGB-encoded values (the built-in "sRGB Encoded Rec.709 (sRGB)") as scene-linear Rec.709, by OCIO: the
    transform Blender applies to an sRGB image (the same float32 values, docs/colour.md). Any shape."""
    return _per_value(x, SRGB, SCENE_LINEAR)


def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """Scene-linear Rec.709 as sRGB-encoded values, by OCIO (negatives and values above 1 follow the curve)."""
    return _per_value(x, SCENE_LINEAR, SRGB)


def legacy_linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """The sRGB encoding the engine computed before colour management (the IEC formula in float32): only a resume of
    a fit made then uses it, so the fitted values, and the fingerprint that ties the checkpoint to them, match."""
    x = np.asarray(x, dtype=np.float32)
    a = np.abs(x)
    encoded = SRGB_SCALE * np.power(a, 1.0 / SRGB_GAMMA, dtype=np.float32) - SRGB_OFFSET
    enc = np.where(a <= SRGB_LINEAR_CUTOFF, a * SRGB_SLOPE, encoded)
    return (np.sign(x) * enc).astype(np.float32)


def to_linear(x: np.ndarray, colorspace: str, config: str | None = None) -> np.ndarray:
    """Pixel values of a file in ``colorspace`` as scene-linear Rec.709 float32 (legacy "sRGB"/"linear" records
    are read as the built-in config's spaces)."""
    space, config = recorded_space(colorspace, config)
    return convert(x, space, role_space(SCENE_LINEAR, config), config)


def from_linear(x: np.ndarray, colorspace: str, config: str | None = None) -> np.ndarray:
    """Scene-linear Rec.709 values as ``colorspace`` (the inverse of ``to_linear``)."""
    space, config = recorded_space(colorspace, config)
    return convert(x, role_space(SCENE_LINEAR, config), space, config)


def to_working(x: np.ndarray, colorspace: str, config: str | None = None) -> np.ndarray:
    """Pixel values of a file in ``colorspace`` in the fit's working encoding (sRGB-encoded Rec.709)."""
    space, config = recorded_space(colorspace, config)
    return convert(x, space, role_space(SRGB, config), config)


def chromaticities(colorspace: str, config: str | None = None) -> tuple[float, ...] | None:
    """The EXR chromaticities (primaries and white) of a space: Rec.709 for the Rec.709 spaces, AP1 for ACEScg,
    ACEScct and ACEScc, AP0 for ACES2065-1; None for a space whose primaries are not one of these (data, P3, ...):
    an EXR without the attribute is read as Rec.709, so a wrong tag is worse than none."""
    config = config or active_config()
    cfg = load_config(config)
    if any(cfg.equivalent(colorspace, role_space(role, config)) for role in (SCENE_LINEAR, SRGB)):
        return REC709_CHROMATICITIES
    names = _names(config)
    for aces, primaries in (("ACEScg", "ACEScg"), ("ACEScct", "ACEScg"), ("ACEScc", "ACEScg"), ("ACES2065-1", None)):
        if names.get(aces.lower()) == colorspace:
            return _ACES_CHROMATICITIES[primaries or aces]
    return None


@dataclass(frozen=True)
class FileColour:
    """What a file's header says about its colour (read once, from the first frame)."""

    is_float: bool
    extension: str
    dpx_transfer: str = ""
    chromaticities: tuple[float, ...] = ()


def file_colour(spec: oiio.ImageSpec, path: str) -> FileColour:
    """The colour facts of an image header (DPX transfer, EXR chromaticities)."""
    chroma = spec.getattribute("chromaticities")
    return FileColour(
        is_float=spec.format.basetype in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE),
        extension=os.path.splitext(path)[1].lower(),
        dpx_transfer=str(spec.getattribute("dpx:Transfer") or ""),
        chromaticities=tuple(float(v) for v in chroma) if chroma is not None else (),
    )


def dpx_encoding(facts: FileColour) -> str:
    """What a DPX header's transfer says of its code values: "log", "linear", or "sRGB" (any other transfer, which
    the default colour space reads with the sRGB curve); "" for a file that is not a DPX. One clip has one."""
    if facts.extension != ".dpx":
        return ""
    if facts.dpx_transfer in LOG_DPX_TRANSFERS:
        return "log"
    return "linear" if facts.dpx_transfer == "Linear" else "sRGB"


def _same_chromaticities(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return len(a) == len(b) == 8 and all(abs(x - y) < 1e-3 for x, y in zip(a, b, strict=True))


#: EXR header attributes that name the file's colour space, in the order they are read: OpenImageIO's tag (what
#: this engine's renders and OIIO-based tools write) and OpenEXR's standard ``colorInteropID`` (``lin_ap1_scene``).
#: OpenImageIO itself reports "lin_rec709" for every EXR that has neither, so the header is read as written.
EXR_TAG_ATTRIBUTES: tuple[str, ...] = (EXR_COLORSPACE_ATTRIBUTE, "colorInteropID")
#: File types whose own specification makes untagged pixels sRGB (PNG, JPEG/JFIF): no assumption is made there.
SRGB_BY_FORMAT: tuple[str, ...] = (".png", ".jpg", ".jpeg")
#: DPX transfers that say nothing of the code values (read with the sRGB curve, as assumed).
_UNDECLARED_DPX_TRANSFERS = ("", "Undefined", "User defined", "Unspecified video")


@dataclass(frozen=True)
class PlateColour:
    """A plate's colour space as decided, and how (``terms.colour.COLOUR_SOURCES``); ``note`` is the one ``note:`` line
    a fit prints when it was assumed ("" otherwise)."""

    space: str
    source: str
    note: str = ""


def header_tag(path: str) -> str:
    """The colour space an EXR's header names (``EXR_TAG_ATTRIBUTES``), as written; "" for none or another type."""
    if os.path.splitext(path)[1].lower() != ".exr":
        return ""
    try:
        with OpenEXR.File(native_path(path), header_only=True) as f:
            # read inside the block: OpenEXR empties the header's dict when the file closes
            values = [f.header().get(name) for name in EXR_TAG_ATTRIBUTES]
    except Exception:  # an unreadable header: the clip's own checks name the file
        return ""
    for value in values:
        if isinstance(value, str) and value.strip() and value.isprintable():
            return value.strip()[:COLOUR_NAME_MAX]
    return ""


def _tagged_space(tag: str, config: str) -> str | None:
    """The config's space for a header's tag: its name, alias or role in the config; else, where the built-in config
    knows the tag as one of the fixed-role spaces (scene-linear Rec.709, sRGB, data), the config's space for that
    role; None when neither (the tag is then said in the note, and not used)."""
    try:
        return resolve(tag, config, "the file's oiio:ColorSpace")
    except InputError:
        pass
    if config == BUILTIN_CONFIG:
        return None
    try:
        builtin = resolve(tag, BUILTIN_CONFIG)
    except InputError:
        return None
    cfg = load_config(BUILTIN_CONFIG)
    for role in (SCENE_LINEAR, SRGB, RAW):
        if cfg.equivalent(builtin, role):
            return role_space(role, config)
    return None


def decide_colorspace(path: str, facts: FileColour | None, config: str | None = None) -> PlateColour:
    """A plate's colour space when ``--colorspace`` is not given, and how it was decided, in this order: the EXR
    header's tag (``header_tag``); the config's file rules when they match the path; a float file's ACES
    chromaticities; then by file type: float files scene-linear Rec.709, integer files and movies sRGB. Only what a
    header states, a rule, or a file type that defines its colour (PNG, JPEG) counts as known; the rest is assumed,
    with a ``note`` saying so. A DPX that declares a log transfer is refused: the sRGB curve would be wrong, and the
    right log space is the user's to name."""
    config = config or active_config()
    cfg = load_config(config)
    tag = header_tag(path) if facts is not None else ""
    tagged = _tagged_space(tag, config) if tag else None
    if tagged is not None:
        return PlateColour(tagged, COLOUR_SOURCE_FILE)
    ruled = cfg.getColorSpaceFromFilepath(path) if config != BUILTIN_CONFIG else ""
    if ruled:
        return PlateColour(resolve(ruled, config, "the config's file rules"), COLOUR_SOURCE_RULES)
    if facts is None:  # a movie
        return _assumed(path, role_space(SRGB, config), "a movie states no colour space the engine reads")
    if facts.is_float:
        return _float_space(path, facts, config, tag)
    encoding = dpx_encoding(facts)
    if encoding == "log":
        raise InputError(
            path,
            f"this DPX declares a log transfer ({facts.dpx_transfer}); decoding it with the sRGB curve would be wrong",
            "name its colour space, e.g. --colorspace ACEScct, or set $OCIO to a config with a Cineon log space",
        )
    if encoding == "linear":
        return PlateColour(role_space(SCENE_LINEAR, config), COLOUR_SOURCE_FILE)
    srgb = role_space(SRGB, config)
    if facts.extension in SRGB_BY_FORMAT:
        return PlateColour(srgb, COLOUR_SOURCE_FORMAT)
    if encoding and facts.dpx_transfer not in _UNDECLARED_DPX_TRANSFERS:
        why = f"its DPX transfer {facts.dpx_transfer!r} is read with the sRGB curve"
    else:
        why = "an integer file whose header names no colour space"
    return _assumed(path, srgb, why)


def _float_space(path: str, facts: FileColour, config: str, tag: str) -> PlateColour:
    """A float file's space from its chromaticities: ACES AP1/AP0 (known), Rec.709 (known: scene-linear Rec.709),
    none or others (assumed scene-linear Rec.709)."""
    names = _names(config)
    for name, chroma in _ACES_CHROMATICITIES.items():
        if _same_chromaticities(facts.chromaticities, chroma) and name.lower() in names:
            return PlateColour(names[name.lower()], COLOUR_SOURCE_FILE)
    linear = role_space(SCENE_LINEAR, config)
    if _same_chromaticities(facts.chromaticities, REC709_CHROMATICITIES):
        return PlateColour(linear, COLOUR_SOURCE_FILE)
    said = "other chromaticities" if facts.chromaticities else "no chromaticities"
    tagged = f"a tag {tag!r} that {config} does not know" if tag else "no colour-space tag"
    return _assumed(path, linear, f"a float file with {tagged} and {said}")


def _assumed(path: str, space: str, why: str) -> PlateColour:
    """An assumed space and its one ``note:`` line: what was assumed, why, and how to say otherwise."""
    note = (
        f"note: {path}: colour space assumed {space!r} ({why}) — if the plate is in another, name it with "
        "--colorspace, e.g. ACEScg"
    )
    return PlateColour(space, COLOUR_SOURCE_ASSUMED, note)


def default_colorspace(path: str, facts: FileColour | None, config: str | None = None) -> str:
    """A plate's colour space when ``--colorspace`` is not given (``decide_colorspace``'s space)."""
    return decide_colorspace(path, facts, config).space


__all__ = [
    "BUILTIN_CONFIG",
    "RAW",
    "REC709_CHROMATICITIES",
    "SCENE_LINEAR",
    "SRGB",
    "WORKING_ENCODING",
    "FileColour",
    "PlateColour",
    "active_config",
    "chromaticities",
    "convert",
    "decide_colorspace",
    "default_colorspace",
    "dpx_encoding",
    "file_colour",
    "from_linear",
    "header_tag",
    "is_data",
    "is_linear",
    "legacy_linear_to_srgb",
    "linear_to_srgb",
    "load_config",
    "recorded_space",
    "resolve",
    "role_space",
    "srgb_to_linear",
    "to_linear",
    "to_working",
]
