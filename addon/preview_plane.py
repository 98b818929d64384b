"""The live preview in the 3D viewport: build the plane, its material and its camera from a ``PreviewPlan``
(``core.preview_plan``), and render one frame of it (Cycles on the CPU) for a check or a figure.

Only datablocks named ``NA_...`` are created, reused or removed, so rebuilding is idempotent. The edit images are
the canvases' own datablocks (never reloaded here): paint shows on the plane as it is laid down. At a proxy size
(``core.preview_proxy``) the UV passes and the plate's frames are written smaller first, from the export's passes and
the plate, which are only read: nothing the artist made is touched.
"""

from __future__ import annotations

import os
import time
from typing import Any

import bpy
import numpy as np

from ..engine import contract as C
from . import compat, compositor
from .core import exr_passes
from .core import preview_plan as V
from .core import preview_proxy as X
from .core import tree_plan as P

_NODE_TYPES = {
    V.TEX_COORD: "ShaderNodeTexCoord",
    V.TEX_IMAGE: "ShaderNodeTexImage",
    V.SEPARATE_XYZ: "ShaderNodeSeparateXYZ",
    V.COMBINE_XYZ: "ShaderNodeCombineXYZ",
    V.MATH: "ShaderNodeMath",
    V.VECTOR_MATH: "ShaderNodeVectorMath",
    V.MIX: "ShaderNodeMix",
    V.EMISSION: "ShaderNodeEmission",
    V.OUTPUT: "ShaderNodeOutputMaterial",
    V.VALUE: "ShaderNodeValue",
}


def split_uv_passes(plan: V.PreviewPlan) -> int:
    """Write each layer's UV pass as plain RGB EXRs (``exr_passes``; at a proxy size the pixel under each proxy
    pixel's centre, uncompressed), skipping files newer than their pass file; returns how many were written. Each
    pass file is read once for all its layers (reading is most of the time: a 4K pass file takes seconds)."""
    todo: dict[str, list[tuple[V.UVSplit, str]]] = {}
    for split in plan.splits:
        for pass_file, rgb_file in split.files:
            if not X.is_fresh(rgb_file, pass_file):
                todo.setdefault(pass_file, []).append((split, rgb_file))
    written = 0
    for pass_file, outputs in todo.items():
        names = tuple(dict.fromkeys(c for split, _ in outputs for c in split.channels))
        ch = exr_passes.read_channels(pass_file, names)
        for split, rgb_file in outputs:
            planes = [ch[c] for c in split.channels]
            if split.size is None:
                exr_passes.write_rgb(rgb_file, *planes)
            else:
                small = [X.downsample(plane, split.size) for plane in planes]
                exr_passes.write_rgb(rgb_file, *small, compression=exr_passes.NO_COMPRESSION)
            written += 1
    return written


def write_plate_proxy(proxy: V.PlateProxy) -> tuple[V.PreviewImage, int]:
    """Write the plate's frames at the proxy size, skipping those whose proxy is newer than the frame; returns the
    preview's plate image and how many were written. Blender reads each frame (any format it reads): an 8-bit one's
    bytes are written as they are to an 8-bit PNG in the plate's colour space, a float one's scene-linear values to
    an uncompressed float EXR read as Non-Color, so the proxy's pixels are the plate's pixels exactly."""
    written, is_float = 0, None
    for source, stem in proxy.files:
        made = [stem + ext for ext in X.PLATE_EXTS if X.is_fresh(stem + ext, source)]
        if made:
            is_float = made[0].endswith(X.PLATE_FLOAT_EXT) if is_float is None else is_float
            continue
        try:
            img = bpy.data.images.load(source, check_existing=False)
        except RuntimeError:  # a gap in the plate, or a file Blender cannot read: shown as the plate shows it, empty
            continue
        try:
            w, h = img.size
            px = np.empty(w * h * 4, np.float32)
            img.pixels.foreach_get(px)
            frame_float = bool(img.is_float)
        finally:
            bpy.data.images.remove(img)
        if not w or not h:
            continue
        small = X.downsample(px.reshape(h, w, 4), proxy.size, top_first=False)[::-1]  # rows top-first
        if frame_float:
            exr_passes.write_rgb(
                stem + X.PLATE_FLOAT_EXT, *(small[..., c] for c in range(3)), compression=exr_passes.NO_COMPRESSION
            )
        else:
            X.write_png_rgba8(stem + X.PLATE_BYTE_EXT, np.rint(np.clip(small, 0.0, 1.0) * 255.0).astype(np.uint8))
        is_float = frame_float if is_float is None else is_float
        written += 1
    return V.proxy_plate_image(proxy, bool(is_float)), written


def _image(spec: V.PreviewImage) -> Any:
    path = os.path.abspath(spec.filepath)
    img = bpy.data.images.get(spec.name)
    if img is not None and os.path.abspath(bpy.path.abspath(img.filepath)) == path:
        img.reload()  # the split files may have been rewritten
    else:
        if img is not None:
            bpy.data.images.remove(img)
        img = bpy.data.images.load(compositor.blend_path(path), check_existing=False)  # relative where it can be
        img.name = spec.name
    img.source = spec.source
    img.colorspace_settings.name = spec.colorspace
    return img


def _socket(sockets: Any, key: str | int) -> Any:
    if isinstance(key, int):
        return sockets[key]
    return next(s for s in sockets if s.name == key and s.enabled)


def _material(plan: V.PreviewPlan, images: dict[str, Any]) -> Any:
    mat = bpy.data.materials.get(V.PREVIEW_MATERIAL) or bpy.data.materials.new(V.PREVIEW_MATERIAL)
    compat.ensure_material_nodes(mat)
    nt = mat.node_tree
    if nt.animation_data is not None:
        nt.animation_data_clear()  # the drivers of the nodes cleared next
    nt.nodes.clear()
    users = {spec.name: spec.user for spec in plan.images}
    made: dict[str, Any] = {}
    for spec in plan.nodes:
        node = nt.nodes.new(_NODE_TYPES[spec.kind])
        node.name = node.label = spec.name
        node.location = spec.location
        params = spec.params
        if spec.kind == V.TEX_IMAGE:
            image_name = params["image"]
            node.image = images.get(image_name) or bpy.data.images.get(image_name)
            node.interpolation = params["interpolation"]
            node.extension = "CLIP"
            user = users.get(image_name)
            if user is not None:
                iu = node.image_user
                iu.frame_duration = user.frame_duration
                iu.frame_start = user.frame_start
                iu.frame_offset = user.frame_offset
                iu.use_auto_refresh = True
                iu.use_cyclic = False
        elif spec.kind in (V.MATH, V.VECTOR_MATH):
            node.operation = params["operation"]
            if spec.kind == V.MATH:
                node.use_clamp = False
        elif spec.kind == V.VALUE:
            node.outputs[0].default_value = params.get("value", 0.0)
            if "driver" in params:
                driver = node.outputs[0].driver_add("default_value").driver
                driver.type = "SCRIPTED"
                driver.expression = params["driver"]
        elif spec.kind == V.MIX:
            node.data_type = "RGBA"
            node.blend_type = "MIX"
            node.clamp_factor = True
            node.clamp_result = False
        for key, value in params.get("defaults", {}).items():
            _socket(node.inputs, key).default_value = value
        made[spec.name] = node
    for link in plan.links:
        nt.links.new(
            _socket(made[link.from_node].outputs, link.from_socket), _socket(made[link.to_node].inputs, link.to_socket)
        )
    if V.FRAME_PAINT_NODE in made:
        nt.nodes.active = made[V.FRAME_PAINT_NODE]
    mat[V.EXPORT_FRAMES_PROP] = list(plan.export_frames)
    mat[V.PROXY_PROP] = [plan.percent, *plan.size, *plan.resolution]
    return mat


def shown_size() -> tuple[int, tuple[int, int], tuple[int, int]] | None:
    """The built preview's (percent, size, the plate's size) (None: no preview built)."""
    mat = bpy.data.materials.get(V.PREVIEW_MATERIAL)
    got = mat.get(V.PROXY_PROP) if mat is not None else None
    if got is None or len(got) != 5:
        return None
    return int(got[0]), (int(got[1]), int(got[2])), (int(got[3]), int(got[4]))


def export_frames() -> tuple[int, int] | None:
    """The exported frames the live preview shows paint on (None: no preview built)."""
    mat = bpy.data.materials.get(V.PREVIEW_MATERIAL)
    frames = mat.get(V.EXPORT_FRAMES_PROP) if mat is not None else None
    return (int(frames[0]), int(frames[1])) if frames is not None and len(frames) == 2 else None


def _collection(scene: Any) -> Any:
    coll = bpy.data.collections.get(V.PREVIEW_COLLECTION) or bpy.data.collections.new(V.PREVIEW_COLLECTION)
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    return coll


def _plane(coll: Any, framing: V.Framing, mat: Any) -> Any:
    mesh = bpy.data.meshes.get(V.PREVIEW_OBJECT) or bpy.data.meshes.new(V.PREVIEW_OBJECT)
    mesh.clear_geometry()
    w, h = framing.size
    mesh.from_pydata([(0, 0, 0), (w, 0, 0), (w, h, 0), (0, h, 0)], [], [(0, 1, 2, 3)])
    uv = mesh.uv_layers.new(name="UVMap")
    for loop, co in zip(uv.data, ((0, 0), (1, 0), (1, 1), (0, 1)), strict=True):
        loop.uv = co
    mesh.materials.clear()
    mesh.materials.append(mat)
    obj = bpy.data.objects.get(V.PREVIEW_OBJECT) or bpy.data.objects.new(V.PREVIEW_OBJECT, mesh)
    obj.data = mesh
    obj.location = (framing.origin[0], framing.origin[1], 0.0)
    obj.rotation_euler = (0.0, 0.0, 0.0)
    obj.scale = (1.0, 1.0, 1.0)
    if obj.name not in coll.objects:
        coll.objects.link(obj)
    return obj


def _camera(coll: Any, framing: V.Framing) -> Any:
    cam = bpy.data.cameras.get(V.PREVIEW_CAMERA) or bpy.data.cameras.new(V.PREVIEW_CAMERA)
    cam.type = "ORTHO"
    cam.ortho_scale = framing.ortho_scale
    cam.sensor_fit = "AUTO"
    cam.shift_x, cam.shift_y = framing.shift
    cam.clip_start, cam.clip_end = 0.01, 2.0 * V.CAMERA_HEIGHT
    obj = bpy.data.objects.get(V.PREVIEW_CAMERA) or bpy.data.objects.new(V.PREVIEW_CAMERA, cam)
    obj.data = cam
    obj.location = framing.camera_location
    obj.rotation_euler = (0.0, 0.0, 0.0)  # looking down -Z at the plane
    if obj.name not in coll.objects:
        coll.objects.link(obj)
    return obj


#: Each twin's edit pixels at its last copy and the edit file's stamp then (``_file_stamp``): to copy only what changed.
_synced: dict[str, tuple[np.ndarray, tuple[str, int, int] | None]] = {}
#: How often (seconds) at most the float twins follow the paint while the preview is shown; the timer waits
#: ``SYNC_LOAD`` times as long as its last check took (large atlases), at most ``SYNC_SLOWEST`` s.
SYNC_INTERVAL = 0.25
SYNC_LOAD = 4.0
SYNC_SLOWEST = 2.0


def _mirror(edit: Any, name: str) -> Any:
    w, h = edit.size
    img = bpy.data.images.get(name)
    if img is None or tuple(img.size) != (w, h) or not img.is_float:
        if img is not None:
            bpy.data.images.remove(img)
        img = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True)
        _synced.pop(name, None)
    img.colorspace_settings.name = "Non-Color"  # raw premultiplied linear values, as the engine reads its PNG
    img.alpha_mode = "PREMUL"
    return img


def _file_stamp(img: Any) -> tuple[str, int, int] | None:
    """The image's file as it is on disk (path, mtime in ns, size): a saved edit image whose stamp is unchanged since
    its last copy holds the same pixels. Save Edits, Land Paint on Atlases (which reloads the image) and another
    file's image change it. None when there is no file."""
    path = bpy.path.abspath(img.filepath) if img.filepath else ""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return os.path.normpath(path), st.st_mtime_ns, st.st_size


def sync(force: bool = False) -> int:
    """Copy every edit image's pixels (unsaved paint included) into its float twin (an 8-bit one converted as the
    engine reads the PNG; a float one, linear premultiplied, as it is); only images whose pixels changed since the
    last copy (``force``: all; an edit image with no unsaved paint whose file is as it was at the last copy is not
    read again). Returns how many."""
    mat = bpy.data.materials.get(V.PREVIEW_MATERIAL)
    if mat is None or mat.node_tree is None:
        return 0
    copied = 0
    for node in mat.node_tree.nodes:
        if not node.name.startswith("Edit_") or node.image is None:
            continue
        twin = node.image
        if not twin.name.startswith(V.mirror_image_name("")):
            continue
        edit = bpy.data.images.get(P.edit_image_name(twin.name.removeprefix(V.mirror_image_name(""))))
        if edit is None or not edit.size[0]:
            continue
        last, last_stamp = _synced.get(twin.name, (None, None))
        stamp = _file_stamp(edit)
        if not force and last is not None and not edit.is_dirty and stamp is not None and stamp == last_stamp:
            continue
        w, h = edit.size
        px = np.empty(w * h * 4, np.float32)
        edit.pixels.foreach_get(px)
        if not force and last is not None and tuple(twin.size) == (w, h) and np.array_equal(last, px):
            _synced[twin.name] = (last, stamp)
            continue
        if tuple(twin.size) != (w, h):
            twin = _mirror(edit, twin.name)
            node.image = twin
        twin.pixels.foreach_set(px if edit.is_float else V.straight_srgb_to_premultiplied(px))
        twin.update()
        _synced[twin.name] = (px, stamp)
        copied += 1
    return copied


def _tick() -> float | None:
    start = time.perf_counter()
    try:
        scene = bpy.context.scene
        if scene is None or not is_shown(scene):
            return SYNC_INTERVAL
        sync()
    except (ReferenceError, AttributeError, RuntimeError):
        pass  # a file loading or the add-on going away: try again next time
    return min(SYNC_SLOWEST, max(SYNC_INTERVAL, SYNC_LOAD * (time.perf_counter() - start)))


def forget_copies() -> int:
    """After another file is loaded (File > Open, Revert): the copies remembered belong to the file that was open,
    and the loaded file's twins hold no paint (a twin is made in Blender: the .blend keeps none of its pixels). Forget
    them and fill the loaded file's twins now, so the preview shows its paint before the timer's next tick; returns
    how many were filled."""
    _synced.clear()
    try:
        return sync()
    except (ReferenceError, AttributeError, RuntimeError):
        return 0  # an image the loaded file lacks: the timer tries again


def start_live() -> None:
    """Keep the float twins following the paint (a timer: painting sends no event an add-on can hook)."""
    if not bpy.app.timers.is_registered(_tick):
        bpy.app.timers.register(_tick, first_interval=SYNC_INTERVAL, persistent=True)


def stop_live() -> None:
    if bpy.app.timers.is_registered(_tick):
        bpy.app.timers.unregister(_tick)


def build(scene: Any, tree: P.TreePlan, manifest: dict[str, Any], manifest_path: str, filter_type: str) -> Any:
    """Create (or recreate) the preview for an imported export whose compositor tree ``tree`` is built (its edit
    images exist), at the scene's proxy size (``preview_proxy``); returns the plane. The scene's camera becomes the
    preview's only when it has none."""
    frame_paint = bpy.data.images.get(P.FRAME_PAINT_IMAGE) is not None
    percent = X.proxy_percent(scene.neural_atlas.preview_proxy, tree.resolution)
    plan = V.plan_preview(tree, manifest, manifest_path, filter_type, frame_paint, percent)
    split_uv_passes(plan)
    if plan.plate_proxy is not None:  # the plate's image shows its proxy
        plate = write_plate_proxy(plan.plate_proxy)[0]
        plan.images = [plate if spec.name == plate.name else spec for spec in plan.images]
    images = {spec.name: _image(spec) for spec in plan.images}
    for layer, twin in plan.mirrors.items():
        images[twin] = _mirror(bpy.data.images[P.edit_image_name(layer)], twin)
    coll = _collection(scene)
    mat = _material(plan, images)
    plane = _plane(coll, plan.framing, mat)
    cam = _camera(coll, plan.framing)
    if scene.camera is None:
        scene.camera = cam
    coll.hide_viewport = False
    coll.hide_render = False
    sync(force=True)
    start_live()
    return plane


def plan_rebuild(scene: Any) -> tuple[P.TreePlan, dict[str, Any], str]:
    """What ``rebuild`` builds from, checked without changing anything: (tree, manifest, its path). Raises the
    import's errors (``ops.import_run.IMPORT_ERRORS``, one line each)."""
    props = scene.neural_atlas
    manifest_path = compositor.imported_manifest(scene)
    manifest = C.load_manifest(manifest_path)
    plate = compositor.known_plate(scene, manifest_path)  # a run folder relinked without its plate
    names = compat.colorspace_names()
    tree = P.plan_tree(manifest, manifest_path, props.filter_type, None, names, plate, compat.BILINEAR_TAPS)
    missing = sorted(name for name in map(P.edit_image_name, tree.layers) if bpy.data.images.get(name) is None)
    if missing:
        raise ValueError(f"{', '.join(missing)} missing: import the atlas again ({manifest_path})")
    return tree, manifest, manifest_path


def rebuild(scene: Any, planned: tuple[P.TreePlan, dict[str, Any], str] | None = None) -> Any:
    """Build the preview again for the scene's imported export (after ``NA_FramePaint`` appears, say) from
    ``planned`` (``plan_rebuild``; None: planned now); returns the plane. Raises the import's errors."""
    tree, manifest, manifest_path = planned or plan_rebuild(scene)
    return build(scene, tree, manifest, manifest_path, scene.neural_atlas.filter_type)


def set_filter(filter_type: str) -> int:
    """The edit images' interpolation in the preview material for a panel filter (``tree_plan.FILTERS``), the same
    sampling as the compositor's; returns the nodes set."""
    mat = bpy.data.materials.get(V.PREVIEW_MATERIAL)
    count = 0
    for node in mat.node_tree.nodes if mat is not None and mat.node_tree is not None else ():
        if node.name.startswith("Edit_") and node.bl_idname == "ShaderNodeTexImage":
            node.interpolation = V.INTERPOLATION[filter_type]
            count += 1
    return count


def is_shown(scene: Any) -> bool:
    coll = bpy.data.collections.get(V.PREVIEW_COLLECTION)
    return coll is not None and coll.name in scene.collection.children and not coll.hide_viewport


def hide(scene: Any) -> None:
    coll = bpy.data.collections.get(V.PREVIEW_COLLECTION)
    if coll is not None:
        coll.hide_viewport = True
        coll.hide_render = True


def render_frame(scene: Any, frame: int, path: str) -> str:
    """Render the preview at scene frame ``frame`` to a float EXR (scene-linear RGBA), as the viewport's Rendered
    shading shows it: Cycles on the CPU, 1 sample, a 0.01-pixel box filter (each pixel the plane point under its
    centre), no denoising, Standard view, the compositor off, through the preview camera. The scene's settings are
    restored afterwards; returns ``path``. It renders at the scene's resolution: a preview at a proxy size is seen
    pixel for pixel with the scene's resolution percentage at that size (at 100 % each proxy pixel shows as a block).

    A final Cycles render without a UI reloads every file image from its file afterwards, dropping unsaved paint
    (measured on 4.5 and 5.0, even for an empty scene): the pixels of every image with unsaved changes are kept and
    put back. (A scratch scene holding only the preview would not do: its image sequences do not follow its frame.)"""
    r, cycles, view = scene.render, scene.cycles, scene.view_settings
    # each setting the render needs, with its value; the scene's own values are put back afterwards
    render_settings = (
        (r, "engine", "CYCLES"),
        (r, "use_compositing", False),  # the compositor would replace the picture with its own tree's result
        (r, "use_sequencer", False),
        (r, "film_transparent", False),
        (r, "dither_intensity", 0.0),
        (scene, "camera", bpy.data.objects[V.PREVIEW_CAMERA]),
        (view, "view_transform", "Standard"),
        (view, "look", "None"),
        (view, "exposure", 0.0),
        (view, "gamma", 1.0),
        (cycles, "device", "CPU"),
        (cycles, "samples", 1),
        (cycles, "use_adaptive_sampling", False),
        (cycles, "use_denoising", False),
        (cycles, "pixel_filter_type", "BOX"),
        (cycles, "filter_width", 0.01),
    )
    saved = [(owner, attr, getattr(owner, attr)) for owner, attr, _ in render_settings]
    current = scene.frame_current
    unsaved = _keep_unsaved()
    try:
        for owner, attr, value in render_settings:
            setattr(owner, attr, value)
        scene.frame_set(frame)
        sync()
        bpy.ops.render.render(write_still=False, scene=scene.name)
        result = bpy.data.images["Render Result"]
        settings = scene.render.image_settings
        state = compat.image_settings_state(settings)
        try:
            compat.set_render_format(scene, "exr")
            os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
            result.save_render(filepath=path, scene=scene)
        finally:
            compat.restore_image_settings(settings, state)
    finally:
        for owner, attr, value in saved:
            setattr(owner, attr, value)
        _put_back(unsaved)
        scene.frame_set(current)
    return path


def _keep_unsaved() -> list[tuple[Any, np.ndarray]]:
    kept = []
    for img in bpy.data.images:
        if img.is_dirty and img.source == "FILE" and img.size[0]:
            px = np.empty(len(img.pixels), np.float32)
            img.pixels.foreach_get(px)
            kept.append((img, px))
    return kept


def _put_back(kept: list[tuple[Any, np.ndarray]]) -> None:
    for img, px in kept:
        img.pixels.foreach_set(px)  # marks it unsaved again, as it was
        img.update()
