"""Operators: Fit Atlas (modal in the UI, blocking in background mode), Cancel, Import, Render, Paint."""

from __future__ import annotations

import json
import os
import shlex
from typing import Any

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, StringProperty

from ..engine import contract as C
from . import compositor, estimate, mask_math, masks, paint, preferences
from . import engine_process as EP
from . import engine_setup as ES
from . import tree_plan as P

#: running fits by scene name, so Cancel (another operator) can reach the modal operator's job
_SESSIONS: dict[str, FitSession] = {}


def is_running(scene: Any) -> bool:
    return scene.name in _SESSIONS


class UserError(Exception):
    """Something the artist can fix; the message says what."""


def _abs(path: str) -> str:
    return os.path.normpath(bpy.path.abspath(path)) if path else ""


def clip_plate(clip: Any) -> tuple[str, int | None]:
    """(what the engine reads: a sequence's folder or the movie file, the first file's number or None)."""
    path = _abs(clip.filepath)
    if clip.source == "SEQUENCE":
        return os.path.dirname(path), mask_math.file_number(path)
    return path, None


def clip_range(props: Any) -> tuple[int, int]:
    clip = props.clip
    if props.use_clip_range:
        return clip.frame_start, clip.frame_start + clip.frame_duration - 1
    first = max(props.frame_start, clip.frame_start)
    last = min(props.frame_end, clip.frame_start + clip.frame_duration - 1)
    if last < first:
        raise UserError(f"frames {props.frame_start}-{props.frame_end} are outside the clip")
    return first, last


def engine_inputs(props: Any, run_dir: str) -> tuple[str, list[str], list[str]]:
    """(plate, ["--mask", dir, ..., "--frames", "A:B"], ["--set", k=v, ...]); rasterizes Mask layers."""
    clip = props.clip
    if clip is None:
        raise UserError("choose the clip to fit")
    if not props.layers:
        raise UserError("add a foreground layer (a Mask or a folder of mask images)")
    plate, first_number = clip_plate(clip)
    first, last = clip_range(props)
    frames = list(range(first, last + 1))
    width, height = clip.size
    args = []
    names = mask_math.mask_file_names(frames, first_number, clip.frame_start)
    for i, layer in enumerate(props.layers, start=1):
        if layer.source == "MASK":
            if layer.mask is None:
                raise UserError(f"layer {i} has no Mask")
            folder = os.path.join(run_dir + ".masks", f"layer{i}")
            masks.rasterize(layer.mask, width, height, frames, folder, names)
        else:
            folder = _abs(layer.folder)
            if not os.path.isdir(folder):
                raise UserError(f"layer {i}: mask folder {folder!r} does not exist")
        args += ["--mask", folder]
    # the engine's --frames are positions in the sequence, not scene frames
    args += ["--frames", f"{first - clip.frame_start}:{last - clip.frame_start}"]
    sets = []
    for item in [f"long_edge={props.long_edge}", *shlex.split(props.overrides)]:
        sets += ["--set", item]
    return plate, args, sets


def _run_dir(props: Any) -> str:
    if not props.run_dir:
        raise UserError("choose a Run Folder")
    if props.run_dir.startswith("//") and not bpy.data.filepath:
        raise UserError("save the .blend file first (the Run Folder is relative to it), or choose an absolute one")
    return _abs(props.run_dir).rstrip(os.sep)


class FitSession:
    """One Fit Atlas run: masks -> ``engine fit`` -> ``engine export`` -> import. Driven by ``step()``."""

    def __init__(self, context: Any, resume: bool = False):
        scene = context.scene
        props = scene.neural_atlas
        self.scene_name = scene.name
        self.python = preferences.engine_python(context)
        if not self.python:
            raise UserError("no engine Python: run Set up engine in the add-on's preferences")
        self.run_dir = _run_dir(props)
        self.log_path = self.run_dir + ".blender.log"
        self.resume = resume
        if resume:
            if not os.path.exists(os.path.join(self.run_dir, C.RUN_CHECKPOINT)):
                raise UserError(f"nothing to resume in {self.run_dir}")
            self.fit_argv = ES.engine_argv(self.python, C.VERB_FIT, "--resume", "--out", self.run_dir, "--no-bar")
        else:
            self.fit_argv = self._fit_argv(context, props)
        self.export_argv = ES.engine_argv(self.python, C.VERB_EXPORT, self.run_dir)
        self.phase = "fit"
        self.job: EP.EngineJob | None = None
        self.result: EP.JobResult | None = None
        self.manifest: str | None = None

    def _fit_argv(self, context: Any, props: Any) -> list[str]:
        if os.path.exists(os.path.join(self.run_dir, C.RUN_CHECKPOINT)):
            raise UserError(f"{self.run_dir} already holds a fit: Resume it, or choose another Run Folder")
        plate, masks_and_frames, sets = engine_inputs(props, self.run_dir)
        args = [plate, *masks_and_frames, "--out", self.run_dir, "--preset", props.preset, *sets]
        return ES.engine_argv(self.python, C.VERB_FIT, *args, "--no-bar")

    # --- driving -------------------------------------------------------------------------------------------
    def start(self) -> None:
        os.makedirs(os.path.dirname(self.log_path) or ".", exist_ok=True)
        if os.path.exists(self.log_path) and not self.resume:
            os.remove(self.log_path)
        self.job = EP.EngineJob(self.fit_argv, self.log_path, env=ES.engine_env()).start()

    def step(self) -> bool:
        """Poll; move to the next phase when one ends. True while there is more to do."""
        assert self.job is not None
        self.job.poll()
        if not self.job.done():
            return True
        result = self.job.result()
        if self.phase == "fit" and result.status == EP.STATUS_OK:
            self.phase = "export"
            self.job = EP.EngineJob(self.export_argv, self.log_path, env=ES.engine_env()).start()
            return True
        if self.phase == "export" and result.status == EP.STATUS_OK:
            self.manifest = result.manifest
            if not self.manifest:
                result = EP.JobResult(EP.STATUS_FAILED, result.returncode, "export wrote no manifest", self.log_path)
        self.result = result
        self.phase = "done"
        return False

    def run_blocking(self, timeout: float | None = None, on_step: Any = None) -> EP.JobResult:
        import time

        self.start()
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.step():
            if on_step is not None:
                on_step()
            if deadline is not None and time.monotonic() > deadline:
                self.cancel()
                deadline = None
            time.sleep(0.1)
        assert self.result is not None
        return self.result

    def cancel(self) -> None:
        if self.job is not None:
            self.job.cancel()

    def status_text(self) -> str:
        if self.job is None:
            return "starting…"
        st = self.job.state
        if self.phase == "export":
            return f"exporting passes {st.step}/{st.total}" if st.total else "exporting passes…"
        return st.summary()


def _show(props: Any, session: FitSession) -> None:
    if session.job is not None:
        props.progress = session.job.state.fraction
    props.status = session.status_text()


def _redraw(context: Any) -> None:
    for window in context.window_manager.windows:
        for area in window.screen.areas:
            if area.type in ("CLIP_EDITOR", "PROPERTIES"):
                area.tag_redraw()


def import_manifest(
    context: Any, manifest_path: str, setup_paint: bool = True, edits: dict[str, str] | None = None
) -> P.TreePlan:
    """Read the manifest, build the compositor tree and the paint canvases (``edits``: layer -> other image)."""
    props = context.scene.neural_atlas
    manifest = C.load_manifest(manifest_path)
    plan = P.plan_tree(manifest, manifest_path, props.filter_type, edits)
    compositor.build(context.scene, plan)
    if setup_paint:
        paint.setup_canvases(context, plan.layers)
    props.manifest = manifest_path
    return plan


class NEURALATLAS_OT_fit(bpy.types.Operator):
    """Fit layered neural atlases to the clip with the engine, then import the result"""

    bl_idname = "neural_atlas.fit"
    bl_label = "Fit Atlas"

    resume: BoolProperty(name="Resume", default=False, options={"SKIP_SAVE"})
    timeout: FloatProperty(name="Timeout", default=0.0, options={"SKIP_SAVE", "HIDDEN"}, description="0: none")

    _timer = None
    _session: FitSession | None = None

    @classmethod
    def poll(cls, context):
        # the live session, not the saved flag: a .blend saved during a fit must not block the next one
        return context.scene is not None and not is_running(context.scene)

    def _prepare(self, context) -> FitSession | None:
        props = context.scene.neural_atlas
        try:
            return FitSession(context, resume=self.resume)
        except (UserError, RuntimeError) as exc:
            props.status = str(exc)
            self.report({"ERROR"}, str(exc))
            return None

    def _finish(self, context, session: FitSession) -> set[str]:
        props = context.scene.neural_atlas
        _SESSIONS.pop(session.scene_name, None)
        props.running = False
        props.log_path = session.log_path
        result = session.result
        assert result is not None
        props.can_resume = os.path.exists(os.path.join(session.run_dir, C.RUN_CHECKPOINT))
        if result.status == EP.STATUS_OK and session.manifest:
            try:
                import_manifest(context, session.manifest)
            except (C.ManifestError, P.PlanError, RuntimeError) as exc:
                props.status = f"import failed: {exc}"
                self.report({"ERROR"}, f"{props.status} (log: {session.log_path})")
                return {"CANCELLED"}
            props.progress = 1.0
            props.status = "done: the atlas is in the compositor"
            props.can_resume = False
            self.report({"INFO"}, f"Fit Atlas done; imported {session.manifest}")
            return {"FINISHED"}
        props.status = result.message
        level = "WARNING" if result.status == EP.STATUS_CANCELLED else "ERROR"
        self.report({level}, f"Fit Atlas {result.status}: {result.message} (log: {session.log_path})")
        return {"CANCELLED"}

    def execute(self, context):
        session = self._prepare(context)
        if session is None:
            return {"CANCELLED"}
        props = context.scene.neural_atlas
        props.running = True
        _SESSIONS[session.scene_name] = session
        try:
            session.run_blocking(timeout=self.timeout or None, on_step=lambda: _show(props, session))
        finally:
            props.running = False
        return self._finish(context, session)

    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)  # no event loop: the blocking path (what the tests call)
        session = self._prepare(context)
        if session is None:
            return {"CANCELLED"}
        session.start()
        self._session = session
        _SESSIONS[session.scene_name] = session
        context.scene.neural_atlas.running = True
        self._timer = context.window_manager.event_timer_add(0.1, window=context.window)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        session = self._session
        if event.type == "ESC":
            session.cancel()
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        more = session.step()
        _show(context.scene.neural_atlas, session)
        _redraw(context)
        if more:
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self._timer)
        return self._finish(context, session)


class NEURALATLAS_OT_estimate(bpy.types.Operator):
    """Time a few steps of every preset on this clip with the engine (replaces the documented estimate)"""

    bl_idname = "neural_atlas.estimate"
    bl_label = "Estimate Time"

    def execute(self, context):
        props = context.scene.neural_atlas
        try:
            python = preferences.engine_python(context)
            if not python:
                raise UserError("no engine Python: run Set up engine in the add-on's preferences")
            run_dir = _run_dir(props)
            plate, masks_and_frames, sets = engine_inputs(props, run_dir)
        except (UserError, RuntimeError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        argv = ES.engine_argv(python, C.VERB_ESTIMATE, plate, *masks_and_frames, *sets, "--json")
        log = run_dir + ".estimate.log"
        job = EP.EngineJob(argv, log, env=ES.engine_env()).start()
        context.window_manager.progress_begin(0, 1)
        try:
            result = job.wait(timeout=1800)
        finally:
            context.window_manager.progress_end()
        with open(log, encoding="utf-8", errors="replace") as f:
            rows = estimate.parse_engine_estimate(f.read(), C.ESTIMATE_TAG)
        if result.status != EP.STATUS_OK or not rows:
            self.report({"ERROR"}, f"estimate failed: {result.message} (log: {log})")
            return {"CANCELLED"}
        props.estimate_json = json.dumps(rows)
        self.report({"INFO"}, estimate.estimate_text(props.preset, rows, 0.0))
        return {"FINISHED"}


class NEURALATLAS_OT_cancel(bpy.types.Operator):
    """Stop the fit; the engine writes a checkpoint that Resume continues from"""

    bl_idname = "neural_atlas.cancel"
    bl_label = "Cancel"

    def execute(self, context):
        session = _SESSIONS.get(context.scene.name)
        if session is None:
            context.scene.neural_atlas.running = False
            return {"CANCELLED"}
        session.cancel()
        context.scene.neural_atlas.status = "cancelling: writing a checkpoint…"
        return {"FINISHED"}


class NEURALATLAS_OT_import(bpy.types.Operator):
    """Import an exported run (manifest.json): compositor tree, edit layers and paint canvases"""

    bl_idname = "neural_atlas.import_run"
    bl_label = "Import Atlas"

    filepath: StringProperty(subtype="FILE_PATH")
    filter_glob: StringProperty(default="manifest.json", options={"HIDDEN"})
    setup_paint: BoolProperty(name="Paint Canvases", default=True)

    def execute(self, context):
        path = _abs(self.filepath)
        try:
            plan = import_manifest(context, path, self.setup_paint)
        except (C.ManifestError, P.PlanError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"imported {len(plan.layers)} layers, frames {plan.frame_start}-{plan.frame_end}")
        return {"FINISHED"}

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}


class NEURALATLAS_OT_float_edits(bpy.types.Operator):
    """Paint in float: each layer's edit becomes a linear, premultiplied EXR beside its PNG (the engine uses it too)"""

    bl_idname = "neural_atlas.float_edits"
    bl_label = "Float Edit Layers"

    def execute(self, context):
        props = context.scene.neural_atlas
        if not props.manifest:
            self.report({"ERROR"}, "import an atlas first")
            return {"CANCELLED"}
        made, skipped = [], []
        try:
            manifest = C.load_manifest(props.manifest)
            for layer in manifest["layers"]:
                img = bpy.data.images.get(P.edit_image_name(layer["name"]))
                if img is None or _abs(img.filepath).lower().endswith(C.EDIT_LAYER_FLOAT_EXT):
                    continue  # not imported, or already float
                if _abs(img.filepath) != os.path.normpath(P.resolve(props.manifest, layer["edit_layer"])):
                    skipped.append(layer["name"])  # another image was given for this layer: not the run's edit
                    continue
                made.append(paint.make_float_edit(layer["name"]))
            keep = {name: _abs(bpy.data.images[P.edit_image_name(name)].filepath) for name in skipped}
            import_manifest(context, props.manifest, True, keep)  # the tree and canvases now use the EXRs
        except (ValueError, OSError) as exc:  # ManifestError, PlanError, an existing EXR, a full disk
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        msg = f"{len(made)} float edit layer(s): " + (", ".join(os.path.basename(p) for p in made) or "none")
        if skipped:
            msg += f"; not converted (they use another image than the run's edit layer): {', '.join(skipped)}"
        self.report({"INFO"}, msg)
        return {"FINISHED"}


class NEURALATLAS_OT_save_edits(bpy.types.Operator):
    """Save the painted edit layers to their files in the run folder (PNG or float EXR, as each layer is)"""

    bl_idname = "neural_atlas.save_edits"
    bl_label = "Save Edits"

    def execute(self, context):
        saved = paint.save_edits()
        self.report({"INFO"}, f"saved {len(saved)} edit layer(s)")
        return {"FINISHED"}


class NEURALATLAS_OT_paint_setup(bpy.types.Operator):
    """A canvas per layer: the edit layer as the active paint slot over the atlas"""

    bl_idname = "neural_atlas.paint_setup"
    bl_label = "Paint Canvases"

    def execute(self, context):
        prefix = P.PREFIX + "Edit_"
        layers = [img.name.removeprefix(prefix) for img in bpy.data.images if img.name.startswith(prefix)]
        objs = paint.setup_canvases(context, layers)
        self.report({"INFO"}, f"{len(objs)} canvas(es): select one and switch to Texture Paint")
        return {"FINISHED"}


class NEURALATLAS_OT_render(bpy.types.Operator):
    """Render the edited clip from the compositor"""

    bl_idname = "neural_atlas.render"
    bl_label = "Render Edited Clip"

    directory: StringProperty(subtype="DIR_PATH", options={"SKIP_SAVE"})
    file_format: EnumProperty(
        items=[("", "Scene setting", ""), ("exr", "EXR", ""), ("png", "PNG", ""), ("movie", "Movie", "")],
        default="",
        options={"SKIP_SAVE"},
    )

    def execute(self, context):
        props = context.scene.neural_atlas
        out = _abs(self.directory or props.render_dir)
        fmt = self.file_format or props.render_format
        if not props.manifest:
            self.report({"ERROR"}, "import an atlas first")
            return {"CANCELLED"}
        paint.save_edits()
        try:
            files = compositor.render(context.scene, out, fmt)
        except RuntimeError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"rendered {len(files)} file(s) to {out}")
        return {"FINISHED"}


class NEURALATLAS_OT_layer_add(bpy.types.Operator):
    """Add a foreground layer"""

    bl_idname = "neural_atlas.layer_add"
    bl_label = "Add Layer"

    def execute(self, context):
        props = context.scene.neural_atlas
        props.layers.add()
        props.layer_index = len(props.layers) - 1
        return {"FINISHED"}


class NEURALATLAS_OT_layer_remove(bpy.types.Operator):
    """Remove the selected foreground layer"""

    bl_idname = "neural_atlas.layer_remove"
    bl_label = "Remove Layer"

    def execute(self, context):
        props = context.scene.neural_atlas
        if props.layers:
            props.layers.remove(props.layer_index)
            props.layer_index = max(0, min(props.layer_index, len(props.layers) - 1))
        return {"FINISHED"}


classes = (
    NEURALATLAS_OT_fit,
    NEURALATLAS_OT_estimate,
    NEURALATLAS_OT_cancel,
    NEURALATLAS_OT_import,
    NEURALATLAS_OT_float_edits,
    NEURALATLAS_OT_save_edits,
    NEURALATLAS_OT_paint_setup,
    NEURALATLAS_OT_render,
    NEURALATLAS_OT_layer_add,
    NEURALATLAS_OT_layer_remove,
)
