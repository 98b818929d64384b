"""Every difference between Blender 4.2-4.5 and 5.0 the add-on meets, and the only module that branches on
one (a version or a feature check): the compositor tree and its output, Map UV filtering, Alpha Over, Set
Alpha and Math sockets, the mattes' File Output nodes, the render's file/video settings, float EXR saving, the
clip's annotation datablock, animation F-curves and material nodes. The facts behind each branch:
docs/blender-compat.md.
"""

from __future__ import annotations

import contextlib
from typing import Any

import bpy

from .core import tree_plan as P

V5 = bpy.app.version >= (5, 0, 0)

#: The options of a path setting that may hold a path relative to the .blend (``//``): 4.5 and later warn on such a
#: value unless the property says it supports one; earlier versions do not know the option (and do not warn).
PATH_OPTIONS: set[str] = {"PATH_SUPPORTS_BLEND_RELATIVE"} if bpy.app.version >= (4, 5, 0) else {"ANIMATABLE"}

_NODE_TYPES = {
    P.PLATE: "CompositorNodeMovieClip",
    P.IMAGE: "CompositorNodeImage",
    P.MAP_UV: "CompositorNodeMapUV",
    P.SEPARATE: "CompositorNodeSeparateColor",
    # 5.0 removed the compositor's MixRGB/Math for the shared nodes, which 4.2 does not allow in a compositor
    P.ADD_COLOR: "ShaderNodeMix" if V5 else "CompositorNodeMixRGB",
    P.ADD_VALUE: "ShaderNodeMath" if V5 else "CompositorNodeMath",
    P.SET_ALPHA: "CompositorNodeSetAlpha",
    P.ALPHA_OVER: "CompositorNodeAlphaOver",
    P.OUTPUT: "NodeGroupOutput" if V5 else "CompositorNodeComposite",
    P.VIEWER: "CompositorNodeViewer",
    P.FRAME: "NodeFrame",
    P.REROUTE: "NodeReroute",
    P.FILE_OUTPUT: "CompositorNodeOutputFile",
    # the 4.x bilinear group's (``tree_plan.bilinear_group``; 5.0 samples bilinearly in Map UV itself)
    P.GROUP: "CompositorNodeGroup",
    P.GROUP_INPUT: "NodeGroupInput",
    P.GROUP_OUTPUT: "NodeGroupOutput",
    P.MATH: "ShaderNodeMath" if V5 else "CompositorNodeMath",
    P.SEPARATE_XYZ: "CompositorNodeSeparateXYZ",
    P.COMBINE_XYZ: "CompositorNodeCombineXYZ",
    P.SWITCH: "CompositorNodeSwitch",
}

#: the name of the 5.0 compositing node group the add-on creates when the scene has none
TREE_NAME = f"{P.PREFIX}Compositing"
#: 4.x's Map UV has no bilinear filter (its smooth one, EWA, is up to 0.2 off bilinear at hard texel edges): the tree
#: samples bilinearly with ``tree_plan.BILINEAR_GROUP``'s nearest taps there, and its Map UV nodes stay Nearest.
BILINEAR_TAPS = not V5


def node_type(kind: str) -> str:
    return _NODE_TYPES[kind]


def scene_tree(scene: Any, create: bool = True) -> Any:
    """The scene's compositor tree (created empty when missing); None if missing and not ``create``."""
    if V5:
        tree = scene.compositing_node_group
        if tree is None and create:
            tree = bpy.data.node_groups.new(TREE_NAME, "CompositorNodeTree")
            scene.compositing_node_group = tree
        if tree is not None and create:
            _ensure_output_interface(tree)
        return tree
    if scene.node_tree is None or not scene.use_nodes:
        if not create:
            return scene.node_tree
        fresh = scene.node_tree is None
        scene.use_nodes = True
        if fresh:
            # Blender's default tree: its Render Layers node would make every render a slow EEVEE render of the
            # (empty) scene; nothing in it is the artist's yet
            scene.node_tree.nodes.clear()
    return scene.node_tree


def _ensure_output_interface(tree: Any) -> None:
    # without this socket, links to the Group Output silently connect nothing: the render is black
    for item in tree.interface.items_tree:
        if getattr(item, "in_out", None) == "OUTPUT" and item.socket_type == "NodeSocketColor":
            return
    tree.interface.new_socket(name="Image", in_out="OUTPUT", socket_type="NodeSocketColor")


def setup_node(node: Any, kind: str, params: dict[str, Any]) -> None:
    """Per-kind settings that differ between versions."""
    if kind == P.MAP_UV:
        set_map_uv_filter(node, params.get("filter", P.FILTER_DEFAULT))
    elif kind == P.ADD_COLOR:
        node.blend_type = "ADD"
        if V5:
            node.data_type = "RGBA"
            node.clamp_result = False
            node.clamp_factor = True
            _enabled(node.inputs, "Factor").default_value = 1.0
        else:
            node.use_alpha = False  # the colours add; the alpha is the first input's (replaced later)
            node.use_clamp = False
            node.inputs[0].default_value = 1.0
    elif kind == P.ADD_VALUE:
        node.operation = "ADD"
        node.use_clamp = False
    elif kind == P.SET_ALPHA:
        if V5:
            node.inputs["Type"].default_value = "Replace Alpha"
        else:
            node.mode = "REPLACE_ALPHA"
    elif kind == P.ALPHA_OVER:
        # premultiplied foreground: out = bg * (1 - fg.a) + fg
        straight = node.inputs.get("Straight Alpha")
        if straight is not None:
            straight.default_value = False
        if V5:
            node.inputs["Factor"].default_value = 1.0
            node.inputs["Type"].default_value = "Over"
        else:
            node.use_premultiply = False
            node.premul = 0.0
            node.inputs[0].default_value = 1.0
    elif kind == P.OUTPUT and hasattr(node, "use_alpha"):  # 4.3-4.5; 4.2 has an Alpha input instead
        node.use_alpha = True
    elif kind == P.FRAME:
        node.label = params["label"]
        node.use_custom_color = True
        node.color = params["color"]
        node.label_size = 16
    elif kind == P.FILE_OUTPUT:
        setup_matte_output(node)
    elif kind == P.MATH:
        node.operation = params["operation"]
        node.use_clamp = False
        for key, value in params.get("values", {}).items():
            _math_input(node, key).default_value = value
    elif kind == P.SWITCH:
        set_switch(node, params["on"])
    elif kind == P.GROUP:
        node.node_tree = bpy.data.node_groups[params["group"]]


def set_switch(node: Any, on: bool) -> None:
    """A Switch node's choice: 4.5 has a Switch input socket; 4.2 only the ``check`` property."""
    socket = node.inputs.get("Switch")
    if socket is not None:
        socket.default_value = on
    if hasattr(node, "check"):
        node.check = on


def _math_input(node: Any, key: str) -> Any:
    return node.inputs["abc".index(key)]


def setup_matte_output(node: Any) -> None:
    """A File Output node with one float input written as a single-channel (``V``) full-float EXR named
    ``tree_plan.MATTE_FILE`` in the node's folder (``set_file_output_dir``), values as they are (Non-Color).

    4.x: ``base_path`` + one file slot whose path is the file name (``#`` the frame number). 5.0 replaced those
    with ``directory`` + ``file_name`` + ``file_output_items`` (an item's name follows the file name; a ``/`` in it
    becomes ``_``, so each matte has its own node and folder), its format starts as multilayer EXR, and an input that
    is a single value rather than an image writes no file (measured on 5.0.1)."""
    fmt = node.format
    if V5:
        fmt.media_type = "IMAGE"  # first: it decides which file formats exist
        node.file_output_items.clear()
        node.file_output_items.new("FLOAT", P.MATTE_FILE)
        node.file_name = ""
    else:
        node.file_slots.clear()
        node.file_slots.new(P.MATTE_FILE)
    fmt.file_format = "OPEN_EXR"
    fmt.color_depth = "32"
    fmt.exr_codec = "ZIP"
    fmt.color_mode = "BW"
    fmt.color_management = "OVERRIDE"
    fmt.linear_colorspace_settings.name = "Non-Color"  # a matte is data: no conversion from the scene's space


def file_output_dir(node: Any) -> str:
    return node.directory if V5 else node.base_path


def set_file_output_dir(node: Any, directory: str) -> None:
    """The folder a File Output node writes into (``//`` relative to the .blend allowed)."""
    if V5:
        node.directory = directory
    else:
        node.base_path = directory


def set_map_uv_filter(node: Any, filter_type: str) -> None:
    """The Map UV node's own filter for ``filter_type`` (``tree_plan.FILTERS``): 5.0's Nearest or Bilinear; always
    Nearest on 4.x, where bilinear is ``tree_plan.BILINEAR_GROUP`` chosen by the layer's Switch."""
    if V5:
        node.inputs["Interpolation"].default_value = "Nearest" if filter_type == P.FILTER_NEAREST else "Bilinear"
        node.inputs["Extension X"].default_value = "Clip"
        node.inputs["Extension Y"].default_value = "Clip"
    else:
        node.filter_type = "NEAREST"


def _enabled(sockets: Any, name: str) -> Any:
    return next(s for s in sockets if s.name == name and s.enabled)


def input_socket(node: Any, kind: str, key: str) -> Any:
    if kind == P.MAP_UV:
        return node.inputs["Image" if key == "image" else "UV"]
    if kind == P.SEPARATE:
        return node.inputs[0]
    if kind == P.ADD_COLOR:
        if V5:
            return _enabled(node.inputs, key.upper())
        return node.inputs[1 if key == "a" else 2]  # Fac, Image, Image
    if kind == P.ADD_VALUE:
        return node.inputs[0 if key == "a" else 1]
    if kind == P.SET_ALPHA:
        return node.inputs["Image" if key == "image" else "Alpha"]
    if kind == P.ALPHA_OVER:
        if V5:
            return node.inputs["Background" if key == "bg" else "Foreground"]
        return node.inputs[1 if key == "bg" else 2]  # both are called "Image" on 4.x
    if kind in (P.OUTPUT, P.VIEWER, P.REROUTE, P.FILE_OUTPUT):
        return node.inputs[0]
    if kind in (P.GROUP, P.GROUP_OUTPUT):
        return node.inputs[key]
    if kind == P.MATH:
        return _math_input(node, key)
    if kind == P.SEPARATE_XYZ:
        return node.inputs[0]
    if kind == P.COMBINE_XYZ:
        return node.inputs[key.upper()]
    if kind == P.SWITCH:
        return node.inputs[key.title()]
    raise KeyError(f"{kind} has no input {key!r}")


def output_socket(node: Any, kind: str, key: str) -> Any:
    if kind == P.IMAGE and key != "image":
        return node.outputs[key]  # a pass of a multilayer EXR
    if kind in (P.PLATE, P.IMAGE, P.MAP_UV, P.SET_ALPHA, P.ALPHA_OVER):
        return node.outputs["Image"]
    if kind == P.SEPARATE:
        return node.outputs["Alpha"]
    if kind == P.ADD_COLOR:
        return _enabled(node.outputs, "Result") if V5 else node.outputs[0]
    if kind in (P.ADD_VALUE, P.REROUTE, P.MATH, P.COMBINE_XYZ, P.SWITCH):
        return node.outputs[0]
    if kind in (P.GROUP, P.GROUP_INPUT):
        return node.outputs[key]
    if kind == P.SEPARATE_XYZ:
        return node.outputs[key.upper()]
    raise KeyError(f"{kind} has no output {key!r}")


def make_output_active(tree: Any, node: Any) -> None:
    """Several outputs may exist (the artist's and ours); the render uses the active one."""
    if not hasattr(node, "is_active_output"):
        tree.nodes.active = node  # 4.x: the active Composite node is the one that renders
        return
    for other in tree.nodes:
        if other.bl_idname == node.bl_idname and other != node:
            other.is_active_output = False
    node.is_active_output = True


#: The file formats whose image settings have a linear colour space (``linear_colorspace_settings``).
LINEAR_FORMATS = frozenset({"OPEN_EXR", "OPEN_EXR_MULTILAYER", "HDR"})


def image_settings_state(settings: Any) -> dict[str, Any]:
    """What ``set_render_format`` changes of the render's image settings, to restore after a render. The linear colour
    space only of a format that has one: reading it for another (a PNG, Blender's default) prints Blender's warning
    "current value '-1' matches no enum"."""
    return {
        "media_type": settings.media_type if V5 else None,
        "file_format": settings.file_format,
        "color_depth": settings.color_depth,
        "color_mode": settings.color_mode,
        "color_management": settings.color_management,
        "linear_colorspace": (
            settings.linear_colorspace_settings.name if settings.file_format in LINEAR_FORMATS else None
        ),
    }


def restore_image_settings(settings: Any, state: dict[str, Any]) -> None:
    if V5 and settings.media_type != state["media_type"]:
        settings.media_type = state["media_type"]  # first: it decides which file formats exist
    settings.file_format = state["file_format"]
    settings.color_management = state["color_management"]
    if state["linear_colorspace"] is not None:  # a format without a linear space (PNG) keeps its own
        with contextlib.suppress(TypeError, ValueError):
            settings.linear_colorspace_settings.name = state["linear_colorspace"]
    try:
        settings.color_depth = state["color_depth"]
        settings.color_mode = state["color_mode"]
    except TypeError:
        pass  # the format restored does not offer them (a movie's colour depth)


def set_render_format(scene: Any, file_format: str, exr_colorspace: str = "Linear Rec.709") -> None:
    """'exr' (float32 RGBA, linear, in ``exr_colorspace``), 'png' (8-bit RGBA) or 'movie' (H.264 MP4)."""
    s = scene.render.image_settings
    if file_format == "movie":
        if V5:
            s.media_type = "VIDEO"
        s.file_format = "FFMPEG"
        scene.render.ffmpeg.format = "MPEG4"
        scene.render.ffmpeg.codec = "H264"
        s.color_mode = "RGB"
        return
    if V5:
        s.media_type = "IMAGE"
    if file_format == "exr":
        s.file_format = "OPEN_EXR"
        s.color_depth = "32"
        s.exr_codec = "ZIP"
        # the EXR in the plate's scene-linear space (ACEScg ...): the output's own colour management, both versions
        s.color_management = "OVERRIDE"
        s.linear_colorspace_settings.name = exr_colorspace
    else:
        s.file_format = "PNG"
        s.color_depth = "8"
    s.color_mode = "RGBA"


def colorspace_names() -> frozenset[str]:
    """The colour spaces of this Blender's OCIO config (4.5 has no ACEScc/ACEScct; 5.0 has both)."""
    prop = bpy.types.ColorManagedInputColorspaceSettings.bl_rna.properties["name"]
    return frozenset(item.identifier for item in prop.enum_items)


def new_node(tree: Any, kind: str) -> Any:
    return tree.nodes.new(node_type(kind))


def mask_node_setup(node: Any) -> None:
    """Mask node for exact rasterization: no feather, the scene's size."""
    if V5:
        node.inputs["Feather"].default_value = False
    else:
        node.use_feather = False
        node.size_source = "SCENE"


def action_fcurves(id_data: Any) -> list[Any]:
    """The F-curves animating ``id_data`` (5.0 removed ``Action.fcurves`` in favour of slots/channelbags)."""
    ad = id_data.animation_data
    if ad is None or ad.action is None:
        return []
    action = ad.action
    slot = getattr(ad, "action_slot", None)
    if slot is not None:
        from bpy_extras import anim_utils

        bag = anim_utils.action_get_channelbag_for_slot(action, slot)
        return list(bag.fcurves) if bag is not None else []
    return list(action.fcurves)


def ensure_material_nodes(mat: Any) -> None:
    """5.0 materials always use nodes (``use_nodes`` is deprecated there)."""
    if not V5:
        mat.use_nodes = True


def set_float_exr(image: Any) -> None:
    """Save ``image`` as a full-float OpenEXR (the half-float switch exists in some versions only)."""
    image.file_format = "OPEN_EXR"
    if hasattr(image, "use_half_precision"):
        image.use_half_precision = False


# --- the Movie Clip Editor's annotations: ``clip.grease_pencil`` (legacy GreasePencil) up to 4.5, ``clip.annotation``
# (Annotation) in 5.0; layers, frames, strokes and points read the same on both.
def _annotation_attribute(clip: Any) -> str:
    return "annotation" if hasattr(clip, "annotation") else "grease_pencil"


def clip_annotation(clip: Any) -> Any | None:
    """The clip's annotation datablock, or None."""
    return getattr(clip, _annotation_attribute(clip), None)


def new_clip_annotation(clip: Any, name: str) -> Any:
    """A new annotation datablock, given to ``clip``."""
    data = bpy.data.annotations if hasattr(bpy.data, "annotations") else bpy.data.grease_pencils
    annotation = data.new(name)
    setattr(clip, _annotation_attribute(clip), annotation)
    return annotation
