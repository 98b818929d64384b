"""Paint set-up: per layer a plane whose material shows the edit layer over the atlas, with the edit layer
as the active paint slot, and saving the edit layers back to their PNG files."""

from __future__ import annotations

import os
from typing import Any

import bpy

from . import compat
from . import tree_plan as P


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


def setup_canvases(context: Any, layers: list[str]) -> list[Any]:
    """A unit plane per layer, side by side, UVs covering the atlas; returns the objects."""
    objects = []
    collection = bpy.data.collections.get(f"{P.PREFIX}Canvases")
    if collection is None:
        collection = bpy.data.collections.new(f"{P.PREFIX}Canvases")
    if collection.name not in context.scene.collection.children:
        context.scene.collection.children.link(collection)
    for layer in layers:
        edit = bpy.data.images.get(P.edit_image_name(layer))
        atlas = bpy.data.images.get(P.atlas_image_name(layer))
        if edit is None or atlas is None:
            continue
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
        aspect = edit.size[0] / edit.size[1] if edit.size[1] else 1.0
        obj.scale = (aspect, 1.0, 1.0)  # texels stay square while painting
        obj.location = (sum(1.2 * max(1.0, o.scale[0]) for o in objects), 0.0, 0.0)
        mat = _material(layer, edit, atlas)
        if not mesh.materials:
            mesh.materials.append(mat)
        else:
            mesh.materials[0] = mat
        objects.append(obj)
    return objects


def save_edits() -> list[str]:
    """Write every painted edit layer back to its PNG (8-bit sRGB, straight alpha); returns the paths."""
    saved = []
    for img in bpy.data.images:
        if not img.name.startswith(P.PREFIX + "Edit_") or not img.is_dirty:
            continue
        path = bpy.path.abspath(img.filepath)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        img.filepath_raw = path
        img.file_format = "PNG"
        img.save()
        saved.append(path)
    return saved
