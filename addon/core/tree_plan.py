"""The compositor tree as plain data, planned from a manifest. No bpy here.

For layers i with Map UV outputs P_i (premultiplied: rgb_i = edit_i(uv_i).rgb * a_i * Z_i, alpha
A_i = edit_i(uv_i).a * Z_i) the tree computes the engine's render equation

    out = plate * (1 - sum_i A_i) + sum_i rgb_i

not a chain of Alpha Overs (which would give plate(1-A0)(1-A1) + P0(1-A1) + P1 where layers overlap).
The colour sum uses Mix/Add, whose alpha is its first input's, so the alphas are summed separately
(Separate Color -> Math/Add) and put back with Set Alpha; one premultiplied Alpha Over puts the sum over
the plate. ``addon/compositor.py`` turns a plan into nodes; ``addon/compat.py`` maps the abstract socket keys used
here to each Blender version's sockets.

The plan also says where each node sits: every node belongs to a labelled frame (Plate, Passes, one per layer, Blend,
Mattes), so an artist opening the tree sees what each group does. The Mattes frame offers each layer's matte (its
alpha pass) and the paint's coverage (the alpha sum above) as named Reroutes a compositor can pick up, and writes
them as float EXR sequences beside the render (``matte_path``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

from ...engine import contract as C  # type: ignore[import-not-found]
from . import frames as F
from .colorspaces import blender_colorspace, edit_colorspace, engine_colorspace, output_colorspace

#: Every node and image the add-on creates starts with this; rebuilding removes only these.
PREFIX = "NA_"

# node kinds (addon/compat.py knows each version's node type and sockets)
PLATE = "plate"  # MovieClip node; output "image"
IMAGE = "image"  # Image node; outputs "image" or one per pass of a multilayer EXR
MAP_UV = "map_uv"  # inputs "image", "uv"; output "image"
SEPARATE = "separate"  # input "image"; output "alpha"
ADD_COLOR = "add_color"  # inputs "a", "b"; output "result" (rgb sum, alpha of "a")
ADD_VALUE = "add_value"  # inputs "a", "b"; output "value"
SET_ALPHA = "set_alpha"  # inputs "image", "alpha"; output "image" (alpha replaced)
ALPHA_OVER = "alpha_over"  # inputs "bg", "fg" (premultiplied); output "image"
OUTPUT = "output"  # input "image"
VIEWER = "viewer"  # input "image": what the Compositor's backdrop and the Image Editor's Viewer Node show
FRAME = "frame"  # a labelled, coloured box that groups nodes (params "label", "color"); no sockets
REROUTE = "reroute"  # input "in"; output "out": a named point in the tree to pick a matte up from
FILE_OUTPUT = "file_output"  # input "image": written each rendered frame to <mattes dir>/<params "matte">/MATTE_FILE

# the Blender 4.x bilinear filter's node group: Map UV, Math, Separate/Combine XYZ, Switch and group nodes
GROUP = "group"  # a node group's instance (params "group"); sockets by the group's interface names
GROUP_INPUT = "group_input"  # outputs: the group's inputs, by name
GROUP_OUTPUT = "group_output"  # inputs: the group's outputs, by name
MATH = "math"  # inputs "a", "b", "c"; output "value"; params "operation", "values" (an input's constant)
SEPARATE_XYZ = "separate_xyz"  # input "vector"; outputs "x", "y", "z"
COMBINE_XYZ = "combine_xyz"  # inputs "x", "y", "z"; output "vector"
SWITCH = "switch"  # inputs "off", "on"; output "image"; params "on" (bool)

#: The filters: the edit layers sampled as ``engine render --filter NAME`` samples them, by the same names, in the
#: compositor (Render Edited Clip) and in the live preview alike, on every Blender version.
FILTER_BILINEAR = "bilinear"
FILTER_NEAREST = "nearest"
FILTERS = (FILTER_BILINEAR, FILTER_NEAREST)
#: ``engine render``'s default.
FILTER_DEFAULT = FILTER_BILINEAR
#: Blender 4.x's Map UV has no bilinear filter (its smooth one is EWA, up to 0.2 off at hard paint edges): there a
#: layer's bilinear sample is this node group, four nearest taps weighted as ``engine render`` weighs them.
BILINEAR_GROUP = f"{PREFIX}Bilinear"

#: The Viewer node fed by the composite (the render's output): the Compositor's backdrop shows it.
VIEWER_NODE = f"{PREFIX}Viewer"
PLATE_CLIP = f"{PREFIX}Plate"
PASSES_IMAGE = f"{PREFIX}Passes"
#: The live preview: a plate-sized plane in the 3D viewport whose material is the composite
#: (``addon/preview_plane.py``).
PREVIEW_OBJECT = f"{PREFIX}Preview"
#: Paint laid on one plate frame (plate-sized RGBA, transparent where unpainted), shown over the preview and landed on
#: the atlases by ``engine project-frame``.
FRAME_PAINT_IMAGE = f"{PREFIX}FramePaint"


#: The fix of a plate that is not where the manifest says.
PLATE_FIX = "put the plate back, or choose where it is now with Relink Run Folder"


#: The render folder's subfolder of the mattes: ``<render dir>/mattes/<Matte>/matte.#####.exr``.
MATTES_DIR = "mattes"
#: A matte's file name in its folder, ``#####`` the plate's frame number, always five digits (the frames beside it are
#: padded as ``engine render`` pads them, ``render_job.output_template``; ``engine render`` writes no mattes, so none
#: is named two ways).
MATTE_FILE = "matte.#####"
MATTE_EXT = ".exr"
#: The matte of the paint: where the edit layers cover the plate, ``sum_i A_i`` (the alpha the Blend frame puts over
#: the plate). Not a layer name: layers are Background, Foreground, Foreground1, ... (the engine's
#: ``terms.export_names.layer_name``).
PAINT_MATTE = "Paint"
#: The matte of every foreground layer together, ``sum_i a_i`` over the foregrounds' alpha passes, offered when there
#: are two or more: the whole object when Find Parts split it into the parts that move apart (one holdout for "the
#: dog", not a sum the artist builds). Not a layer name either.
FOREGROUNDS_MATTE = "Foregrounds"


class PlanError(ValueError):
    """The manifest cannot be turned into a tree (message says why and what to do)."""


@dataclass(frozen=True)
class NodeSpec:
    name: str
    kind: str
    location: tuple[float, float]  # in the editor's space, not relative to the frame the node sits in
    params: dict[str, Any] = field(default_factory=dict)
    parent: str = ""  # the FRAME node it sits in ("": none, as a frame itself)


@dataclass(frozen=True)
class LinkSpec:
    from_node: str
    from_socket: str
    to_node: str
    to_socket: str


@dataclass(frozen=True)
class ImageSpec:
    """An image datablock: a file, or a sequence whose scene frame F shows file number F."""

    name: str
    filepath: str
    colorspace: str  # Blender's name: "sRGB", "Non-Color", the plate's ("ACEScg", "Linear Rec.709", ...)
    sequence: bool = False
    frame_start: int = 1  # scene frame of the first file
    frame_duration: int = 1


@dataclass
class GroupPlan:
    """A node group: its interface (name, socket type) and its nodes and links (no frames)."""

    name: str
    inputs: list[tuple[str, str]]
    outputs: list[tuple[str, str]]
    nodes: list[NodeSpec]
    links: list[LinkSpec]


@dataclass
class TreePlan:
    nodes: list[NodeSpec]
    links: list[LinkSpec]
    images: list[ImageSpec]
    plate: ImageSpec
    frame_start: int
    frame_end: int
    resolution: tuple[int, int]
    layers: list[str]
    output_colorspace: str = "Linear Rec.709"  # the EXR render's colour space (``output_colorspace``)
    fps: tuple[int, float] | None = None
    """The scene's ``(render.fps, render.fps_base)``: the plate's exact rate (``frames.scene_fps``); None: none."""
    pixel_aspect: tuple[float, float] = (1.0, 1.0)
    """The scene's ``(pixel_aspect_x, pixel_aspect_y)``: the plate's pixel aspect ratio."""
    mattes: list[str] = field(default_factory=list)
    """The mattes the tree offers and writes: each layer's (its alpha pass), then ``PAINT_MATTE``, then
    ``FOREGROUNDS_MATTE`` where there are two foreground layers or more."""
    groups: list[GroupPlan] = field(default_factory=list)
    """The node groups the nodes use (built before them): ``bilinear_group`` where Map UV has no bilinear filter."""


def edit_image_name(layer: str) -> str:
    return f"{PREFIX}Edit_{layer}"


def atlas_image_name(layer: str) -> str:
    return f"{PREFIX}Atlas_{layer}"


def matte_node_name(matte: str) -> str:
    """The Reroute a compositor picks the matte up from (a layer's name, or ``PAINT_MATTE``)."""
    return f"{PREFIX}Matte_{matte}"


def matte_file_node_name(matte: str) -> str:
    """The File Output node that writes the matte on each rendered frame."""
    return f"{PREFIX}MatteFile_{matte}"


def matte_of_file_node(name: str) -> str | None:
    """The matte a File Output node named ``matte_file_node_name(matte)`` writes; None for any other node."""
    prefix = matte_file_node_name("")
    return name.removeprefix(prefix) if name.startswith(prefix) and name != prefix else None


def matte_dir(render_dir: str, matte: str) -> str:
    """The folder of one matte's EXR sequence in a render folder."""
    return os.path.join(render_dir, MATTES_DIR, matte)


def matte_path(render_dir: str, matte: str, frame: int) -> str:
    """The matte of plate frame ``frame`` in a render folder: ``<render_dir>/mattes/<matte>/matte.00012.exr``."""
    digits = MATTE_FILE.count("#")
    name = MATTE_FILE.replace("#" * digits, f"{frame:0{digits}d}") + MATTE_EXT
    return os.path.join(matte_dir(render_dir, matte), name)


def filter_switch_name(layer: str) -> str:
    """The Switch between a layer's nearest Map UV (off) and its ``BILINEAR_GROUP`` (on), where there is one."""
    return f"{PREFIX}Filter_{layer}"


def frame_node_name(group: str) -> str:
    return f"{PREFIX}Frame_{group}"


#: The frames' groups and colours (display RGB, dim: Blender draws a frame's colour behind its nodes).
FRAME_PLATE, FRAME_PASSES, FRAME_BLEND, FRAME_MATTES = "Plate", "Passes", "Blend", "Mattes"
FRAME_COLORS: dict[str, tuple[float, float, float]] = {
    FRAME_PLATE: (0.25, 0.25, 0.32),
    FRAME_PASSES: (0.22, 0.30, 0.22),
    "Layer": (0.32, 0.26, 0.18),
    FRAME_BLEND: (0.20, 0.27, 0.33),
    FRAME_MATTES: (0.30, 0.20, 0.28),
}


def layer_frame_group(layer: str) -> str:
    return f"Layer_{layer}"


def layer_frame_label(layer: str) -> str:
    return f"Layer {layer}: edit + Map UV"


def frame_spec(group: str, label: str, color_key: str) -> NodeSpec:
    """A FRAME node: its location is unused (a frame fits itself around its nodes)."""
    return NodeSpec(frame_node_name(group), FRAME, (0.0, 0.0), {"label": label, "color": FRAME_COLORS[color_key]})


def contiguous_frames(frames: list[int]) -> tuple[int, int]:
    first, last = min(frames), max(frames)
    if sorted(frames) != list(range(first, last + 1)):
        raise PlanError(f"exported frames {first}..{last} have gaps; export a contiguous range (--frames A:B)")
    return first, last


def plan_tree(
    manifest: dict[str, Any],
    manifest_path: str,
    filter_type: str = FILTER_DEFAULT,
    edits: dict[str, str] | None = None,
    colorspaces: frozenset[str] | None = None,
    known_plate: str | None = None,
    bilinear_taps: bool = False,
) -> TreePlan:
    """The tree for a validated manifest; ``edits`` maps a layer name to another edit image file. ``colorspaces``:
    the colour spaces this Blender has (``compat.colorspace_names``): a plate in another one is a PlanError.
    ``known_plate``: where the scene's plate clip of this import is (``plate_path``: a run folder relinked without its
    plate still finds it there). ``bilinear_taps``: Map UV has no bilinear filter (``compat.BILINEAR_TAPS``): each
    layer also gets ``BILINEAR_GROUP`` and a Switch (``NA_Filter_<Layer>``, on for bilinear) between the two."""
    if filter_type not in FILTERS:
        raise PlanError(f"unknown filter {filter_type!r}")
    edits = edits or {}
    passes = manifest["passes"]
    clip = manifest["clip"]
    first, last = contiguous_frames(passes["frames"])
    count = last - first + 1
    pass_dir = C.resolve_manifest_path(manifest_path, passes["dir"])
    pass_first = os.path.join(pass_dir, passes["pattern"].format(frame=first))
    plate = _plate_image(manifest_path, clip, first, count, colorspaces, known_plate)
    images = [ImageSpec(PASSES_IMAGE, pass_first, "Non-Color", True, first, count)]
    images += _layer_images(manifest_path, manifest["layers"], edits)
    layers = [layer["name"] for layer in manifest["layers"]]

    nodes: list[NodeSpec] = [
        frame_spec(FRAME_PLATE, "Plate", FRAME_PLATE),
        frame_spec(FRAME_PASSES, "Passes", FRAME_PASSES),
    ]
    links: list[LinkSpec] = []
    f_plate, f_passes = frame_node_name(FRAME_PLATE), frame_node_name(FRAME_PASSES)
    n_plate, n_passes = f"{PREFIX}Plate", f"{PREFIX}Passes"
    nodes.append(NodeSpec(n_plate, PLATE, (-900.0, 300.0), {"clip": PLATE_CLIP}, f_plate))
    passes_params = {"image": PASSES_IMAGE, "layer": passes["exr_layer"], "sequence": True}
    nodes.append(NodeSpec(n_passes, IMAGE, (-900.0, 0.0), passes_params, f_passes))
    groups = [bilinear_group()] if bilinear_taps else []
    map_outputs = [
        _layer_nodes(nodes, links, layer, i, n_passes, filter_type, bilinear_taps)
        for i, layer in enumerate(manifest["layers"])
    ]
    alpha_node, alpha_socket = _blend_nodes(nodes, links, map_outputs, layers, n_plate)

    sources = [(layer["name"], n_passes, layer["alpha_pass"]) for layer in manifest["layers"]]
    sources.append((PAINT_MATTE, alpha_node, alpha_socket))
    nodes.append(frame_spec(FRAME_MATTES, "Mattes", FRAME_MATTES))
    foregrounds = [layer["alpha_pass"] for layer in manifest["layers"] if layer["role"] == C.ROLE_FOREGROUND]
    if len(foregrounds) >= 2:
        sources.append((FOREGROUNDS_MATTE, *_summed(nodes, links, n_passes, foregrounds)))
    _matte_nodes(nodes, links, sources)
    res = passes["resolution"]
    size = (int(res[0]), int(res[1]))
    fps, aspect = F.scene_fps(C.clip_rate(clip)), F.scene_pixel_aspect(clip.get("pixel_aspect", 1.0))
    mattes = [matte for matte, _, _ in sources]
    return TreePlan(
        nodes, links, images, plate, first, last, size, layers, output_colorspace(clip), fps, aspect, mattes, groups
    )


def _plate_image(
    manifest_path: str,
    clip: dict[str, Any],
    first: int,
    count: int,
    colorspaces: frozenset[str] | None,
    known_plate: str | None,
) -> ImageSpec:
    """The plate clip's image (``PLATE_CLIP``) for the exported frames ``first`` .. ``first + count - 1``."""
    if clip["kind"] == "sequence":
        numbers = list(clip["frame_numbers"])
        if first not in numbers:
            raise PlanError(f"plate has no frame {first}; export frames that exist in the clip")
        at_first = C.resolve_plate_path(manifest_path, clip, numbers.index(first))  # moved alone: as at export
        plate_file = plate_path(manifest_path, at_first, "plate frame", known_plate)
        return ImageSpec(PLATE_CLIP, plate_file, plate_colorspace(clip, colorspaces), True, first, count)
    # scene frame F shows the movie's frame numbered F: its first frame is numbered start_frame (0 by default)
    movie = plate_path(manifest_path, C.resolve_plate_path(manifest_path, clip), "plate movie", known_plate)
    start = int(clip.get("start_frame", 0))
    return ImageSpec(PLATE_CLIP, movie, plate_colorspace(clip, colorspaces), False, start, count)


def _layer_images(manifest_path: str, manifest_layers: list[dict[str, Any]], edits: dict[str, str]) -> list[ImageSpec]:
    """Each layer's edit image (``edits``' file where it names one) and atlas image, in the layers' order."""
    layers = [layer["name"] for layer in manifest_layers]
    unknown = set(edits) - set(layers)
    if unknown:
        raise PlanError(f"edit for unknown layer(s) {sorted(unknown)}; layers are {layers}")
    images = []
    for layer in manifest_layers:
        name = layer["name"]
        # the float edit layer <Layer>.exr wins over the export's PNG when both exist (the same rule as the engine)
        edit = edits.get(name) or edit_layer_path(manifest_path, layer)
        images.append(ImageSpec(edit_image_name(name), edit, edit_colorspace(edit)))
        atlas = C.resolve_manifest_path(manifest_path, layer["atlas_png"])
        images.append(ImageSpec(atlas_image_name(name), atlas, "sRGB"))
    return images


def _layer_nodes(
    nodes: list[NodeSpec],
    links: list[LinkSpec],
    layer: dict[str, Any],
    i: int,
    n_passes: str,
    filter_type: str,
    bilinear_taps: bool,
) -> str:
    """Layer ``i``'s frame: its edit image sampled at its UV pass (Map UV; with ``bilinear_taps`` also
    ``BILINEAR_GROUP`` and the Switch between them). Returns the node whose "image" is the sampled layer."""
    name = layer["name"]
    y = -420.0 - 250.0 * i  # below the passes node, whose height grows with the layers
    f_layer = frame_node_name(layer_frame_group(name))
    nodes.append(frame_spec(layer_frame_group(name), layer_frame_label(name), "Layer"))
    n_edit, n_map = f"{PREFIX}Edit_{name}", f"{PREFIX}MapUV_{name}"
    nodes.append(NodeSpec(n_edit, IMAGE, (-900.0, y), {"image": edit_image_name(name)}, f_layer))
    nodes.append(NodeSpec(n_map, MAP_UV, (-650.0, y), {"filter": filter_type}, f_layer))
    links.append(LinkSpec(n_edit, "image", n_map, "image"))
    links.append(LinkSpec(n_passes, layer["uv_pass"], n_map, "uv"))
    if not bilinear_taps:
        return n_map
    atlas_size = [int(v) for v in layer["atlas_size"]]
    n_bilinear, n_switch = f"{PREFIX}Bilinear_{name}", filter_switch_name(name)
    params = {"group": BILINEAR_GROUP, "image": edit_image_name(name), "size": atlas_size}
    nodes.append(NodeSpec(n_bilinear, GROUP, (-650.0, y - 120.0), params, f_layer))
    nodes.append(NodeSpec(n_switch, SWITCH, (-450.0, y), {"on": filter_type == FILTER_BILINEAR}, f_layer))
    links.append(LinkSpec(n_edit, "image", n_bilinear, "Image"))
    links.append(LinkSpec(n_passes, layer["uv_pass"], n_bilinear, "UV"))
    links.append(LinkSpec(n_map, "image", n_switch, "off"))
    links.append(LinkSpec(n_bilinear, "Image", n_switch, "on"))
    return n_switch


def _blend_nodes(
    nodes: list[NodeSpec], links: list[LinkSpec], map_outputs: list[str], layer_names: list[str], n_plate: str
) -> tuple[str, str]:
    """The Blend frame: the sampled layers summed (colour Mix/Add, alpha Math/Add, Set Alpha), put over the plate
    (the render's output and the Viewer). Returns the output of the alpha sum: the paint's matte."""
    f_blend = frame_node_name(FRAME_BLEND)
    nodes.append(frame_spec(FRAME_BLEND, "Blend", FRAME_BLEND))
    # the paint's matte: the alpha of the sum (one layer: its Map UV's alpha)
    alpha_node, alpha_socket = _separate(nodes, links, map_outputs[0], f_blend, layer_names[0])
    if len(map_outputs) == 1:
        fg_node, fg_socket = map_outputs[0], "image"
    else:
        color_node, color_socket = map_outputs[0], "image"
        for i, n_map in enumerate(map_outputs[1:], start=1):
            y = -250.0 * i
            n_add = f"{PREFIX}AddColor_{i}"
            nodes.append(NodeSpec(n_add, ADD_COLOR, (-200.0, y), parent=f_blend))
            links.append(LinkSpec(color_node, color_socket, n_add, "a"))
            links.append(LinkSpec(n_map, "image", n_add, "b"))
            color_node, color_socket = n_add, "result"
            sep_node, sep_socket = _separate(nodes, links, n_map, f_blend, layer_names[i])
            n_addv = f"{PREFIX}AddAlpha_{i}"
            nodes.append(NodeSpec(n_addv, ADD_VALUE, (-200.0, y - 120.0), parent=f_blend))
            links.append(LinkSpec(alpha_node, alpha_socket, n_addv, "a"))
            links.append(LinkSpec(sep_node, sep_socket, n_addv, "b"))
            alpha_node, alpha_socket = n_addv, "value"
        n_set = f"{PREFIX}SetAlpha"
        nodes.append(NodeSpec(n_set, SET_ALPHA, (0.0, 0.0), parent=f_blend))
        links.append(LinkSpec(color_node, color_socket, n_set, "image"))
        links.append(LinkSpec(alpha_node, alpha_socket, n_set, "alpha"))
        fg_node, fg_socket = n_set, "image"

    n_over, n_out, n_view = f"{PREFIX}Over", f"{PREFIX}Output", VIEWER_NODE
    nodes.append(NodeSpec(n_over, ALPHA_OVER, (200.0, 200.0), parent=f_blend))
    nodes.append(NodeSpec(n_out, OUTPUT, (400.0, 200.0), parent=f_blend))
    nodes.append(NodeSpec(n_view, VIEWER, (400.0, 60.0), parent=f_blend))
    links.append(LinkSpec(n_plate, "image", n_over, "bg"))
    links.append(LinkSpec(fg_node, fg_socket, n_over, "fg"))
    links.append(LinkSpec(n_over, "image", n_out, "image"))
    links.append(LinkSpec(n_over, "image", n_view, "image"))  # the backdrop shows the composite
    return alpha_node, alpha_socket


def _separate(nodes: list[NodeSpec], links: list[LinkSpec], src_node: str, parent: str, layer: str) -> tuple[str, str]:
    """A Separate Color node taking ``layer``'s sampled edit apart (``NA_Alpha_<Layer>``): its alpha."""
    src = nodes[[n.name for n in nodes].index(src_node)]
    n_sep = f"{PREFIX}Alpha_{layer}"
    nodes.append(NodeSpec(n_sep, SEPARATE, (-400.0, src.location[1] - 60.0), parent=parent))
    links.append(LinkSpec(src_node, "image", n_sep, "image"))
    return n_sep, "alpha"


def _summed(nodes: list[NodeSpec], links: list[LinkSpec], n_passes: str, sockets: list[str]) -> tuple[str, str]:
    """The sum of the passes image's ``sockets`` (Math Add nodes in the Mattes frame): (node, socket) of the sum."""
    f_mattes = frame_node_name(FRAME_MATTES)
    node, socket = n_passes, sockets[0]
    for i, other in enumerate(sockets[1:], start=1):
        n_add = f"{PREFIX}AddForeground_{i}"
        nodes.append(NodeSpec(n_add, ADD_VALUE, (550.0, -400.0 - 120.0 * i), parent=f_mattes))
        links.append(LinkSpec(node, socket, n_add, "a"))
        links.append(LinkSpec(n_passes, other, n_add, "b"))
        node, socket = n_add, "value"
    return node, socket


def _matte_nodes(nodes: list[NodeSpec], links: list[LinkSpec], sources: list[tuple[str, str, str]]) -> None:
    """In the Mattes frame (made before: ``plan_tree``): each matte (name, source node, socket) as a named Reroute and
    the File Output writing it."""
    f_mattes = frame_node_name(FRAME_MATTES)
    for k, (matte, src_node, src_socket) in enumerate(sources):
        y = 200.0 - 130.0 * k
        n_matte, n_file = matte_node_name(matte), matte_file_node_name(matte)
        nodes.append(NodeSpec(n_matte, REROUTE, (700.0, y), parent=f_mattes))
        nodes.append(NodeSpec(n_file, FILE_OUTPUT, (800.0, y + 40.0), {"matte": matte}, f_mattes))
        links.append(LinkSpec(src_node, src_socket, n_matte, "in"))
        links.append(LinkSpec(n_matte, "out", n_file, "image"))


def edit_layer_path(manifest_path: str, layer: dict[str, Any]) -> str:
    """The layer's edit layer file in use (its float twin ``<Layer>.exr`` when that exists, else the PNG), where
    Save Edits writes: checked by the contract's write-path rule (relative, inside the run folder once symlinks are
    resolved), so a manifest cannot make the add-on write anywhere else (``ManifestError``, one line)."""
    png = C.resolve_manifest_write_path(manifest_path, layer["edit_layer"])
    if C.edit_layer_file(png) != png:
        return float_edit_path(manifest_path, layer)
    return png


def float_edit_path(manifest_path: str, layer: dict[str, Any]) -> str:
    """Where the layer's float edit layer is (or would be) written: the PNG's twin, checked like it."""
    return C.resolve_manifest_write_path(manifest_path, C.float_edit_layer(layer["edit_layer"]))


def plate_path(manifest_path: str, path: str, what: str, known_plate: str | None = None) -> str:
    """A plate file the manifest names (relative to it first, like every manifest path), checked to be a file: one
    line naming it and the fix, instead of Blender's silent placeholder.

    ``known_plate``: a file of the same plate where the scene's plate clip shows it (``None``: none). The scene has one
    plate, the same for every operator (import, Live Preview, Paint on Frame, Render): where it has a plate clip, the
    file of the manifest's name in the clip's folder (a movie: the clip's file) is the plate, whatever else the
    manifest names (its relative paths after the run folder moved alone, or the paths as at export, maybe another shot
    folder's copy of the plate); where that is missing, the error says so."""
    full = C.resolve_manifest_path(manifest_path, path)
    if known_plate:
        known = os.path.normpath(os.path.abspath(known_plate))
        full = known if what == "plate movie" else os.path.join(os.path.dirname(known), os.path.basename(full))
    if not os.path.isfile(full):
        problem = f"{what} does not exist" if not os.path.exists(full) else f"{what} is not a file"
        raise PlanError(f"{full}: {problem} — {PLATE_FIX}")
    return full


def plate_colorspace(clip: dict[str, Any], available: frozenset[str] | None = None) -> str:
    """Blender's colour space for the manifest's plate; a space Blender lacks is a PlanError that says what to do."""
    name = engine_colorspace(clip)
    found = blender_colorspace(name, available)
    if found is None:
        raise PlanError(
            f"this Blender's colour management has no {name!r} (the plate's colour space), so the compositor cannot "
            f"decode the plate — import it in Blender 5.0 or later (it has ACEScc and ACEScct), or render with "
            f"`engine render --format plate`"
        )
    return found


#: A Math operand: a node's output (node, socket) or a constant.
Operand = tuple[str, str] | float


@dataclass
class _GroupNodes:
    """A node group's nodes and links as they are planned: each node placed in its column ``x``, below the last."""

    nodes: list[NodeSpec]
    links: list[LinkSpec]
    rows: dict[float, int] = field(default_factory=dict)

    def place(self, x: float) -> tuple[float, float]:
        self.rows[x] = self.rows.get(x, 0) + 1
        return x, -160.0 * self.rows[x]

    def math(self, name: str, operation: str, x: float, *args: Operand) -> tuple[str, str]:
        values = {}
        for key, arg in zip("abc", args, strict=False):
            if isinstance(arg, tuple):
                self.links.append(LinkSpec(arg[0], arg[1], name, key))
            else:
                values[key] = float(arg)
        self.nodes.append(NodeSpec(name, MATH, self.place(x), {"operation": operation, "values": values}))
        return name, "value"


def bilinear_group() -> GroupPlan:
    """``BILINEAR_GROUP``: the bilinear sample of an atlas (inputs Image, UV, and the atlas's Width and Height in
    texels; output Image, premultiplied and times the UV's Z as Map UV's) from nearest Map UV taps, as
    ``engine render --filter bilinear`` computes it. Per axis (u over the width W, v over the height H):

        x = u W - 0.5,  x0 = floor(x),  f = x - x0
        taps at the texel centres (x0 + 0.5) / W and (x0 + 1.5) / W, weighed 1 - f and f; a tap outside the atlas
        (x0 < 0, x0 + 1 > W - 1) weighs 0, and so does the whole sample where u lies outside 0..1.

    Each of the four taps is a nearest Map UV whose UV's Z is its weight times the coverage Z (Map UV multiplies the
    texel by Z); the four are summed as the layers are (colour Mix/Add, alpha Math/Add, Set Alpha)."""
    g = _GroupNodes(
        [NodeSpec("Input", GROUP_INPUT, (-1800.0, 0.0)), NodeSpec("UV", SEPARATE_XYZ, (-1600.0, 0.0))],
        [LinkSpec("Input", "UV", "UV", "vector")],
    )
    u_taps, u_weights, u_inside = _axis(g, "u", ("UV", "x"), ("Input", "Width"))
    v_taps, v_weights, v_inside = _axis(g, "v", ("UV", "y"), ("Input", "Height"))
    cover = g.math("cover_u", "MULTIPLY", -600.0, ("UV", "z"), u_inside)
    cover = g.math("cover", "MULTIPLY", -400.0, cover, v_inside)
    taps: list[str] = []
    for i, (u_tap, u_weight) in enumerate(zip(u_taps, u_weights, strict=True)):
        u_cover = g.math(f"weight{i}_", "MULTIPLY", -400.0, u_weight, cover)
        for j, (v_tap, v_weight) in enumerate(zip(v_taps, v_weights, strict=True)):
            weight = g.math(f"weight{i}{j}", "MULTIPLY", -200.0, u_cover, v_weight)
            n_uv, n_tap = f"uv{i}{j}", f"tap{i}{j}"
            g.nodes.append(NodeSpec(n_uv, COMBINE_XYZ, g.place(0.0)))
            g.nodes.append(NodeSpec(n_tap, MAP_UV, g.place(200.0), {"filter": FILTER_NEAREST}))
            g.links += [LinkSpec(*u_tap, n_uv, "x"), LinkSpec(*v_tap, n_uv, "y"), LinkSpec(*weight, n_uv, "z")]
            g.links += [LinkSpec("Input", "Image", n_tap, "image"), LinkSpec(n_uv, "vector", n_tap, "uv")]
            taps.append(n_tap)
    _sum_taps(g, taps)
    inputs = [
        ("Image", "NodeSocketColor"),
        ("UV", "NodeSocketVector"),
        ("Width", "NodeSocketFloat"),
        ("Height", "NodeSocketFloat"),
    ]
    return GroupPlan(BILINEAR_GROUP, inputs, [("Image", "NodeSocketColor")], g.nodes, g.links)


def _axis(
    g: _GroupNodes, a: str, coord: Operand, size: Operand
) -> tuple[list[tuple[str, str]], list[tuple[str, str]], Operand]:
    """The axis's two tap positions, their weights and whether the coordinate lies inside 0..1 (1 or 0)."""
    x = g.math(f"{a}_texel", "MULTIPLY_ADD", -1400.0, coord, size, -0.5)
    x0 = g.math(f"{a}_floor", "FLOOR", -1200.0, x)
    f = g.math(f"{a}_fraction", "SUBTRACT", -1000.0, x, x0)
    rest = g.math(f"{a}_1-fraction", "SUBTRACT", -800.0, 1.0, f)
    first_in = g.math(f"{a}_first_inside", "GREATER_THAN", -1000.0, x0, -0.5)
    last = g.math(f"{a}_last", "SUBTRACT", -1200.0, size, 1.5)
    second_in = g.math(f"{a}_second_inside", "LESS_THAN", -1000.0, x0, last)
    weights = [g.math(f"{a}_weight0", "MULTIPLY", -600.0, rest, first_in)]
    weights.append(g.math(f"{a}_weight1", "MULTIPLY", -600.0, f, second_in))
    taps = []
    for k, offset in enumerate((0.5, 1.5)):
        centre = g.math(f"{a}_centre{k}", "ADD", -1000.0, x0, offset)
        taps.append(g.math(f"{a}_tap{k}", "DIVIDE", -800.0, centre, size))
    below = g.math(f"{a}_below", "LESS_THAN", -1400.0, coord, 0.0)
    above = g.math(f"{a}_above", "GREATER_THAN", -1400.0, coord, 1.0)
    outside = g.math(f"{a}_outside", "ADD", -1200.0, below, above)
    return taps, weights, g.math(f"{a}_inside", "SUBTRACT", -1000.0, 1.0, outside)


def _sum_taps(g: _GroupNodes, taps: list[str]) -> None:
    """The taps summed as the layers are (colour Mix/Add, alpha Math/Add, Set Alpha) into the group's output."""
    color: tuple[str, str] = (taps[0], "image")
    alpha: tuple[str, str] = _tap_alpha(g.nodes, g.links, taps[0], g.place(400.0))
    for k, n_tap in enumerate(taps[1:], start=1):
        n_add = f"add{k}"
        g.nodes.append(NodeSpec(n_add, ADD_COLOR, g.place(600.0)))
        g.links += [LinkSpec(*color, n_add, "a"), LinkSpec(n_tap, "image", n_add, "b")]
        color = (n_add, "result")
        alpha = g.math(f"add_alpha{k}", "ADD", 600.0, alpha, _tap_alpha(g.nodes, g.links, n_tap, g.place(400.0)))
    g.nodes.append(NodeSpec("sum", SET_ALPHA, (800.0, 0.0)))
    g.nodes.append(NodeSpec("Output", GROUP_OUTPUT, (1000.0, 0.0)))
    g.links += [
        LinkSpec(*color, "sum", "image"),
        LinkSpec(*alpha, "sum", "alpha"),
        LinkSpec("sum", "image", "Output", "Image"),
    ]


def _tap_alpha(
    nodes: list[NodeSpec], links: list[LinkSpec], n_tap: str, location: tuple[float, float]
) -> tuple[str, str]:
    n_sep = f"{n_tap}_alpha"
    nodes.append(NodeSpec(n_sep, SEPARATE, location))
    links.append(LinkSpec(n_tap, "image", n_sep, "image"))
    return n_sep, "alpha"
