"""Blender's colour spaces for the engine's: the plate's (as the manifest names it), the EXR render's and an edit
layer's. The engine names spaces as OCIO's built-in config does; Blender 4.5 and 5.0 name some of them otherwise and
lack some. No bpy here.
"""

from __future__ import annotations

from typing import Any

from ...engine import contract as C  # type: ignore[import-not-found]

#: Blender's names (4.5 and 5.0 configs) for the engine's OCIO colour spaces, by the built-in config's name; the
#: first one Blender has is used. Blender 4.5 has no ACEScc/ACEScct (5.0 has both).
BLENDER_COLORSPACES: dict[str, tuple[str, ...]] = {
    C.COLOUR_SRGB: ("sRGB",),
    C.COLOUR_SCENE_LINEAR: ("Linear Rec.709",),
    C.COLOUR_RAW: ("Non-Color",),
    "ACEScg": ("ACEScg",),
    "ACES2065-1": ("ACES2065-1",),
    "ACEScct": ("ACEScct",),
    "ACEScc": ("ACEScc",),
    "Linear Rec.2020": ("Linear Rec.2020",),
    "Linear P3-D65": ("Linear DCI-P3 D65",),
}
#: The aliases the built-in config gives those spaces (a manifest made with an $OCIO config may use them).
OCIO_ALIASES: dict[str, str] = {
    "srgb_tx": C.COLOUR_SRGB,
    "srgb_texture": C.COLOUR_SRGB,
    "srgb - texture": C.COLOUR_SRGB,
    "utility - srgb - texture": C.COLOUR_SRGB,
    "srgb_encoded_rec709_srgb": C.COLOUR_SRGB,
    "lin_rec709": C.COLOUR_SCENE_LINEAR,
    "lin_rec709_srgb": C.COLOUR_SCENE_LINEAR,
    "lin_srgb": C.COLOUR_SCENE_LINEAR,
    "utility - linear - srgb": C.COLOUR_SCENE_LINEAR,
    "utility - linear - rec.709": C.COLOUR_SCENE_LINEAR,
    "lin_ap1": "ACEScg",
    "aces - acescg": "ACEScg",
    "lin_ap0": "ACES2065-1",
    "aces - aces2065-1": "ACES2065-1",
    "acescct_ap1": "ACEScct",
    "aces - acescct": "ACEScct",
    "acescc_ap1": "ACEScc",
    "aces - acescc": "ACEScc",
    "utility - raw": C.COLOUR_RAW,
    "none": C.COLOUR_RAW,
    "raw": C.COLOUR_RAW,
}
#: The scene-linear spaces among them: Blender writes its EXR render in the plate's space when it is one of these
#: (as ``engine render`` does), else in its scene-linear Rec.709.
LINEAR_COLORSPACES = frozenset({C.COLOUR_SCENE_LINEAR, "ACEScg", "ACES2065-1", "Linear Rec.2020", "Linear P3-D65"})


def engine_colorspace(clip: dict[str, Any]) -> str:
    """The manifest clip's colour space in the built-in config's words (older manifests' "sRGB"/"linear" mapped;
    an alias mapped to its name; any other name kept as it is)."""
    name = str(clip.get("colorspace", "sRGB"))
    if "colour_config" not in clip:
        return C.LEGACY_COLORSPACES.get(name, name)
    return OCIO_ALIASES.get(name.lower(), name)


def blender_colorspace(name: str, available: frozenset[str] | None = None) -> str | None:
    """Blender's colour space for the engine's OCIO space ``name``: its entry in BLENDER_COLORSPACES, else the same
    name (a studio $OCIO config that Blender also uses); None when Blender has none of them (``available``: the
    names this Blender offers; None: assumed to have them all)."""
    for candidate in (*BLENDER_COLORSPACES.get(name, ()), name):
        if available is None or candidate in available:
            return candidate
    return None


def output_colorspace(clip: dict[str, Any]) -> str:
    """Blender's colour space for the EXR render: the plate's when it is scene-linear, else Linear Rec.709 (what
    ``engine render --format exr`` writes)."""
    name = engine_colorspace(clip)
    space = name if name in LINEAR_COLORSPACES else C.COLOUR_SCENE_LINEAR
    return BLENDER_COLORSPACES[space][0]


def edit_colorspace(path: str) -> str:
    """An edit layer is an sRGB PNG with straight alpha, or a linear float EXR with premultiplied alpha."""
    return "Non-Color" if path.lower().endswith(C.EDIT_LAYER_FLOAT_EXT) else "sRGB"
