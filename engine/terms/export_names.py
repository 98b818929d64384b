"""An export's names: its folders, the pass files and their EXR layers, passes and channels, the atlas textures
and the edit layers the artist paints."""

from __future__ import annotations

import os

from .clip import FRAME_FILE_DIGITS

# A run folder holds any number of exports, each in its own versioned folder that is never rewritten:
#   RUN_DIR/exports/v001/manifest.json, passes/atlas.00000.exr ..., atlases/<Layer>.exr|.png
# and ONE set of edit layers shared by every export of the run (the artist's paint, never overwritten):
#   RUN_DIR/edits/<Layer>.png (+ RUN_DIR/edits/layout.json, the atlas frame each edit layer was painted in)
EXPORTS_DIR = "exports"
EXPORT_VERSION_FORMAT = "v{:03d}"
#: A farm's staged export (``export --into vNNN --stage ...``) is assembled in ``exports/.vNNN`` + this suffix until
#: it is published; the farm plan reads the same name to continue an unfinished one.
EXPORT_CHUNKS_SUFFIX = ".chunks"
EDITS_DIR = "edits"
EDITS_LAYOUT = "layout.json"
#: ``edits/aligned.json``: {"neural_atlas_aligned": 1, "export": "vNNN"}, the export whose mapping the edit layers
#: were painted against (written by ``fit --refine`` when missing, and by ``realign``)
EDITS_ALIGNED = "aligned.json"
EDITS_ALIGNED_TAG = "neural_atlas_aligned"

PASSES_DIR = "passes"
ATLASES_DIR = "atlases"
#: Pass files are named by the plate's frame number, padded as the plate's frame files are (``frame_padding``): a
#: plate.1001.exr gives passes/atlas.1001.exr (Blender reads the last digits). A plate with no padding of its own (a
#: movie, frames whose digits vary) gives PASS_FILE_DIGITS digits. The manifest's "pattern" names them: readers
#: take it from there (exports made before the padding followed the plate have five digits).
PASS_FILE_PREFIX = "atlas."
PASS_FILE_DIGITS = 5
PASS_FILE_EXT = ".exr"

#: The single EXR layer of every pass file; Blender's multilayer convention is <layer>.<pass>.<channel>,
#: so one Image node exposes one socket per pass.
EXR_LAYER = "Atlas"
UV_PASS_PREFIX = "UV"  # UV<Layer>: channels U, V, A = u, v (0..1, origin bottom-left), the layer's alpha
#: Alpha<Layer>: one channel V, the layer's alpha (opacity weight; the layers' sum to 1, less by 2^-11 per layer in a
#: compact export: PASS_PRECISIONS)
ALPHA_PASS_PREFIX = "Alpha"
#: A UV pass's channels in the order u, v, coverage: Blender's own name for its UV render pass (``UV.U``, ``UV.V``,
#: ``UV.A``), which its Image node gives Map UV as one vector (it orders U, V, A by letter). OpenImageIO takes a channel
#: named "Z" or "*.Z" as depth (its z_channel) and one named "A" or "*.A" as alpha: the coverage is an alpha.
#: Each manifest layer records its "uv_channels" in this order, so an export of either naming reads the same.
UV_CHANNELS: tuple[str, ...] = ("U", "V", "A")
#: The UV pass's channels in exports made before it took Blender's naming (OpenImageIO read their Z as depth).
LEGACY_UV_CHANNELS: tuple[str, ...] = ("X", "Y", "Z")
ALPHA_CHANNELS: tuple[str, ...] = ("V",)
#: The same UV pass for Nuke, Flame and Natron, in the same pass files: per layer a layer with ONE dot in its channel
#: names, STMap<Layer>.R/G/B/A = u, v, 0 and the coverage (the UV pass's A), float32 copies of the same values.
#: Nuke's EXR reader turns every dot but the last into "_" (Atlas.UVForeground.U shows as Atlas_UVForeground.U) and
#: R/G/B/A into red/green/blue/alpha, so these show as STMap<Layer>.red/green/blue/alpha: an RGBA layer whose rg is
#: what STMap reads and whose alpha is the coverage. Blender's Image node skips one-dot names: its passes are unchanged.
STMAP_PASS_PREFIX = "STMap"
STMAP_CHANNELS: tuple[str, ...] = ("R", "G", "B", "A")
#: How many of the networks' bits the pass files keep (the manifest's passes "precision"; absent: "full", as exports
#: made before it was chosen). Every channel is float32 in both, so every reader reads both alike. ``compact`` (the
#: default) rounds the alpha and the coverage down to half float's precision (at most 2^-11 = 4.9e-4 off: invisible in a
#: matte) and u, v to multiples of PASS_UV_STEP (0.03 texel on a 4096 atlas): the low bits the networks leave are
#: noise that ZIP cannot compress, and without them a frame of passes takes half the bytes. ``full`` keeps every bit.
PASS_PRECISION_COMPACT = "compact"
PASS_PRECISION_FULL = "full"
PASS_PRECISIONS: tuple[str, ...] = (PASS_PRECISION_COMPACT, PASS_PRECISION_FULL)
PASS_UV_STEP = 2.0**-17
#: The Nuke script an export writes next to its manifest (``engine nuke`` writes one anywhere).
NUKE_SCRIPT_NAME = "neural_atlas.nk"

ROLE_BACKGROUND = "background"
ROLE_FOREGROUND = "foreground"

#: Edit layers are RGBA, sRGB-encoded, straight alpha (8-bit PNG: Blender loads it exactly as sRGB).
EDIT_LAYER_EXT = ".png"
#: ...or a float edit layer next to it, RUN_DIR/edits/<Layer>.exr: scene-linear, premultiplied RGBA (what a
#: compositor paints in; no 8-bit quantisation, no sRGB decode). The export only ever creates the PNG, so an
#: EXR beside it is the artist's deliberate choice: when both exist the EXR is used (``edit_layer_file``).
EDIT_LAYER_FLOAT_EXT = ".exr"


def edit_layer_file(edit_layer: str) -> str:
    """The edit layer file in use for a manifest's ``edit_layer`` path (the PNG the export made): its float
    twin ``<same name>.exr`` when that exists, else the path itself. The engine and the add-on both call this,
    so they always read the same paint."""
    if os.path.splitext(edit_layer)[1].lower() == EDIT_LAYER_EXT:
        exr = float_edit_layer(edit_layer)
        if os.path.exists(exr):
            return exr
    return edit_layer


def float_edit_layer(edit_layer: str) -> str:
    """The float twin of an edit layer: ``<same name>.exr`` beside it (whether or not it exists yet)."""
    return os.path.splitext(edit_layer)[0] + EDIT_LAYER_FLOAT_EXT


#: Atlas textures: a float EXR (linear, premultiplied RGBA) and a 16-bit PNG (sRGB, straight alpha).
ATLAS_EXR_EXT = ".exr"
ATLAS_PNG_EXT = ".png"
#: ``export --atlas-size``: texels on an atlas texture's long side (default: the paper's), and the range accepted.
ATLAS_SIZE_DEFAULT = 1000
ATLAS_SIZE_RANGE: tuple[int, int] = (8, 16384)


def layer_name(index: int, num_layers: int) -> str:
    """Layer names used in channel names and file names: Background, Foreground (or Foreground1, 2, ...)."""
    if index == 0:
        return "Background"
    return "Foreground" if num_layers == 2 else f"Foreground{index}"


def uv_pass(layer: str) -> str:
    return f"{UV_PASS_PREFIX}{layer}"


def alpha_pass(layer: str) -> str:
    return f"{ALPHA_PASS_PREFIX}{layer}"


def stmap_pass(layer: str) -> str:
    return f"{STMAP_PASS_PREFIX}{layer}"


def stmap_channel_name(layer: str, channel: str) -> str:
    """Full EXR channel name of a layer's STMap copy, e.g. ``STMapForeground.R`` (one dot: Nuke shows it as is)."""
    return f"{stmap_pass(layer)}.{channel}"


def channel_name(pass_name: str, channel: str) -> str:
    """Full EXR channel name, e.g. ``Atlas.UVForeground.U``."""
    return f"{EXR_LAYER}.{pass_name}.{channel}"


def pass_file_name(frame_number: int, padding: int = PASS_FILE_DIGITS) -> str:
    """``atlas.00012.exr`` for plate frame 12 (``padding`` digits at least)."""
    return pass_pattern(padding).format(frame=frame_number)


def pass_pattern(padding: int) -> str:
    """The manifest's "pattern" of pass files padded to ``padding`` digits: ``atlas.{frame:04d}.exr``."""
    return f"{PASS_FILE_PREFIX}{{frame:0{padding}d}}{PASS_FILE_EXT}"


def blender_pattern(padding: int) -> str:
    """The same pattern as Blender and most compositors write it: ``atlas.####.exr``."""
    return f"{PASS_FILE_PREFIX}{'#' * padding}{PASS_FILE_EXT}"


#: The rendered frames' default name: ``edit.`` + the plate's frame number padded as ``frame_padding`` says + the
#: extension (``edit.1001.exr`` for a ``plate.1001.exr``), as ``engine render`` and the add-on's Render Edited Clip
#: both write it.
RENDER_FRAME_PREFIX = "edit."


def frame_padding(frame_files: list[str] | tuple[str, ...], frame_numbers: list[int] | tuple[int, ...]) -> int:
    """The digits a plate's frame files pad their numbers to: 4 for ``plate.1001.exr`` .. (and for ``plate.0998.exr``
    .. ``plate.1001.exr``), 1 for ``f9.png``, ``f10.png``; PASS_FILE_DIGITS for a movie (no files) or names that are
    not the frame number padded one way. What the outputs numbered by the plate's frames follow."""
    digits = []
    for path, number in zip(frame_files, frame_numbers, strict=False):
        m = FRAME_FILE_DIGITS.search(os.path.basename(path))
        if m is None or int(m.group(1)) != number:
            return PASS_FILE_DIGITS
        digits.append(m.group(1))
    if not digits:
        return PASS_FILE_DIGITS
    padding = min(len(d) for d in digits)
    if any(d != f"{n:0{padding}d}" for d, n in zip(digits, frame_numbers, strict=False)):
        return PASS_FILE_DIGITS
    return padding


#: What ``engine.contract`` re-exports from this module (its own names, not its imports).
__all__ = [
    "ALPHA_CHANNELS",
    "ALPHA_PASS_PREFIX",
    "ATLASES_DIR",
    "ATLAS_EXR_EXT",
    "ATLAS_PNG_EXT",
    "ATLAS_SIZE_DEFAULT",
    "ATLAS_SIZE_RANGE",
    "EDITS_ALIGNED",
    "EDITS_ALIGNED_TAG",
    "EDITS_DIR",
    "EDITS_LAYOUT",
    "EDIT_LAYER_EXT",
    "EDIT_LAYER_FLOAT_EXT",
    "EXPORTS_DIR",
    "EXPORT_CHUNKS_SUFFIX",
    "EXPORT_VERSION_FORMAT",
    "EXR_LAYER",
    "LEGACY_UV_CHANNELS",
    "NUKE_SCRIPT_NAME",
    "PASSES_DIR",
    "PASS_FILE_DIGITS",
    "PASS_FILE_EXT",
    "PASS_FILE_PREFIX",
    "PASS_PRECISIONS",
    "PASS_PRECISION_COMPACT",
    "PASS_PRECISION_FULL",
    "PASS_UV_STEP",
    "RENDER_FRAME_PREFIX",
    "ROLE_BACKGROUND",
    "ROLE_FOREGROUND",
    "STMAP_CHANNELS",
    "STMAP_PASS_PREFIX",
    "UV_CHANNELS",
    "UV_PASS_PREFIX",
    "alpha_pass",
    "blender_pattern",
    "channel_name",
    "edit_layer_file",
    "float_edit_layer",
    "frame_padding",
    "layer_name",
    "pass_file_name",
    "pass_pattern",
    "stmap_channel_name",
    "stmap_pass",
    "uv_pass",
]
