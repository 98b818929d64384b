"""The live preview as plain data: a plate-shaped plane whose material is the engine's render equation, and the
orthographic camera that frames it. No bpy here (``addon/preview_plane.py`` builds it).

Per pixel of the plane (its UVs 0..1 cover the plate), for layers i with UV pass (u_i, v_i, Z_i) and edit image
E_i (float, linear, premultiplied) sampled at (u_i, v_i)

    A_i = E_i.alpha * Z_i,   rgb_i = E_i.rgb * Z_i,   out = plate * (1 - sum_i A_i) + sum_i rgb_i

which is ``engine/edit/equations.py`` and the compositor tree of ``tree_plan``. The edit images are the datablocks
the paint canvases paint into, so a stroke shows at once; the plate and the UV passes are image sequences that
follow the scene frame, so scrubbing shows other frames with the same paint. A shader Image Texture cannot pick the
pass of a multilayer EXR from Python (``exr_passes``): each layer's UV pass is split into a plain RGB EXR sequence
(R=u, G=v, B=Z) beside the export (``PREVIEW_UV_DIR``). An image ``NA_FramePaint``, when it exists, is laid over
the composite by its alpha at the plane's own UVs (node ``FramePaint``: the paint slot for painting on the plane).

At a proxy size (``preview_proxy``: below 100 %) the UV passes and a sequence plate are written at that size under
``preview_proxy.PROXY_DIR`` and the images show those files; the plane, its camera and the edit images are the same.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ...engine import contract as C  # type: ignore[import-not-found]
from . import preview_proxy as X
from . import tree_plan as P

PREVIEW_OBJECT = P.PREVIEW_OBJECT
PREVIEW_COLLECTION = P.PREVIEW_OBJECT
PREVIEW_MATERIAL = P.PREVIEW_OBJECT
PREVIEW_CAMERA = f"{P.PREFIX}PreviewCam"
PREVIEW_PLATE_IMAGE = f"{P.PREFIX}PreviewPlate"
#: The folder beside the manifest with each layer's UV pass as plain RGB EXRs: ``preview_uv/<Layer>/uv.#####.exr``.
PREVIEW_UV_DIR = "preview_uv"
#: The node that shows ``tree_plan.FRAME_PAINT_IMAGE`` (its name is the paint slot's, kept stable).
FRAME_PAINT_NODE = "FramePaint"
#: The node whose value is 1 on the exported frames and 0 elsewhere (a driver on the scene frame): outside the export
#: the layers' passes hold their last frame, so the paint is gated off and the plate shows alone.
IN_EXPORT_NODE = "InExport"
#: The material's custom property holding the exported frames [first, last] (the panel's "outside the export" line).
EXPORT_FRAMES_PROP = "na_export_frames"
#: The material's custom property holding the preview's size [percent, width, height] (the panel's size line).
PROXY_PROP = "na_preview_proxy"

#: The plane is 1 unit high; its right edge this far left of x = 0, where the paint canvases start.
PLANE_HEIGHT = 1.0
PLANE_GAP = 0.2
#: The camera looks down -Z from this height above the plane.
CAMERA_HEIGHT = 2.0

# shader node kinds (``addon/preview_plane.py`` knows their bpy types)
TEX_COORD = "tex_coord"  # output "UV"
TEX_IMAGE = "tex_image"  # input "Vector"; outputs "Color", "Alpha"
SEPARATE_XYZ = "separate_xyz"  # input "Vector"; outputs "X", "Y", "Z"
COMBINE_XYZ = "combine_xyz"  # inputs "X", "Y", "Z"; output "Vector"
MATH = "math"  # inputs 0, 1; output "Value"; params "operation"
VECTOR_MATH = "vector_math"  # inputs 0, 1, "Scale"; output "Vector"; params "operation"
MIX = "mix"  # RGBA mix: inputs "Factor", "A", "B"; output "Result"
VALUE = "value"  # output "Value"; params "value", and "driver": an expression Blender evaluates at each frame
EMISSION = "emission"  # input "Color"; output "Emission"
OUTPUT = "output"  # input "Surface"

#: The edit images' interpolation for each filter (``tree_plan.FILTERS``): Linear is the engine's bilinear, Closest
#: its nearest (the compositor's Map UV samples the same way on every version: ``compat.set_map_uv_filter``).
INTERPOLATION = {P.FILTER_BILINEAR: "Linear", P.FILTER_NEAREST: "Closest"}


@dataclass(frozen=True)
class ShaderNode:
    name: str
    kind: str
    location: tuple[float, float]
    params: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class ShaderLink:
    """``from_socket``/``to_socket``: a socket's name (its first enabled socket of that name) or its index."""

    from_node: str
    from_socket: str | int
    to_node: str
    to_socket: str | int


@dataclass(frozen=True)
class SequenceUser:
    """An Image Texture's image user for a file sequence or movie: scene frame F shows file number (or movie frame)
    ``F - frame_start + 1 + frame_offset``, within ``frame_duration`` frames (Blender's rule, as the compositor's)."""

    frame_start: int
    frame_offset: int
    frame_duration: int


@dataclass(frozen=True)
class PreviewImage:
    name: str
    filepath: str
    colorspace: str
    source: str  # "SEQUENCE", "MOVIE" or "FILE"
    user: SequenceUser | None = None


@dataclass(frozen=True)
class UVSplit:
    """Layer ``layer``'s UV pass (``channels``: u, v, Z) of each pass file, written as a plain RGB EXR: bit for bit
    (``size`` None), or at the proxy ``size`` (width, height; ``preview_proxy.downsample``), uncompressed."""

    layer: str
    channels: tuple[str, str, str]
    files: tuple[tuple[str, str], ...]  # (pass file, RGB file) per frame
    size: tuple[int, int] | None = None


@dataclass(frozen=True)
class PlateProxy:
    """A sequence plate's frames written at ``size``: (plate file, proxy file without its extension) per scene
    frame from ``user.frame_start`` on, the proxy files numbered by scene frame. ``colorspace``: the plate's, which
    an 8-bit proxy keeps (its bytes are the plate's); a float one is scene-linear, read as Non-Color."""

    size: tuple[int, int]
    files: tuple[tuple[str, str], ...]
    colorspace: str
    user: SequenceUser


@dataclass(frozen=True)
class Framing:
    """The plane (lower-left corner ``origin``, ``size``) and the orthographic camera that frames it exactly: a render
    at the plate's resolution and pixel aspect maps each pixel centre to the plate pixel centre under it."""

    origin: tuple[float, float]
    size: tuple[float, float]
    camera_location: tuple[float, float, float]
    ortho_scale: float
    shift: tuple[float, float]


@dataclass
class PreviewPlan:
    nodes: list[ShaderNode]
    links: list[ShaderLink]
    images: list[PreviewImage]
    splits: list[UVSplit]
    framing: Framing
    layers: list[str]
    mirrors: dict[str, str] = field(default_factory=dict)
    """Each layer -> the float twin of its edit image that the material samples (``preview.sync`` copies the paint)."""
    export_frames: tuple[int, int] = (1, 1)
    """The exported frames (first, last): the paint shows on them; elsewhere the plate alone (``IN_EXPORT_NODE``)."""
    percent: int = X.FULL
    """The preview's proxy size, percent of the plate's sides (``preview_proxy``)."""
    size: tuple[int, int] = (1, 1)
    """The size its UV passes are written at (the plate's at 100 %)."""
    resolution: tuple[int, int] = (1, 1)
    """The plate's size (the render's)."""
    plate_proxy: PlateProxy | None = None
    """The plate's frames to write at ``size`` (a sequence plate below 100 %); None: the plate itself is shown."""


def in_export_expression(first: int, last: int) -> str:
    """The driver of ``IN_EXPORT_NODE``: 1 on scene frames ``first`` .. ``last``, else 0. A simple expression (only
    ``frame``, comparisons and arithmetic), which Blender evaluates without running Python, so it works in a file
    opened with scripts disabled."""
    return f"(frame >= {first}) * (frame <= {last})"


def outside_export(frame: int, export_frames: tuple[int, int] | None) -> str | None:
    """The panel's line when the live preview is shown at ``frame`` outside the exported frames; None inside."""
    if export_frames is None or export_frames[0] <= frame <= export_frames[1]:
        return None
    first, last = export_frames
    return f"Frame {frame} is outside the export ({first}-{last}): the preview shows the plate without paint"


def mirror_image_name(layer: str) -> str:
    """The float twin of an edit image that the preview samples: an 8-bit one converted
    (``straight_srgb_to_premultiplied``), a float one copied. Why a twin, even of a float image: Cycles' final render
    reads a file image from its file, not the unsaved paint in Blender (only generated, packed and movie images come
    from memory), so only a generated image shows every stroke in both the viewport and a render."""
    return f"{P.PREFIX}PreviewEdit_{layer}"


#: The exact IEC 61966-2-1 decode of each 8-bit value (what the engine and ``float_edit`` apply).
_SRGB_LUT = np.array([C.srgb_to_linear(k / 255.0) for k in range(256)], np.float32)


def straight_srgb_to_premultiplied(px: np.ndarray) -> np.ndarray:
    """An 8-bit edit image's ``pixels`` (RGBA k/255, sRGB-encoded, straight alpha) -> linear, premultiplied float32:
    ``float_edit``'s conversion, vectorised (the engine's reading of the PNG). Why a twin: Cycles premultiplies an
    8-bit straight-alpha image in 8-bit sRGB and interpolates the encoded values, up to 0.4 off the engine per texel
    (docs/blender-compat.md); a float premultiplied image is sampled as the engine samples."""
    rgba = px.reshape(-1, 4)
    a = np.clip(rgba[:, 3:4], 0.0, 1.0)
    codes = np.clip(np.rint(rgba[:, :3] * 255.0), 0, 255).astype(np.intp)
    return np.concatenate((_SRGB_LUT[codes] * a, a), axis=1).astype(np.float32).ravel()


def uv_image_name(layer: str) -> str:
    return f"{P.PREFIX}PreviewUV_{layer}"


def uv_file(manifest_path: str, layer: str, frame: int, percent: int = X.FULL) -> str:
    """Layer ``layer``'s UV file at ``frame``: beside the manifest in ``PREVIEW_UV_DIR`` (100 %), or in its proxy
    size's folder."""
    if percent != X.FULL:
        return X.uv_file(manifest_path, layer, frame, percent)
    return os.path.join(os.path.dirname(os.path.abspath(manifest_path)), PREVIEW_UV_DIR, layer, f"uv.{frame:05d}.exr")


def proxy_plate_image(proxy: PlateProxy, is_float: bool) -> PreviewImage:
    """The plate image of the proxy preview, once its files are written (``is_float``: as float EXRs)."""
    ext = X.PLATE_FLOAT_EXT if is_float else X.PLATE_BYTE_EXT
    colorspace = "Non-Color" if is_float else proxy.colorspace  # a float proxy holds scene-linear values
    return PreviewImage(PREVIEW_PLATE_IMAGE, proxy.files[0][1] + ext, colorspace, "SEQUENCE", proxy.user)


def size_line(percent: int, size: tuple[int, int], resolution: tuple[int, int]) -> str:
    """The panel's line saying at what size the preview shows the plate."""
    if percent == X.FULL:
        return f"Preview at full size, {resolution[0]}x{resolution[1]}"
    return f"Preview at {percent}%: {size[0]}x{size[1]} of {resolution[0]}x{resolution[1]} (the render is full size)"


def _last_digits(name: str) -> re.Match[str] | None:
    """The run of digits Blender reads as a sequence file's frame number: the last in its name."""
    runs = list(re.finditer(r"\d+", name))
    return runs[-1] if runs else None


def file_number(path: str) -> int | None:
    """The frame number in a sequence file's name (its last run of digits), as Blender reads it; None: none."""
    found = _last_digits(os.path.basename(path))
    return int(found.group()) if found else None


def sequence_file(path: str, number: int) -> str:
    """The file numbered ``number`` of the image sequence that ``path`` belongs to, as Blender numbers it: the
    digits ``file_number`` reads replaced, zero-padded to their width (``path`` itself without a number)."""
    head, name = os.path.split(path)
    last = _last_digits(name)
    if last is None:
        return path
    return os.path.join(head, f"{name[: last.start()]}{number:0{len(last.group())}d}{name[last.end() :]}")


def sequence_user(first_frame: int, first_number: int, count: int) -> SequenceUser:
    """Scene frame ``first_frame + k`` shows file number ``first_number + k`` for k < ``count``."""
    return SequenceUser(first_frame, first_number - 1, count)


def framing(resolution: tuple[int, int], pixel_aspect: tuple[float, float] = (1.0, 1.0)) -> Framing:
    """The plane's shape is the plate's displayed shape (pixel aspect included); it lies left of the canvases.
    Blender's orthographic camera (sensor fit Auto) spans ``ortho_scale`` along the render's longer displayed side,
    so ``ortho_scale`` is the plane's longer side and the camera sits over its centre (no shift)."""
    w_px, h_px = resolution
    aspect = (w_px * pixel_aspect[0]) / (h_px * pixel_aspect[1])
    width, height = PLANE_HEIGHT * aspect, PLANE_HEIGHT
    origin = placement(width, height)
    centre = (origin[0] + width / 2, origin[1] + height / 2, CAMERA_HEIGHT)
    return Framing(origin, (width, height), centre, max(width, height), (0.0, 0.0))


def placement(width: float, height: float) -> tuple[float, float]:
    """Where the plane's lower-left corner goes: left of x = 0 (the canvases run along +X from there)."""
    return (-PLANE_GAP - width, 0.0)


def pixel_centre_uv(x: int, y: int, resolution: tuple[int, int]) -> tuple[float, float]:
    """The plane UV that the render pixel (x, y) (origin bottom-left) sees through the framing camera."""
    return ((x + 0.5) / resolution[0], (y + 0.5) / resolution[1])


def plan_preview(
    tree: P.TreePlan,
    manifest: dict[str, Any],
    manifest_path: str,
    filter_type: str = P.FILTER_DEFAULT,
    frame_paint: bool = False,
    percent: int = X.FULL,
) -> PreviewPlan:
    """The preview for an imported export (``tree``: its compositor plan, which has the plate, range and size), at
    ``percent`` of the plate's size (``preview_proxy.PERCENTS``)."""
    if filter_type not in INTERPOLATION:
        raise P.PlanError(f"unknown filter {filter_type!r}")
    if percent not in X.PERCENTS:
        raise P.PlanError(f"unknown proxy size {percent}%; one of {', '.join(map(str, X.PERCENTS))}")
    size = X.proxy_size(tree.resolution, percent)
    proxied = size if percent != X.FULL else None
    count = tree.frame_end - tree.frame_start + 1
    plate = tree.plate
    # the plate follows the scene frame over all of its frames, not only the exported ones: outside the export the
    # preview shows the plate alone (``IN_EXPORT_NODE``), not a frame held from the export's end
    numbers = [int(n) for n in manifest["clip"].get("frame_numbers") or (tree.frame_start, tree.frame_end)]
    plate_first, plate_last = min(min(numbers), tree.frame_start), max(max(numbers), tree.frame_end)
    plate_proxy = None
    if plate.sequence:
        number = file_number(plate.filepath)
        number = tree.frame_start if number is None else number
        before = tree.frame_start - plate_first
        span = plate_last - plate_first + 1
        user = sequence_user(plate_first, number - before, span)
        plate_image = PreviewImage(PREVIEW_PLATE_IMAGE, plate.filepath, plate.colorspace, "SEQUENCE", user)
        if proxied is not None:
            sources = (sequence_file(plate.filepath, number - before + k) for k in range(span))
            stems = (X.plate_stem(manifest_path, plate_first + k, percent) for k in range(span))
            files = tuple(zip(sources, stems, strict=True))
            plate_proxy = PlateProxy(size, files, plate.colorspace, sequence_user(plate_first, plate_first, span))
    else:
        # a movie's frame numbered ``frame_start`` (TreePlan: its first) is its frame 1
        span = plate_last - plate.frame_start + 1
        user = SequenceUser(plate.frame_start, 0, span)
        plate_image = PreviewImage(PREVIEW_PLATE_IMAGE, plate.filepath, plate.colorspace, "MOVIE", user)
    images = [plate_image]
    splits = []
    passes = manifest["passes"]
    pass_dir = C.resolve_manifest_path(manifest_path, passes["dir"])
    frames = range(tree.frame_start, tree.frame_end + 1)
    for layer in manifest["layers"]:
        name = layer["name"]
        channels = tuple(C.channel_name(layer["uv_pass"], c) for c in layer.get("uv_channels", C.UV_CHANNELS))
        files = tuple(
            (os.path.join(pass_dir, passes["pattern"].format(frame=f)), uv_file(manifest_path, name, f, percent))
            for f in frames
        )
        splits.append(UVSplit(name, (channels[0], channels[1], channels[2]), files, proxied))
        user = sequence_user(tree.frame_start, tree.frame_start, count)
        images.append(PreviewImage(uv_image_name(name), files[0][1], "Non-Color", "SEQUENCE", user))
    sampled = {name: mirror_image_name(name) for name in tree.layers}
    exported = (tree.frame_start, tree.frame_end)
    nodes, links = shader_graph(sampled, filter_type, frame_paint, exported)
    mirrors = dict(sampled)
    fit = framing(tree.resolution, tree.pixel_aspect)
    layers = list(tree.layers)
    return PreviewPlan(
        nodes, links, images, splits, fit, layers, mirrors, exported, percent, size, tree.resolution, plate_proxy
    )


def shader_graph(
    layers: dict[str, str],
    filter_type: str,
    frame_paint: bool = False,
    export_frames: tuple[int, int] | None = None,
) -> tuple[list[ShaderNode], list[ShaderLink]]:
    """The material's nodes and links: the render equation per pixel, then the frame paint over it. ``layers``: each
    layer's image to sample (its float edit image, or the float twin of its 8-bit one). ``export_frames``: the
    layers' sums are gated by ``IN_EXPORT_NODE`` (the plate alone outside them)."""
    nodes = [
        ShaderNode("UVMap", TEX_COORD, (-1600.0, 300.0)),
        ShaderNode("Plate", TEX_IMAGE, (-1300.0, 300.0), {"image": PREVIEW_PLATE_IMAGE, "interpolation": "Closest"}),
    ]
    links = [ShaderLink("UVMap", "UV", "Plate", "Vector")]
    rgb: tuple[str, str | int] | None = None
    alpha: tuple[str, str | int] | None = None
    for i, (layer, image) in enumerate(layers.items()):
        y = -200.0 - 350.0 * i
        c, a = _layer_shader(nodes, links, layer, image, filter_type, y)
        if rgb is None or alpha is None:
            rgb, alpha = (c, "Vector"), (a, "Value")
            continue
        add_c, add_a = f"SumRGB_{i}", f"SumA_{i}"
        nodes += [
            ShaderNode(add_c, VECTOR_MATH, (100.0, y), {"operation": "ADD"}),
            ShaderNode(add_a, MATH, (100.0, y - 200.0), {"operation": "ADD"}),
        ]
        links += [
            ShaderLink(rgb[0], rgb[1], add_c, 0),
            ShaderLink(c, "Vector", add_c, 1),
            ShaderLink(alpha[0], alpha[1], add_a, 0),
            ShaderLink(a, "Value", add_a, 1),
        ]
        rgb, alpha = (add_c, "Vector"), (add_a, "Value")
    if rgb is None or alpha is None:
        raise P.PlanError("the export has no layers; export again")
    if export_frames is not None:
        expression = in_export_expression(*export_frames)
        nodes += [
            ShaderNode(IN_EXPORT_NODE, VALUE, (-100.0, 500.0), {"value": 1.0, "driver": expression}),
            ShaderNode("RGBInExport", VECTOR_MATH, (150.0, 400.0), {"operation": "SCALE"}),
            ShaderNode("AInExport", MATH, (150.0, 250.0), {"operation": "MULTIPLY"}),
        ]
        links += [
            ShaderLink(rgb[0], rgb[1], "RGBInExport", 0),
            ShaderLink(IN_EXPORT_NODE, "Value", "RGBInExport", "Scale"),
            ShaderLink(alpha[0], alpha[1], "AInExport", 0),
            ShaderLink(IN_EXPORT_NODE, "Value", "AInExport", 1),
        ]
        rgb, alpha = ("RGBInExport", "Vector"), ("AInExport", "Value")
    _composite_shader(nodes, links, rgb, alpha, frame_paint)
    return nodes, links


def _layer_shader(
    nodes: list[ShaderNode], links: list[ShaderLink], layer: str, image: str, filter_type: str, y: float
) -> tuple[str, str]:
    """One layer's row: its UV pass split into (u, v) and Z, its image sampled at (u, v), and the node of its
    ``rgb_i = E_i.rgb * Z_i`` (output "Vector") and of its ``A_i = E_i.alpha * Z_i`` (output "Value")."""
    uv, split, at, edit = f"UV_{layer}", f"SplitUV_{layer}", f"EditUV_{layer}", f"Edit_{layer}"
    a, c = f"A_{layer}", f"RGB_{layer}"
    nodes += [
        ShaderNode(uv, TEX_IMAGE, (-1300.0, y), {"image": uv_image_name(layer), "interpolation": "Closest"}),
        ShaderNode(split, SEPARATE_XYZ, (-1000.0, y)),
        ShaderNode(at, COMBINE_XYZ, (-800.0, y)),
        ShaderNode(
            edit,
            TEX_IMAGE,
            (-600.0, y),
            {"image": image, "interpolation": INTERPOLATION[filter_type]},
        ),
        ShaderNode(a, MATH, (-300.0, y - 100.0), {"operation": "MULTIPLY"}),
        ShaderNode(c, VECTOR_MATH, (-100.0, y), {"operation": "SCALE"}),
    ]
    links += [
        ShaderLink("UVMap", "UV", uv, "Vector"),
        ShaderLink(uv, "Color", split, "Vector"),
        ShaderLink(split, "X", at, "X"),
        ShaderLink(split, "Y", at, "Y"),
        ShaderLink(at, "Vector", edit, "Vector"),
        ShaderLink(edit, "Alpha", a, 0),
        ShaderLink(split, "Z", a, 1),
        ShaderLink(edit, "Color", c, 0),  # premultiplied: a float PREMUL image's Color is rgb * a (measured)
        ShaderLink(split, "Z", c, "Scale"),
    ]
    return c, a


def _composite_shader(
    nodes: list[ShaderNode],
    links: list[ShaderLink],
    rgb: tuple[str, str | int],
    alpha: tuple[str, str | int],
    frame_paint: bool,
) -> None:
    """``out = plate * (1 - sum A_i) + sum rgb_i`` (``rgb``, ``alpha``: the sums' outputs) emitted, with the frame
    paint laid over it by its alpha where ``frame_paint``."""
    nodes += [
        ShaderNode("PlateShows", MATH, (300.0, 100.0), {"operation": "SUBTRACT", "defaults": {0: 1.0}}),
        ShaderNode("PlateKept", VECTOR_MATH, (500.0, 300.0), {"operation": "SCALE"}),
        ShaderNode("Composite", VECTOR_MATH, (700.0, 200.0), {"operation": "ADD"}),
        ShaderNode("Emission", EMISSION, (1100.0, 200.0), {"defaults": {"Strength": 1.0}}),
        ShaderNode("Output", OUTPUT, (1300.0, 200.0)),
    ]
    links += [
        ShaderLink(alpha[0], alpha[1], "PlateShows", 1),
        ShaderLink("Plate", "Color", "PlateKept", 0),
        ShaderLink("PlateShows", "Value", "PlateKept", "Scale"),
        ShaderLink("PlateKept", "Vector", "Composite", 0),
        ShaderLink(rgb[0], rgb[1], "Composite", 1),
        ShaderLink("Emission", "Emission", "Output", "Surface"),
    ]
    shown: tuple[str, str | int] = ("Composite", "Vector")
    if frame_paint:
        params = {"image": P.FRAME_PAINT_IMAGE, "interpolation": "Closest"}
        nodes += [
            ShaderNode(FRAME_PAINT_NODE, TEX_IMAGE, (700.0, -150.0), params),
            ShaderNode("FramePaintOver", MIX, (900.0, 200.0)),
        ]
        links += [
            ShaderLink(FRAME_PAINT_NODE, "Alpha", "FramePaintOver", "Factor"),
            ShaderLink("Composite", "Vector", "FramePaintOver", "A"),
            ShaderLink(FRAME_PAINT_NODE, "Color", "FramePaintOver", "B"),
        ]
        shown = ("FramePaintOver", "Result")
    links.append(ShaderLink(shown[0], shown[1], "Emission", "Color"))
