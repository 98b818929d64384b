"""Colour: the plate's colour space as a clip record and a manifest name it, how it was decided, and the sRGB
transfer function both sides decode with."""

from __future__ import annotations

import math
from typing import Any

#: The colour-space values of records made before colour management (no "colour_config" beside them); still read.
COLORSPACES: tuple[str, ...] = ("sRGB", "linear")
#: Colour (docs/colour.md). A clip's "colorspace" is the name of its plate's colour space in the OCIO config named by
#: "colour_config" ($OCIO's path when it was set, else COLOUR_BUILTIN_CONFIG). Records without "colour_config" were
#: made before colour management: their "sRGB"/"linear" mean the built-in config's spaces below (LEGACY_COLORSPACES).
COLOUR_BUILTIN_CONFIG = "ocio://default"
#: Blender's scene-linear space (edit layers, atlas EXRs, the edit composite), in the built-in config's words.
COLOUR_SCENE_LINEAR = "Linear Rec.709 (sRGB)"
#: The sRGB encoding of COLOUR_SCENE_LINEAR (PNG edit layers and atlases; the fit's working encoding).
COLOUR_SRGB = "sRGB Encoded Rec.709 (sRGB)"
#: Data: passes, masks (never converted).
COLOUR_RAW = "Raw"
LEGACY_COLORSPACES: dict[str, str] = {"sRGB": COLOUR_SRGB, "linear": COLOUR_SCENE_LINEAR}
#: The EXR header attribute that names a file's colour space for OCIO readers (OpenImageIO's): passes say COLOUR_RAW.
EXR_COLORSPACE_ATTRIBUTE = "oiio:ColorSpace"
#: The longest colour-space or config name a record may hold (a path to a config file included).
COLOUR_NAME_MAX = 4096
#: How the plate's colour space was decided, recorded beside it as "colour_source" (clip.json and the manifest's
#: clip; absent from runs made before it was kept): named (``--colorspace``), stated by the file's header (an EXR's
#: oiio:ColorSpace tag, ACES or Rec.709 chromaticities, a DPX's linear transfer), chosen by $OCIO's file rules, given
#: by a file type that defines its colour (PNG, JPEG: sRGB), or assumed: nothing said it (a float file read as
#: scene-linear Rec.709; a TIFF, an undeclared DPX or a movie as sRGB), and the fit printed one ``note:`` line.
COLOUR_SOURCE_ASKED = "asked"
COLOUR_SOURCE_FILE = "file"
COLOUR_SOURCE_RULES = "rules"
COLOUR_SOURCE_FORMAT = "format"
COLOUR_SOURCE_ASSUMED = "assumed"
COLOUR_SOURCES: tuple[str, ...] = (
    COLOUR_SOURCE_ASKED,
    COLOUR_SOURCE_FILE,
    COLOUR_SOURCE_RULES,
    COLOUR_SOURCE_FORMAT,
    COLOUR_SOURCE_ASSUMED,
)


def valid_colour_record(colorspace: Any, config: Any) -> bool:
    """A clip record's colour: a legacy value without a config, or a space name with its config (non-empty
    strings, no control characters); whether the config knows the name is the engine's check (OCIO)."""

    def name(v: Any) -> bool:
        return isinstance(v, str) and 0 < len(v) <= COLOUR_NAME_MAX and v.isprintable()

    if config is None:
        return colorspace in COLORSPACES
    return name(colorspace) and name(config)


#: The sRGB transfer function (IEC 61966-2-1): encoded values at or below SRGB_ENCODED_CUTOFF decode through the
#: linear segment (divide by SRGB_SLOPE), the others as ((c + SRGB_OFFSET) / SRGB_SCALE) ** SRGB_GAMMA.
SRGB_ENCODED_CUTOFF = 0.04045
#: Linear values at or below this encode through the linear segment.
SRGB_LINEAR_CUTOFF = 0.0031308
SRGB_SLOPE = 12.92
SRGB_OFFSET = 0.055
SRGB_SCALE = 1.055
SRGB_GAMMA = 2.4


def srgb_to_linear(c: float) -> float:
    """Decode one sRGB-encoded value to linear by the exact IEC formula; values outside [0, 1] extend the curve
    symmetrically. (The engine and Blender decode images by OCIO's float32 form of this curve, which differs by up
    to 2.4e-5: ``engine.io.colour.srgb_to_linear``, docs/colour.md.)"""
    a = abs(c)
    lin = a / SRGB_SLOPE if a <= SRGB_ENCODED_CUTOFF else ((a + SRGB_OFFSET) / SRGB_SCALE) ** SRGB_GAMMA
    return math.copysign(lin, c)


#: What ``engine.contract`` re-exports from this module (its own names, not its imports).
__all__ = [
    "COLORSPACES",
    "COLOUR_BUILTIN_CONFIG",
    "COLOUR_NAME_MAX",
    "COLOUR_RAW",
    "COLOUR_SCENE_LINEAR",
    "COLOUR_SOURCES",
    "COLOUR_SOURCE_ASKED",
    "COLOUR_SOURCE_ASSUMED",
    "COLOUR_SOURCE_FILE",
    "COLOUR_SOURCE_FORMAT",
    "COLOUR_SOURCE_RULES",
    "COLOUR_SRGB",
    "EXR_COLORSPACE_ATTRIBUTE",
    "LEGACY_COLORSPACES",
    "SRGB_ENCODED_CUTOFF",
    "SRGB_GAMMA",
    "SRGB_LINEAR_CUTOFF",
    "SRGB_OFFSET",
    "SRGB_SCALE",
    "SRGB_SLOPE",
    "srgb_to_linear",
    "valid_colour_record",
]
