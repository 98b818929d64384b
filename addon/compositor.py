"""Turn a ``TreePlan`` (``core.tree_plan``) into images, a movie clip and compositor nodes; render the result.

Only datablocks and nodes whose names start with ``tree_plan.PREFIX`` are created, reused or removed,
so rebuilding is idempotent and the artist's own nodes and images are never touched.
"""

from __future__ import annotations

import os
from typing import Any

import bpy

from . import compat
from .core import frames as F
from .core import relink
from .core import tree_plan as P


def blend_path(path: str) -> str:
    """``path`` as the scene stores it: relative to the saved .blend (``//``, as Blender stores the artist's own
    clip) where it can be, so a shot folder copied with its .blend keeps working; absolute in an unsaved .blend or
    on another drive (``core.relink.relative_path``)."""
    return relink.relative_path(path, bpy.data.filepath)


def _ours(collection: Any, spec: P.ImageSpec) -> tuple[Any, bool]:
    """The datablock ``spec`` names in ``collection`` (images, movie clips), loaded from its file unless it
    already shows that file (then it is reused); (datablock, reused). Loaded by its path relative to the .blend
    where it has one (``blend_path``)."""
    path = os.path.abspath(spec.filepath)
    block = collection.get(spec.name)
    if block is not None and os.path.abspath(bpy.path.abspath(block.filepath)) == path:
        return block, True
    if block is not None:
        collection.remove(block)
    block = collection.load(blend_path(path), check_existing=False)
    block.name = spec.name
    return block, False


def _load_image(spec: P.ImageSpec) -> Any:
    img, reused = _ours(bpy.data.images, spec)
    if reused:
        img.reload()
    img.source = "SEQUENCE" if spec.sequence else "FILE"
    img.colorspace_settings.name = spec.colorspace
    if not spec.sequence:
        # a PNG edit layer is straight alpha (Blender premultiplies it on load); a float EXR is premultiplied
        # (by the file's kind: ``is_float`` is False until the pixels are first loaded)
        img.alpha_mode = "PREMUL" if spec.colorspace == "Non-Color" else "STRAIGHT"
    return img


def _load_plate(spec: P.ImageSpec) -> Any:
    clip, _ = _ours(bpy.data.movieclips, spec)
    clip.colorspace_settings.name = spec.colorspace
    # scene frame F shows plate frame F: a sequence starts at its first file's number, a movie at its first frame's
    # number (0 unless the fit numbered it with --start-frame)
    clip.frame_start = spec.frame_start
    clip.frame_offset = 0
    return clip


def remove_ours(tree: Any) -> int:
    ours = [n for n in tree.nodes if n.name.startswith(P.PREFIX)]
    for node in ours:
        tree.nodes.remove(node)
    return len(ours)


def build(scene: Any, plan: P.TreePlan, set_range: bool = False) -> dict[str, Any]:
    """Create (or recreate) the plan's nodes in the scene's compositor; returns them by name. ``set_range``: the
    scene's range becomes the imported frames even where the artist's lies within them (``configure_scene``)."""
    images = {spec.name: _load_image(spec) for spec in plan.images}
    clip = _load_plate(plan.plate)
    tree = compat.scene_tree(scene)
    remove_ours(tree)
    nodes: dict[str, Any] = {}
    kinds: dict[str, str] = {}
    mattes_root = os.path.join(render_dir(scene), P.MATTES_DIR)
    for spec in plan.nodes:
        node = compat.new_node(tree, spec.kind)
        node.name = spec.name
        node.label = spec.name.removeprefix(P.PREFIX).replace("_", " ")
        node.location = spec.location  # before the parent: a node keeps its place in the editor when framed
        if spec.kind == P.PLATE:
            node.clip = clip
        elif spec.kind == P.IMAGE:
            node.image = images[spec.params["image"]]
            if spec.params.get("sequence"):
                node.frame_duration = plan.frame_end - plan.frame_start + 1
                node.frame_start = plan.frame_start
                node.frame_offset = plan.frame_start - 1  # file number = scene frame
                node.use_auto_refresh = True
                node.layer = spec.params["layer"]
        compat.setup_node(node, spec.kind, spec.params)
        if spec.kind == P.FILE_OUTPUT:
            compat.set_file_output_dir(node, os.path.join(mattes_root, spec.params["matte"]))
            node.mute = not writes_mattes(scene)
        nodes[spec.name] = node
        kinds[spec.name] = spec.kind
    for spec in plan.nodes:
        if spec.parent:
            nodes[spec.name].parent = nodes[spec.parent]
    for link in plan.links:
        src = compat.output_socket(nodes[link.from_node], kinds[link.from_node], link.from_socket)
        dst = compat.input_socket(nodes[link.to_node], kinds[link.to_node], link.to_socket)
        tree.links.new(src, dst)
    out = next(n for name, n in nodes.items() if kinds[name] == P.OUTPUT)
    compat.make_output_active(tree, out)
    configure_scene(scene, plan, set_range)
    return nodes


def render_dir(scene: Any) -> str:
    """The panel's render folder (as the artist typed it: ``//`` relative to the .blend)."""
    props = getattr(scene, "neural_atlas", None)
    return str(props.render_dir) if props is not None and props.render_dir else "//neural_atlas_render/"


def writes_mattes(scene: Any) -> bool:
    props = getattr(scene, "neural_atlas", None)
    return bool(props.write_mattes) if props is not None else True


def point_mattes(scene: Any, out_dir: str | None = None) -> list[str]:
    """Aim the tree's matte File Output nodes at ``out_dir/mattes/<Matte>/`` (None: where they are) and mute
    them unless the panel's Write Mattes is on; returns the folders they write to when they write.

    File Output nodes write on every render of the scene (an F12 animation render too), so they stay aimed at
    the last Render Edited Clip's folder: the mattes always sit beside the frames they belong to."""
    tree = compat.scene_tree(scene, create=False)
    write = writes_mattes(scene)
    folders = []
    for node in tree.nodes if tree is not None else ():
        matte = P.matte_of_file_node(node.name)
        if matte is None:
            continue
        if out_dir is not None:
            compat.set_file_output_dir(node, _blend_relative(P.matte_dir(os.path.abspath(out_dir), matte)))
        node.mute = not write
        if write:
            folders.append(compat.file_output_dir(node))
    return folders


def _blend_relative(path: str) -> str:
    """``path`` relative to the saved .blend (``//...``), so the File Output follows a shot folder that moves with
    its .blend; as it is when the .blend is unsaved or on another drive."""
    if not bpy.data.filepath:
        return path
    try:
        return str(bpy.path.relpath(path))
    except ValueError:
        return path


def add_output(tree: Any, socket: Any) -> Any:
    """A compositor output node (the version's kind) fed by ``socket``; returns the node."""
    out = compat.new_node(tree, P.OUTPUT)
    compat.setup_node(out, P.OUTPUT, {})
    tree.links.new(socket, compat.input_socket(out, P.OUTPUT, "image"))
    return out


def configure_scene(scene: Any, plan: P.TreePlan, set_range: bool = False) -> None:
    """The scene as the plate is: its range the exported frames' numbers (handles included: every imported frame)
    unless the artist's lies within them (``frames.scene_range``; ``set_range``: always), its resolution, pixel
    aspect ratio and exact frame rate (a plate that states no rate keeps the scene's)."""
    first, last = F.scene_range(
        (scene.frame_start, scene.frame_end), (plan.frame_start, plan.frame_end), force=set_range
    )
    scene.frame_start, scene.frame_end = first, last  # a start past the old end moves the end there first: no clamp
    r = scene.render
    r.resolution_x, r.resolution_y = plan.resolution
    r.resolution_percentage = 100
    r.pixel_aspect_x, r.pixel_aspect_y = plan.pixel_aspect
    if plan.fps is not None:
        r.fps, r.fps_base = plan.fps


def set_filter(scene: Any, filter_type: str) -> int:
    tree = compat.scene_tree(scene, create=False)
    count = 0
    for node in tree.nodes if tree is not None else ():
        if node.name.startswith(P.PREFIX + "MapUV_"):
            compat.set_map_uv_filter(node, filter_type)
            count += 1
    return count


def render(scene: Any, out_dir: str, file_format: str = "exr", exr_colorspace: str = "Linear Rec.709") -> list[str]:
    """Render the compositor for the scene's frame range into ``out_dir/edit.#####.<ext>`` (or a movie).

    The view transform is Standard and dithering off for the render, so a PNG is the plain sRGB encoding
    of the linear result (the artist's settings are restored afterwards). An EXR is written in
    ``exr_colorspace`` (``TreePlan.output_colorspace``: the plate's space when scene-linear, as ``engine render``).
    The tree's mattes are written beside it, ``out_dir/mattes/<Matte>/matte.#####.exr`` (``point_mattes``).
    """
    os.makedirs(out_dir, exist_ok=True)
    point_mattes(scene, out_dir)
    r = scene.render
    s = r.image_settings
    saved = {
        "filepath": r.filepath,
        "dither": r.dither_intensity,
        "view": scene.view_settings.view_transform,
        "look": scene.view_settings.look,
        "extension": r.use_file_extension,
    }
    image_settings = compat.image_settings_state(s)
    try:
        scene.view_settings.view_transform = "Standard"
        scene.view_settings.look = "None"
        r.dither_intensity = 0.0
        r.compositor_device = "CPU"
        r.compositor_precision = "FULL"
        compat.set_render_format(scene, file_format, exr_colorspace)
        r.use_file_extension = True
        r.filepath = os.path.join(os.path.abspath(out_dir), "edit." if file_format != "movie" else "edit_")
        if file_format != "movie":
            r.filepath += "#####"
        result = bpy.ops.render.render(animation=True, scene=scene.name)
        if "FINISHED" not in result:
            raise RuntimeError(f"render returned {result}")
    finally:
        compat.restore_image_settings(s, image_settings)
        r.filepath = saved["filepath"]
        r.use_file_extension = saved["extension"]
        r.dither_intensity = saved["dither"]
        scene.view_settings.view_transform = saved["view"]
        scene.view_settings.look = saved["look"]
    return sorted(os.path.join(out_dir, f) for f in os.listdir(out_dir) if f.startswith("edit"))
