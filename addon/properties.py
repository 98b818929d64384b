"""The add-on's scene settings: one root PropertyGroup, ``Scene.neural_atlas``."""

from __future__ import annotations

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from ..engine import contract as C
from . import compat
from .core import estimate, preview_proxy
from .core import tree_plan as P

#: Refine's preset menu entry for "the schedule the fit ran with" (no ``--preset``).
REFINE_SAME_PRESET = "FIT"


def _forget_estimate(self, context):
    self.estimate_json = ""  # measured for another clip or size


def _on_write_mattes(self, context):
    from . import compositor

    compositor.point_mattes(context.scene)


def _on_filter(self, context):
    from . import compositor, preview_plane

    compositor.set_filter(context.scene, self.filter_type)
    preview_plane.set_filter(self.filter_type)


def _on_preview_proxy(self, context):
    from .ops import preview

    preview.show_at_new_size(context.scene)


class NEURALATLAS_PG_layer(bpy.types.PropertyGroup):
    source: EnumProperty(
        name="Source",
        items=[
            ("MASK", "Mask", "A Blender Mask datablock, rasterized per frame"),
            ("FOLDER", "Images", "A folder with one mask image per frame"),
        ],
        default="MASK",
        description="Where this layer's masks come from: a Blender Mask, or a folder of mask images",
    )
    mask: PointerProperty(name="Mask", type=bpy.types.Mask, description="Roto of this foreground object")
    folder: StringProperty(
        name="Folder",
        subtype="DIR_PATH",
        description=f"Mask images (>{C.MASK_THRESHOLD:.0%} = foreground)",
        options=compat.PATH_OPTIONS,
    )


class NEURALATLAS_PG_scene(bpy.types.PropertyGroup):
    clip: PointerProperty(
        name="Clip", type=bpy.types.MovieClip, description="The plate to fit", update=_forget_estimate
    )
    use_clip_range: BoolProperty(name="Whole Clip", default=True, description="Fit every frame of the clip")
    frame_start: IntProperty(name="Start", default=1, description="First scene frame to fit")
    frame_end: IntProperty(name="End", default=50, description="Last scene frame to fit")
    long_edge: IntProperty(
        name="Fit Resolution",
        default=C.DEFAULT_LONG_EDGE,
        min=64,
        max=4096,
        description="Long edge of the resolution the fit runs at",
        update=_forget_estimate,
    )
    preset: EnumProperty(
        name="Preset",
        items=estimate.preset_items(),
        default="draft",
        description="How long the fit trains, and so how closely it follows the plate (Estimate Time measures each)",
    )
    overrides: StringProperty(
        name="Engine Settings",
        default="",
        description="Engine settings for Fit Atlas, Estimate Time and Submit to Farm, space separated KEY=VALUE, "
        "e.g. steps=2000 (advanced; python -m engine fit --help-config lists the keys)",
        update=_forget_estimate,
    )
    follow_flow: BoolProperty(
        name="Follow Motion",
        default=True,
        description="Export: average each layer's UV along optical flow where it slips "
        "against it, so paint follows legs and bending, turning bodies: over a few frames or along whole "
        "trajectories, whichever reads the plate back sharper (off: the atlas's UV as fitted)",
    )
    refine_steps: IntProperty(
        name="Steps",
        default=1000,
        min=0,
        soft_max=100000,
        description="Refine: steps to add to the finished fit (0: on to the chosen preset's step budget)",
    )
    refine_preset: EnumProperty(
        name="Refine With",
        items=[(REFINE_SAME_PRESET, "Fit's Preset", "The schedule the fit ran with"), *estimate.preset_items()],
        default=REFINE_SAME_PRESET,
        description="Refine with this preset's learning rates and schedule (a preset the fit was not trained for "
        "is refused by the engine, saying why)",
    )
    carry_from: StringProperty(
        name="Paint From",
        subtype="FILE_PATH",
        description="Another fit of this plate (its run folder or manifest.json) whose paint Carry Paint takes",
    )
    layers: CollectionProperty(type=NEURALATLAS_PG_layer, description="The foreground objects to fit, a layer each")
    layer_index: IntProperty(description="The layer selected in the list")
    use_scribbles: BoolProperty(
        name="Split with Scribbles",
        default=False,
        description="Split the one foreground layer into parts (e.g. two legs) marked with the clip's annotation "
        "strokes: part 1 in red, part 2 in green, part 3 in blue, part 4 in yellow, on about one frame in six",
    )
    find_parts: BoolProperty(
        name="Find Parts",
        default=True,
        description="Split the one foreground layer into the parts that move apart (a limb swinging across the "
        "body), found from its motion when the fit starts; an object that moves as one piece stays one layer",
    )
    run_dir: StringProperty(
        name="Run Folder",
        subtype="DIR_PATH",
        default="//neural_atlas/",
        description="Where the fit is written",
        options=compat.PATH_OPTIONS,
    )
    # relative to the .blend where it can be (as the imported images are): a shot folder copied whole keeps working
    manifest: StringProperty(
        name="Manifest", subtype="FILE_PATH", description="The imported export", options=compat.PATH_OPTIONS
    )
    imported_layers: StringProperty(default="", description="The imported run's layers, comma separated")
    # the identifiers are engine render's --filter names; the numbers keep what older files stored (0 was the
    # default, 2 Nearest)
    filter_type: EnumProperty(
        name="Filter",
        items=[
            (
                P.FILTER_BILINEAR,
                "Bilinear",
                "Edit layers sampled bilinearly, in the live preview and the render alike (engine render --filter "
                "bilinear)",
                0,
            ),
            (
                P.FILTER_NEAREST,
                "Nearest",
                "Nearest texel, in the live preview and the render alike: blocky (engine render --filter nearest)",
                2,
            ),
        ],
        default=P.FILTER_DEFAULT,
        description="How the paint is read from the atlases, in the Live Preview and the render alike",
        update=_on_filter,
    )
    preview_proxy: EnumProperty(
        name="Preview Size",
        items=preview_proxy.items(),
        default=preview_proxy.AUTO,
        description="The Live Preview's size, as Blender's proxies: its plate and UV passes written at this size so a "
        "frame change loads less (painting and the render stay full size)",
        update=_on_preview_proxy,
    )
    render_dir: StringProperty(
        name="Output",
        subtype="DIR_PATH",
        default="//neural_atlas_render/",
        description="The folder Render Edited Clip writes the edited frames to",
        options=compat.PATH_OPTIONS,
    )
    write_mattes: BoolProperty(
        name="Write Mattes",
        default=True,
        description="Render Edited Clip also writes each layer's matte and the paint's coverage, float EXR, "
        "to <Output>/mattes/<Layer>/matte.#####.exr",
        update=_on_write_mattes,
    )
    render_format: EnumProperty(
        name="Format",
        items=[
            ("exr", "OpenEXR", "Float, linear"),
            ("png", "PNG", "8-bit sRGB"),
            ("movie", "Movie", "H.264 MP4"),
        ],
        default="exr",
        description="The file format of the edited frames",
    )
    # Render Edited Clip's progress (written by its operator, shown by the Paint & Render panel)
    render_progress: FloatProperty(
        default=0.0, min=0.0, max=1.0, subtype="FACTOR", description="How far Render Edited Clip has got"
    )
    render_status: StringProperty(default="", description="What Render Edited Clip last said")
    estimate_json: StringProperty(default="", description="The engine's time estimate per preset (JSON)")
    # live state of an engine job (written by the operators, shown by the panel)
    running: BoolProperty(default=False, description="Whether the engine is working for this scene")
    progress: FloatProperty(
        default=0.0, min=0.0, max=1.0, subtype="FACTOR", description="How far the engine's job has got"
    )
    status: StringProperty(default="", description="What the engine's job last said")
    fit_result: StringProperty(
        default="", description="What the last Fit Atlas, Refine or Carry Paint made (kept while other jobs run)"
    )
    log_path: StringProperty(default="", description="The log file of the engine's last job")
    can_resume: BoolProperty(default=False, description="Whether the Run Folder holds a stopped fit to resume")
    # what Submit to Farm last said (the Manager's job, the bundle folder, or why not)
    farm_status: StringProperty(default="", description="What Submit to Farm last said")


classes = (NEURALATLAS_PG_layer, NEURALATLAS_PG_scene)


def register_props() -> None:
    bpy.types.Scene.neural_atlas = PointerProperty(type=NEURALATLAS_PG_scene)


def unregister_props() -> None:
    del bpy.types.Scene.neural_atlas
