"""Turn a ``TreePlan`` (``core.tree_plan``) into images, a movie clip and compositor nodes; render the result.

Only datablocks and nodes whose names start with ``tree_plan.PREFIX`` are created, reused or removed,
so rebuilding is idempotent and the artist's own nodes and images are never touched.
"""

from __future__ import annotations

import os
from typing import Any

import bpy

from ..engine import contract as C
from . import compat
from .core import frames as F
from .core import relink
from .core import render_job as RJ
from .core import tree_plan as P


def blend_path(path: str) -> str:
    """``path`` as the scene stores it: relative to the saved .blend (``//``, as Blender stores the artist's own
    clip) where it can be, so a shot folder copied with its .blend keeps working; absolute in an unsaved .blend or
    on another drive (``core.relink.relative_path``)."""
    return relink.relative_path(path, bpy.data.filepath)


def imported_manifest(scene: Any) -> str:
    """The manifest the scene imported, absolute and normalised ('' when none; it is stored relative to the .blend
    where it can)."""
    props = getattr(scene, "neural_atlas", None)
    return os.path.normpath(bpy.path.abspath(props.manifest)) if props is not None and props.manifest else ""


def known_plate(scene: Any, manifest_path: str) -> str | None:
    """The file of the scene's plate clip when ``manifest_path`` belongs to the run the scene imported from (its
    manifest, or a later export of the same run folder): where that run's plate is, even after the run folder was
    relinked without it (``tree_plan.plate_path``). None otherwise: another run's plate is where its manifest says."""
    imported = imported_manifest(scene)
    clip = bpy.data.movieclips.get(P.PLATE_CLIP)
    if not imported or clip is None or not clip.filepath:
        return None
    if C.manifest_run_root(imported) != C.manifest_run_root(os.path.abspath(manifest_path)):
        return None
    return os.path.normpath(bpy.path.abspath(clip.filepath))


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


def build_group(group: P.GroupPlan) -> Any:
    """The node group ``group`` plans (``NA_...``: emptied and filled again when it exists)."""
    tree = bpy.data.node_groups.get(group.name)
    if tree is None or tree.bl_idname != "CompositorNodeTree":
        tree = bpy.data.node_groups.new(group.name, "CompositorNodeTree")
    tree.nodes.clear()
    tree.interface.clear()
    for name, socket_type in group.inputs:
        tree.interface.new_socket(name=name, in_out="INPUT", socket_type=socket_type)
    for name, socket_type in group.outputs:
        tree.interface.new_socket(name=name, in_out="OUTPUT", socket_type=socket_type)
    nodes: dict[str, Any] = {}
    kinds: dict[str, str] = {}
    for spec in group.nodes:
        node = compat.new_node(tree, spec.kind)
        node.name = node.label = spec.name
        node.location = spec.location
        compat.setup_node(node, spec.kind, spec.params)
        nodes[spec.name], kinds[spec.name] = node, spec.kind
    _link(tree, group.links, nodes, kinds)
    return tree


def _link(tree: Any, links: list[P.LinkSpec], nodes: dict[str, Any], kinds: dict[str, str]) -> None:
    for link in links:
        src = compat.output_socket(nodes[link.from_node], kinds[link.from_node], link.from_socket)
        dst = compat.input_socket(nodes[link.to_node], kinds[link.to_node], link.to_socket)
        tree.links.new(src, dst)


def _atlas_size(spec: P.NodeSpec, images: dict[str, Any]) -> tuple[int, int]:
    """The texels a bilinear group samples: its edit image's (the atlas size the manifest says until it loads)."""
    img = images.get(spec.params["image"])
    size = tuple(img.size) if img is not None else (0, 0)
    return (int(size[0]), int(size[1])) if size[0] and size[1] else tuple(spec.params["size"])


def build(scene: Any, plan: P.TreePlan, set_range: bool = False) -> dict[str, Any]:
    """Create (or recreate) the plan's nodes in the scene's compositor; returns them by name. ``set_range``: the
    scene's range becomes the imported frames even where the artist's lies within them (``configure_scene``)."""
    images = {spec.name: _load_image(spec) for spec in plan.images}
    clip = _load_plate(plan.plate)
    tree = compat.scene_tree(scene)
    remove_ours(tree)
    for group in plan.groups:
        build_group(group)
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
        if spec.kind == P.GROUP:
            node.inputs["Width"].default_value, node.inputs["Height"].default_value = _atlas_size(spec, images)
        if spec.kind == P.FILE_OUTPUT:
            compat.set_file_output_dir(node, os.path.join(mattes_root, spec.params["matte"]))
            node.mute = not writes_mattes(scene)
        nodes[spec.name] = node
        kinds[spec.name] = spec.kind
    for spec in plan.nodes:
        if spec.parent:
            nodes[spec.name].parent = nodes[spec.parent]
    _link(tree, plan.links, nodes, kinds)
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


def output_template(scene: Any) -> str:
    """The frames' name for the export the scene imported: ``render_job.output_template`` of its manifest's clip
    record (``edit.####`` for a plate ``plate.1001.png`` ..), ``edit.#####`` for a scene that imported none."""
    imported = imported_manifest(scene)
    return RJ.output_template(C.load_manifest(imported)["clip"] if imported else {})


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
    unless the artist's lies within them (``frames.scene_range``; ``set_range``: always), the current frame one of
    them (``frames.frame_inside``), its resolution, pixel aspect ratio and exact frame rate (a plate that states no
    rate keeps the scene's)."""
    first, last = F.scene_range(
        (scene.frame_start, scene.frame_end), (plan.frame_start, plan.frame_end), force=set_range
    )
    scene.frame_start, scene.frame_end = first, last  # a start past the old end moves the end there first: no clamp
    current = F.frame_inside(scene.frame_current, plan.frame_start, plan.frame_end)
    if current != scene.frame_current:
        scene.frame_set(current)  # the first imported frame, not Blender's frame 1 the export lacks
    r = scene.render
    r.resolution_x, r.resolution_y = plan.resolution
    r.resolution_percentage = 100
    r.pixel_aspect_x, r.pixel_aspect_y = plan.pixel_aspect
    if plan.fps is not None:
        r.fps, r.fps_base = plan.fps


def set_filter(scene: Any, filter_type: str) -> int:
    """The tree's layers sampled with ``filter_type`` (``tree_plan.FILTERS``): each Map UV's own filter, and on
    4.x each layer's Switch between its nearest Map UV and its bilinear group; returns the layers set."""
    tree = compat.scene_tree(scene, create=False)
    count = 0
    for node in tree.nodes if tree is not None else ():
        if node.name.startswith(P.PREFIX + "MapUV_"):
            compat.set_map_uv_filter(node, filter_type)
            count += 1
        elif node.name.startswith(P.filter_switch_name("")):
            compat.set_switch(node, filter_type == P.FILTER_BILINEAR)
    return count


class RenderSession:
    """One Render Edited Clip, step by step: ``begin`` sets the output up, ``render_step`` renders one frame (or,
    for a movie, the whole movie), ``end`` puts the artist's settings back. The blocking ``render`` and the modal
    operator both drive it, so both write the same files; ``end`` belongs in a ``finally`` (a cancel or an error
    restores the settings too).

    The view transform is Standard and dithering off for the render, so a PNG is the plain sRGB encoding of the
    linear result. An EXR is written in ``exr_colorspace`` (``TreePlan.output_colorspace``: the plate's space when
    scene-linear, as ``engine render``). The frames are named by ``template`` (``render_job.output_template`` of the
    manifest's clip record: ``edit.####`` for a plate ``plate.1001.png`` .., the names ``engine render`` writes by
    default; None: the scene's imported export's, ``output_template``). A frame is rendered as a still of that frame
    with ``write_still``: Blender writes it to the frame's own path (``RenderSettings.frame_path``), the same
    ``edit.1001.<ext>`` an animation render writes. The tree's mattes are written beside the frames,
    ``out_dir/mattes/<Matte>/matte.#####.exr`` (``point_mattes``; always five digits: ``engine render`` writes no
    mattes to match).

    ``exported``: the export's first and last frame; the scene's frames outside them are not rendered
    (``render_job.exported_only``: they have no passes). A movie's animation render is given the scene range of the
    frames rendered, and the artist's range is put back by ``end``.
    """

    _template = ""

    def __init__(
        self,
        scene: Any,
        out_dir: str,
        file_format: str = "exr",
        exr_colorspace: str = "Linear Rec.709",
        exported: tuple[int, int] | None = None,
        template: str | None = None,
    ):
        self.scene = scene
        self.out_dir = out_dir
        self.file_format = file_format
        self.exr_colorspace = exr_colorspace
        self.exported = exported
        self.template = output_template(scene) if template is None else template
        self._saved: dict[str, Any] | None = None
        self._image_settings: dict[str, Any] | None = None

    def scene_frames(self) -> list[int]:
        """The scene's frames, as an animation render renders them."""
        s = self.scene
        return RJ.frame_list(s.frame_start, s.frame_end, s.frame_step)

    def frames(self) -> list[int]:
        """The frames rendered: the scene's that the export has passes for (all of them without ``exported``)."""
        frames = self.scene_frames()
        return frames if self.exported is None else RJ.exported_only(frames, self.exported)[0]

    def skipped(self) -> list[int]:
        """The scene's frames left out (outside the export)."""
        frames = self.scene_frames()
        return [] if self.exported is None else RJ.exported_only(frames, self.exported)[1]

    def steps(self) -> list[int | None]:
        """One step per frame; a movie: one step (None) that renders it all."""
        return RJ.steps_for(self.file_format, self.frames())

    def begin(self) -> None:
        os.makedirs(self.out_dir, exist_ok=True)
        point_mattes(self.scene, self.out_dir)
        scene = self.scene
        r = scene.render
        self._saved = {
            "filepath": r.filepath,
            "dither": r.dither_intensity,
            "view": scene.view_settings.view_transform,
            "look": scene.view_settings.look,
            "extension": r.use_file_extension,
            "frame": scene.frame_current,
            "range": (scene.frame_start, scene.frame_end),
        }
        self._image_settings = compat.image_settings_state(r.image_settings)
        scene.view_settings.view_transform = "Standard"
        scene.view_settings.look = "None"
        r.dither_intensity = 0.0
        r.compositor_device = "CPU"
        r.compositor_precision = "FULL"
        compat.set_render_format(scene, self.file_format, self.exr_colorspace)
        r.use_file_extension = True
        movie = self.file_format not in RJ.FRAME_FORMATS
        self._template = os.path.join(os.path.abspath(self.out_dir), RJ.MOVIE_PREFIX if movie else self.template)
        r.filepath = self._template
        frames = self.frames()
        if movie and self.skipped() and frames:  # the animation render covers the rendered frames only
            _set_range(scene, frames[0], frames[-1])

    def render_step(self, frame: int | None) -> None:
        """Render ``frame`` into its file (None: the whole movie); RuntimeError when Blender does not finish."""
        scene = self.scene
        if frame is None:
            result = bpy.ops.render.render(animation=True, scene=scene.name)
        else:
            scene.frame_set(frame)
            # a still is written to the output path as it is: the frame's own path (``####`` -> the frame number,
            # the extension added), the name an animation render gives that frame
            r = scene.render
            r.filepath = self._template
            r.filepath = r.frame_path(frame=frame)
            result = bpy.ops.render.render(write_still=True, scene=scene.name)
        if "FINISHED" not in result:
            raise RuntimeError(f"render returned {result}")

    def end(self) -> None:
        """The artist's settings back (safe to call twice, and after a ``begin`` that failed half-way)."""
        saved, image_settings = self._saved, self._image_settings
        if saved is None:
            return
        scene = self.scene
        r = scene.render
        if image_settings is not None:
            compat.restore_image_settings(r.image_settings, image_settings)
        r.filepath = saved["filepath"]
        r.use_file_extension = saved["extension"]
        r.dither_intensity = saved["dither"]
        scene.view_settings.view_transform = saved["view"]
        scene.view_settings.look = saved["look"]
        if (scene.frame_start, scene.frame_end) != saved["range"]:
            _set_range(scene, *saved["range"])
        if scene.frame_current != saved["frame"]:
            scene.frame_set(saved["frame"])
        self._saved = self._image_settings = None

    def written(self) -> list[str]:
        return sorted(os.path.join(self.out_dir, f) for f in os.listdir(self.out_dir) if f.startswith("edit"))


def _set_range(scene: Any, first: int, last: int) -> None:
    """The scene's range ``first``-``last`` whatever it was (Blender moves one end when the other passes it)."""
    scene.frame_start = first
    scene.frame_end = last
    scene.frame_start = first


def render(
    scene: Any,
    out_dir: str,
    file_format: str = "exr",
    exr_colorspace: str = "Linear Rec.709",
    template: str | None = None,
) -> list[str]:
    """Render the compositor for the scene's frame range into ``out_dir/edit.1001.<ext>`` .. (named by ``template``,
    as ``RenderSession`` names them: padded as ``engine render`` pads its frames) or a movie, blocking: every step of
    a ``RenderSession`` in turn (the artist's settings are restored afterwards, also on an error)."""
    session = RenderSession(scene, out_dir, file_format, exr_colorspace, template=template)
    try:
        session.begin()
        for frame in session.steps():
            session.render_step(frame)
    finally:
        session.end()
    return session.written()
