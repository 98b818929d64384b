"""Paint set-up: per layer a plane whose material shows the edit layer over the atlas, with the edit layer
as the active paint slot; saving the edit layers back to their files in the format each has (8-bit sRGB PNG,
straight alpha, or float EXR, scene-linear and premultiplied); and turning a PNG edit layer into a float one.

Float edit layers exist because Blender decodes 8-bit sRGB through OCIO, which differs slightly from the exact
IEC 61966-2-1 formula the engine uses (docs/blender-compat.md): a float layer is read raw by both, so the
compositor and ``engine render`` agree to float precision, and paint keeps values above 1 and below 1/255."""

from __future__ import annotations

import array
import os
from collections.abc import Iterable
from contextlib import nullcontext
from typing import Any

import bpy
from mathutils import Vector

from ..engine import contract as C
from . import compat
from .core import float_edit, placement, relink, run_files, unsaved_paint
from .core import tree_plan as P


def canvas_name(layer: str) -> str:
    return f"{P.PREFIX}Canvas_{layer}"


def _material(layer: str, edit: Any, atlas: Any) -> Any:
    name = f"{P.PREFIX}Paint_{layer}"
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    compat.ensure_material_nodes(mat)
    nt = mat.node_tree
    nt.nodes.clear()
    n_atlas = nt.nodes.new("ShaderNodeTexImage")
    n_atlas.name, n_atlas.image, n_atlas.location = "Atlas", atlas, (-500, 200)
    n_edit = nt.nodes.new("ShaderNodeTexImage")
    n_edit.name, n_edit.image, n_edit.location = "Edit", edit, (-500, -100)
    n_mix = nt.nodes.new("ShaderNodeMix")
    n_mix.data_type = "RGBA"
    n_mix.location = (-200, 100)
    mix_in = [s for s in n_mix.inputs if s.enabled]
    mix_out = next(s for s in n_mix.outputs if s.enabled and s.name == "Result")
    nt.links.new(n_edit.outputs["Alpha"], mix_in[0])  # Factor: the paint's alpha
    nt.links.new(n_atlas.outputs["Color"], mix_in[1])
    n_edit_color = n_edit.outputs["Color"]
    nt.links.new(n_edit_color, mix_in[2])
    n_emit = nt.nodes.new("ShaderNodeEmission")
    n_emit.location = (0, 100)
    nt.links.new(mix_out, n_emit.inputs["Color"])
    n_out = nt.nodes.new("ShaderNodeOutputMaterial")
    n_out.location = (200, 100)
    nt.links.new(n_emit.outputs[0], n_out.inputs["Surface"])
    nt.nodes.active = n_edit  # the active image node is the texture-paint slot
    mat.paint_active_slot = 0
    return mat


def scene_boxes(context: Any, also: Iterable[str] = ()) -> list[placement.Box]:
    """World-space boxes of the scene's visible objects, the add-on's own (``NA_``) left out except those named in
    ``also``: what a plane the add-on places must keep clear of (``placement.place_row``)."""
    context.view_layer.update()  # world matrices of objects moved since the last update
    keep = set(also)
    boxes = []
    for obj in context.scene.objects:
        if (obj.name.startswith(P.PREFIX) and obj.name not in keep) or not obj.visible_get():
            continue
        world = obj.matrix_world
        boxes.append(placement.Box.around(tuple(world @ Vector(corner)) for corner in obj.bound_box))
    return boxes


def setup_canvases(context: Any, layers: list[str]) -> list[Any]:
    """A plane per layer, UVs covering the atlas, its sides in the atlas's proportions; in a row beyond the scene's
    own objects (``placement.place_row``), so no canvas sits inside or on top of the artist's work. Returns them."""
    collection = bpy.data.collections.get(f"{P.PREFIX}Canvases")
    if collection is None:
        collection = bpy.data.collections.new(f"{P.PREFIX}Canvases")
    if collection.name not in context.scene.collection.children:
        context.scene.collection.children.link(collection)
    found = []
    for layer in layers:
        edit = bpy.data.images.get(P.edit_image_name(layer))
        atlas = bpy.data.images.get(P.atlas_image_name(layer))
        if edit is not None and atlas is not None:
            found.append((layer, edit, atlas))
    aspects = [edit.size[0] / edit.size[1] if edit.size[1] else 1.0 for _, edit, _ in found]
    spots = placement.place_row(scene_boxes(context), [(aspect, 1.0) for aspect in aspects])
    objects = []
    for (layer, edit, atlas), aspect, spot in zip(found, aspects, spots, strict=True):
        name = canvas_name(layer)
        mesh = bpy.data.meshes.get(name)
        if mesh is None:
            mesh = bpy.data.meshes.new(name)
            mesh.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [], [(0, 1, 2, 3)])
            uv = mesh.uv_layers.new(name="UVMap")
            for loop, co in zip(uv.data, ((0, 0), (1, 0), (1, 1), (0, 1)), strict=True):
                loop.uv = co
        obj = bpy.data.objects.get(name) or bpy.data.objects.new(name, mesh)
        if obj.name not in collection.objects:
            collection.objects.link(obj)
        obj.scale = (aspect, 1.0, 1.0)  # texels stay square while painting
        obj.location = spot
        mat = _material(layer, edit, atlas)
        if not mesh.materials:
            mesh.materials.append(mat)
        else:
            mesh.materials[0] = mat
        objects.append(obj)
    return objects


def show_layer(context: Any, layer: str, canvas: Any | None) -> int:
    """Make ``layer`` the one painted: its canvas the active, selected object (what Texture Paint paints in the 3D
    viewport) and its edit image the one every Image Editor shows (what Paint mode paints there). Returns how many
    Image Editors now show it."""
    if canvas is not None and canvas.name in context.view_layer.objects:
        for obj in context.view_layer.objects:
            if obj.name.startswith(canvas_name("")):
                obj.select_set(obj == canvas)
        canvas.select_set(True)
        context.view_layer.objects.active = canvas
    edit = bpy.data.images[P.edit_image_name(layer)]
    shown = 0
    for window in context.window_manager.windows:
        for area in window.screen.areas:
            for space in area.spaces:
                if space.type == "IMAGE_EDITOR":
                    space.image = edit
                    shown += 1
    return shown


def painted_layer(context: Any) -> str | None:
    """The imported layer being painted where the panel is drawn: the Image Editor's edit image, else the active
    object's canvas; None when neither is one."""
    prefix = P.edit_image_name("")
    image = getattr(getattr(context, "space_data", None), "image", None)
    if image is not None and image.name.startswith(prefix):
        return image.name.removeprefix(prefix)
    obj = getattr(context, "active_object", None)
    if obj is not None and obj.name.startswith(canvas_name("")):
        return obj.name.removeprefix(canvas_name(""))
    return None


def _is_exr(path: str) -> bool:
    return path.lower().endswith(C.EDIT_LAYER_FLOAT_EXT)


def _dirty_edits() -> list[Any]:
    return [img for img in bpy.data.images if img.name.startswith(P.PREFIX + "Edit_") and img.is_dirty]


def save_before_reload(action: str) -> list[str]:
    """Save the unsaved paint of every edit layer (``save_edits``) before ``action`` reloads or replaces the edit
    images, which would drop it; returns the paths saved. Raises ValueError (one line, ``unsaved_paint.refusal``)
    when some paint has no file to go to, before anything is saved or reloaded; a run folder in use or a full disk
    raise as in ``save_edits``, the paint still unsaved in Blender."""
    dirty = [
        unsaved_paint.EditImage(img.name, img.filepath, img.packed_file is not None, img.source == "GENERATED")
        for img in _dirty_edits()
    ]
    line = unsaved_paint.refusal(action, dirty)
    if line:
        raise ValueError(line)
    return save_edits()


def save_edits(manifest_path: str | None = None) -> list[str]:
    """Write every painted edit layer back to its file, keeping the format it has; returns the paths.

    A PNG stays 8-bit sRGB with straight alpha; an EXR stays a full-float, scene-linear, premultiplied EXR
    (Non-Color since the import, so Blender writes the raw values: a Linear one would be saved encoded). Holds the
    run folder's lock of ``manifest_path`` (default: the imported atlas's) while writing: ``contract.RunLocked``
    (one line naming the export or project-frame that holds it) leaves every file as it was."""
    dirty = _dirty_edits()
    if not dirty:
        return []
    manifest_path = manifest_path or bpy.path.abspath(bpy.context.scene.neural_atlas.manifest)
    lock = run_files.edits_lock(manifest_path, run_files.SAVE_EDITS_HOLDER) if manifest_path else nullcontext()
    saved = []
    with lock:
        for img in dirty:
            path = bpy.path.abspath(img.filepath)
            os.makedirs(os.path.dirname(path), exist_ok=True)
            img.filepath_raw = relink.relative_path(path, bpy.data.filepath)  # stays relative to the .blend
            if _is_exr(path):
                # the import made it Non-Color (raw values on save); setting the colourspace here, even to the same
                # name, would reload the image from disk and silently drop the unsaved paint (docs/blender-compat.md)
                compat.set_float_exr(img)
            else:
                img.file_format = "PNG"
            save_atomically(img, path)
            saved.append(path)
    return saved


def save_atomically(img: Any, path: str) -> None:
    """Save ``img`` (its format already set) under a hidden name beside ``path``, check that a whole image was
    written, and rename it onto ``path``: a full disk or a crash mid-save leaves the edit layer as it was. Blender
    reports a failed save without raising (and marks the image saved), so the file is read back; when it is not
    whole the paint is marked unsaved again (it is still in Blender) and this raises OSError (one line)."""
    tmp = run_files.saving_path(path)
    try:
        img.save(filepath=tmp)
        if not _whole_image(tmp, tuple(img.size)):
            _mark_unsaved(img)
            raise OSError(f"{path}: could not be saved (is the disk full?) — free space, then Save Edits again")
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def _whole_image(path: str, size: tuple[int, int]) -> bool:
    """Whether ``path`` holds a readable image of ``size``."""
    if not os.path.isfile(path) or os.path.getsize(path) == 0:
        return False
    probe = bpy.data.images.load(path, check_existing=False)
    try:
        return tuple(probe.size) == size
    finally:
        bpy.data.images.remove(probe)


def _mark_unsaved(img: Any) -> None:
    """Give Blender's image its own pixels back, which marks it unsaved (so Save Edits and quitting still see it)."""
    px = array.array("f", [0.0]) * (img.size[0] * img.size[1] * img.channels)
    img.pixels.foreach_get(px)
    img.pixels.foreach_set(px)


def make_float_edit(layer: str, dst: str | None = None) -> str:
    """Write ``<Layer>.exr`` (linear, premultiplied) next to the layer's PNG edit, from its current pixels
    (unsaved paint included); returns the path. Refuses to replace an existing EXR: that is the artist's paint.
    The PNG is left as it was; from now on the EXR is the layer's edit (``contract.edit_layer_file``). ``dst``: where
    to write it, as ``tree_plan.float_edit_path`` checked it (default: beside the image's file)."""
    img = bpy.data.images.get(P.edit_image_name(layer))
    if img is None:
        raise ValueError(f"no edit layer {layer!r}: import the atlas first")
    src = bpy.path.abspath(img.filepath)
    if _is_exr(src):
        raise ValueError(f"{src} is already a float edit layer")
    dst = dst or C.float_edit_layer(src)
    if os.path.exists(dst):
        raise ValueError(f"{dst} exists (it is used instead of the PNG): import the atlas again to paint in it")
    w, h = img.size
    px = array.array("f", [0.0]) * (w * h * float_edit.CHANNELS)
    img.pixels.foreach_get(px)  # a byte image gives its stored sRGB values, straight alpha, rows bottom-up
    out = float_edit.straight_srgb_to_premultiplied_linear(px)
    tmp = bpy.data.images.new(f"{P.PREFIX}tmp_float_edit", w, h, alpha=True, float_buffer=True)
    try:
        tmp.colorspace_settings.name = "Non-Color"  # raw values on save (a Linear image would be sRGB-encoded)
        tmp.alpha_mode = "PREMUL"
        tmp.pixels.foreach_set(out)
        tmp.filepath_raw = dst
        compat.set_float_exr(tmp)
        os.makedirs(os.path.dirname(dst), exist_ok=True)
        save_atomically(tmp, dst)  # a half-written EXR would win over the PNG: all of it or nothing
    finally:
        bpy.data.images.remove(tmp)
    return dst
