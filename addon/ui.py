"""The add-on's "Fit Atlas" sidebar tab: Fit Atlas and Paint & Render in the Movie Clip Editor, and Paint & Render
(the same panel, one class per editor) in the 3D viewport and the Image Editor, where the painting happens."""

from __future__ import annotations

import json

import bpy

from . import compositor, edit_layers, preferences, preview_plane, scribbles
from .core import estimate, needs, running
from .core import farm as FM
from .core import preview_plan as V
from .core import scribble_math as S
from .core.errors import UserError
from .ops import refine
from .ops.render import active_render, passes_file, plate_file

#: Theme colour-set icons that show the scribble colours in the panel (default theme: red, green, blue, yellow).
COLOUR_ICONS = {
    "red": "COLORSET_01_VEC",
    "green": "COLORSET_03_VEC",
    "blue": "COLORSET_04_VEC",
    "yellow": "COLORSET_09_VEC",
}
#: The Fit Atlas panel's line while Submit to Farm may not reach the Flamenco Manager.
FARM_OFFLINE_TEXT = "Online access is off: Flamenco needs it (Preferences > System > Network)"
#: How many scribbled frames the panel lists.
FRAMES_SHOWN = 8


class NEURALATLAS_UL_layers(bpy.types.UIList):
    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0):
        row = layout.row(align=True)
        one = len(data.layers) == 1
        split = "split by scribbles" if data.use_scribbles else "parts from motion" if data.find_parts else None
        row.label(text=f"Object ({split})" if one and split else f"Foreground {index + 1}")
        row.prop(item, "source", text="")
        row.prop(item, "mask" if item.source == "MASK" else "folder", text="")


def _estimate_text(props) -> str:
    clip = props.clip
    if clip is None:
        return ""
    frames = clip.frame_duration if props.use_clip_range else max(1, props.frame_end - props.frame_start + 1)
    try:  # the --set items the fit gets: Fit Resolution, then the overrides (the last one given wins)
        items = FM.set_items(props.long_edge, props.overrides)
    except UserError:  # an unclosed quote: Fit Atlas says so; the estimate is the preset's
        items = ()
    long_edge = estimate.overridden_int(items, "long_edge") or props.long_edge
    seconds = estimate.estimate_seconds(
        props.preset, frames, clip.size[0], clip.size[1], long_edge, estimate.overridden_int(items, "steps")
    )
    try:
        engine_rows = json.loads(props.estimate_json) if props.estimate_json else {}
    except ValueError:
        engine_rows = {}
    return estimate.estimate_text(props.preset, engine_rows, seconds)


def _draw_scribbles(box, props) -> None:
    """Which colour means what (from the engine's colour code), and what the clip holds so far."""
    box.label(text="Annotate tool, one annotation layer per colour:", icon="GREASEPENCIL")
    for colour, meaning in S.legend():
        box.label(text=f"{colour.title()}: {meaning}", icon=COLOUR_ICONS.get(colour, "NONE"))
    box.operator("neural_atlas.scribble_layers", icon="ADD")
    box.label(text="Stroke each part on about one frame in six")
    if len(props.layers) != 1:
        box.label(text="Keep exactly one foreground layer: the whole object", icon="ERROR")
    annotation = scribbles.clip_annotation(props.clip) if props.clip is not None else None
    frames = scribbles.scribbled_frames(annotation)
    if not frames:
        box.label(text="No strokes in these colours yet", icon="INFO")
        return
    names = [c for k, (c, _) in enumerate(S.legend()) if k in scribbles.scribble_labels(annotation)]
    shown = ", ".join(str(f) for f in frames[:FRAMES_SHOWN]) + (" …" if len(frames) > FRAMES_SHOWN else "")
    box.label(text=f"{', '.join(names)} on frame(s) {shown}", icon="CHECKMARK" if len(names) > 1 else "ERROR")


def _draw_farm(col, props, context) -> None:
    """Submit to Farm and its one status line (what the farm got, or why it cannot be sent now)."""
    settings = preferences.farm_settings(context)
    where = "Flamenco" if settings.kind == FM.FARM_FLAMENCO else "OpenJD bundle"
    col.operator("neural_atlas.submit_farm", text=f"Submit to Farm ({where})", icon="NETWORK_DRIVE")
    refusal = preferences.farm_refusal(context)
    if refusal:
        col.label(text=FARM_OFFLINE_TEXT, icon="INTERNET_OFFLINE")
    elif props.farm_status:
        col.label(text=props.farm_status)


def _moved_line(context) -> str | None:
    """The line saying the imported manifest, passes or plate are not on disk (``needs.moved_need``): Relink."""
    return needs.moved_need(compositor.imported_manifest(context.scene), passes_file(), plate_file=plate_file())


class _SidebarPanel:
    """The add-on's tab in the Movie Clip Editor's sidebar."""

    bl_space_type = "CLIP_EDITOR"
    bl_region_type = "UI"
    bl_category = "Neural Atlas"  # the add-on's tab in every editor: it holds Fit Atlas and Paint & Render


class NEURALATLAS_PT_fit(_SidebarPanel, bpy.types.Panel):
    bl_idname = "NEURALATLAS_PT_fit"
    bl_label = "Fit Atlas"

    def draw(self, context):
        props = context.scene.neural_atlas
        if not preferences.engine_python(context):
            self.layout.label(text="Set up the engine in the preferences", icon="ERROR")
            if preferences.online_refusal():  # Set up engine cannot download: the way that needs no network
                self.layout.label(text="Online access is off: set Engine Python there", icon="INTERNET_OFFLINE")
        col = self.layout.column()
        col.prop(props, "clip")
        col.prop(props, "use_clip_range")
        if not props.use_clip_range:
            row = col.row(align=True)
            row.prop(props, "frame_start")
            row.prop(props, "frame_end")
        col.prop(props, "long_edge")
        col.prop(props, "preset")
        col.prop(props, "overrides")
        col.prop(props, "follow_flow")
        text = _estimate_text(props)
        if text:
            row = col.row()
            row.label(text=text, icon="TIME")
            row.operator("neural_atlas.estimate", text="", icon="FILE_REFRESH")
        col.label(text="Foreground layers")
        row = col.row()
        row.template_list("NEURALATLAS_UL_layers", "", props, "layers", props, "layer_index", rows=2)
        sub = row.column(align=True)
        sub.operator("neural_atlas.layer_add", icon="ADD", text="")
        sub.operator("neural_atlas.layer_remove", icon="REMOVE", text="")
        col.operator("neural_atlas.find_masks", icon="VIEWZOOM")
        row = col.row(align=True)
        row.prop(props, "use_scribbles")
        sub = row.row(align=True)
        sub.active = len(props.layers) == 1 and not props.use_scribbles  # where the engine may split the object
        sub.prop(props, "find_parts")
        if props.use_scribbles:
            _draw_scribbles(col.box(), props)
        col.prop(props, "run_dir")
        if running.is_running(context.scene.name):
            col.progress(factor=props.progress, type="BAR", text=props.status or "running…")
            col.operator("neural_atlas.cancel", icon="CANCEL")
        else:
            row = col.row(align=True)
            used = refine.holds_fit(props)  # a fit there: greyed with the reason, not a button that refuses
            sub = row.row(align=True)
            sub.enabled = not used
            sub.operator("neural_atlas.fit", icon="PLAY")
            if used:
                col.label(text=needs.USED_RUN_FOLDER, icon="INFO")
            if props.can_resume:
                row.operator("neural_atlas.fit", text="Resume", icon="RECOVER_LAST").resume = True
            if refine.finished_fit(props):  # the Run Folder holds a finished fit: continue it, keep the paint
                box = col.box()
                box.label(text="Refine this fit, keep the paint")
                box.row(align=True).prop(props, "refine_steps")
                box.prop(props, "refine_preset")
                box.operator("neural_atlas.refine", icon="FILE_REFRESH")
            if props.status:
                col.label(text=props.status)
            if props.fit_result and props.fit_result != props.status:  # the last fit's outcome, kept in view
                col.label(text=props.fit_result, icon="CHECKMARK")
            if props.log_path:
                col.label(text=f"log: {props.log_path}")
        _draw_farm(col, props, context)


def _draw_layers(col, props, context) -> None:
    """One button per imported layer (Paint Layer), the one being painted here pressed."""
    layers = [name.strip() for name in props.imported_layers.split(",") if name.strip()]
    if not layers:
        return
    painted = edit_layers.painted_layer(context)
    row = col.row(align=True)
    row.label(text="Paint", icon="RENDERLAYERS")
    for layer in layers:
        row.operator("neural_atlas.paint_layer", text=layer, depress=layer == painted).layer = layer


def draw_paint_render(layout, context) -> None:
    """Paint & Render, in every editor that has it (Movie Clip Editor, 3D viewport, Image Editor): the import, the
    layer to paint, Save Edits, Live Preview, Paint on Frame / Land Paint, the filter and Render Edited Clip."""
    props = context.scene.neural_atlas
    col = layout.column()
    col.operator("neural_atlas.import_run", icon="IMPORT")
    if props.manifest:
        col.label(text=props.manifest)
        moved = _moved_line(context)
        if moved:
            col.label(text=moved, icon="ERROR")
        col.operator("neural_atlas.relink", icon="FILE_REFRESH")
    _draw_layers(col, props, context)
    row = col.row(align=True)
    row.operator("neural_atlas.paint_setup", icon="BRUSH_DATA")
    row.operator("neural_atlas.save_edits", icon="FILE_TICK")
    col.operator("neural_atlas.float_edits", icon="IMAGE_DATA")
    shown = preview_plane.is_shown(context.scene)  # a toggle: pressed while the preview is on screen
    col.operator("neural_atlas.live_preview", icon="HIDE_OFF" if shown else "HIDE_ON", depress=shown)
    col.prop(props, "preview_proxy")  # the preview's size (Blender's proxy sizes); the render stays full size
    built = preview_plane.shown_size() if shown else None
    if built is not None:
        col.label(text=V.size_line(*built))
    outside = V.outside_export(context.scene.frame_current, preview_plane.export_frames()) if shown else None
    if outside:
        col.label(text=outside, icon="INFO")
    row = col.row(align=True)  # another fit's paint, laid on this one's atlases (engine realign --from)
    row.prop(props, "carry_from")
    row.operator("neural_atlas.carry_paint", icon="PASTEDOWN")
    row = col.row(align=True)  # paint over one plate frame, landed on the atlases (engine project-frame)
    row.operator("neural_atlas.frame_paint_start", icon="TPAINT_HLT")
    row.operator("neural_atlas.frame_paint_land", icon="IMPORT")
    col.prop(props, "filter_type")  # how the edit layers are sampled, in the preview and the render alike
    if running.is_running(context.scene.name):
        col.progress(factor=props.progress, type="BAR", text=props.status or "running…")
        col.operator("neural_atlas.cancel", icon="CANCEL")
    col.prop(props, "render_dir")
    col.prop(props, "render_format")
    col.prop(props, "write_mattes")
    if active_render(context.scene) is not None:
        col.progress(factor=props.render_progress, type="BAR", text=props.render_status or "rendering…")
        col.operator("neural_atlas.render_cancel", icon="CANCEL")
    else:
        col.operator("neural_atlas.render", icon="RENDER_ANIMATION")
        if props.render_status:
            col.label(text=props.render_status)


class NEURALATLAS_PT_edit(_SidebarPanel, bpy.types.Panel):
    bl_idname = "NEURALATLAS_PT_edit"
    bl_label = "Paint & Render"

    def draw(self, context):
        draw_paint_render(self.layout, context)


class NEURALATLAS_PT_edit_view3d(bpy.types.Panel):
    """Paint & Render where Texture Paint paints the canvases and the live preview shows: the 3D viewport."""

    bl_idname = "NEURALATLAS_PT_edit_view3d"
    bl_label = "Paint & Render"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = _SidebarPanel.bl_category

    def draw(self, context):
        draw_paint_render(self.layout, context)


class NEURALATLAS_PT_edit_image(bpy.types.Panel):
    """Paint & Render where an edit layer or the frame paint is painted flat: the Image Editor."""

    bl_idname = "NEURALATLAS_PT_edit_image"
    bl_label = "Paint & Render"
    bl_space_type = "IMAGE_EDITOR"
    bl_region_type = "UI"
    bl_category = _SidebarPanel.bl_category

    def draw(self, context):
        draw_paint_render(self.layout, context)


#: The Paint & Render panel of each editor the artist paints or looks in.
PAINT_PANELS = (NEURALATLAS_PT_edit, NEURALATLAS_PT_edit_view3d, NEURALATLAS_PT_edit_image)


classes = (NEURALATLAS_UL_layers, NEURALATLAS_PT_fit, *PAINT_PANELS)
