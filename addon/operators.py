"""Operators: Fit Atlas and Find Masks (modal in the UI, blocking in background mode), Cancel, Import, Render,
Paint."""

from __future__ import annotations

import json
import os
import shlex
from typing import Any

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from ..engine import contract as C
from . import compositor, estimate, mask_math, masks, paint, preferences, scribbles
from . import engine_process as EP
from . import engine_setup as ES
from . import tree_plan as P

#: running engine sessions (a fit or a mask search) by scene name, so Cancel (another operator) can reach the
#: modal operator's job, and a second one cannot start in the same scene
_SESSIONS: dict[str, EngineSession] = {}
#: The Find Masks output, inside the Run Folder (a numbered sibling when it already holds masks).
AUTO_MASKS_DIR = "auto_masks"
#: The Movie Clip the found masks are loaded as, for checking (Blender numbers repeats: NA_AutoMasks.001).
AUTO_MASKS_CLIP = f"{P.PREFIX}AutoMasks"


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


def scribble_dir(run_dir: str) -> str:
    """Where Fit Atlas rasterizes the clip's scribbles (beside the Run Folder, like the rasterized masks)."""
    return run_dir + ".scribbles"


def scribble_args(clip: Any, run_dir: str, frames: list[int], first_number: int | None) -> list[str]:
    """Rasterize the clip's code-coloured annotation strokes on ``frames``; [SCRIBBLE_ARG, folder]."""
    colours = ", ".join(f"part {i + 1} in {name}" for i, (name, _) in enumerate(scribbles.legend()[:2]))
    labels = scribbles.scribble_labels(scribbles.clip_annotation(clip), frames)
    if not labels:
        raise UserError(
            f"Split with Scribbles: clip {clip.name!r} has no annotation strokes in the scribble colours on "
            f"frames {frames[0]}-{frames[-1]}: with the Annotate tool draw {colours}"
        )
    if max(labels) < 1:
        raise UserError("Split with Scribbles: only red strokes, so nothing is split: scribble the other part in green")
    folder = scribble_dir(run_dir)
    scribbles.clear_scribbles(folder)
    offset = first_number or 0  # a movie's frames are numbered from 0, a sequence's by its files

    def name(frame: int) -> str:
        return C.SCRIBBLE_FILE_FORMAT.format(offset + frame - clip.frame_start)

    width, height = clip.size
    scribbles.write_scribbles(clip, folder, width, height, name, frames)
    return [C.SCRIBBLE_ARG, folder]


def engine_inputs(props: Any, run_dir: str, with_scribbles: bool = True) -> tuple[str, list[str], list[str]]:
    """(plate, ["--mask", dir, ..., "--frames", "A:B"(, "--scribbles", dir)], ["--set", k=v, ...]); rasterizes
    Mask layers (and, with ``props.use_scribbles``, the clip's scribbles)."""
    clip = props.clip
    if clip is None:
        raise UserError("choose the clip to fit")
    if not props.layers:
        raise UserError("add a foreground layer (a Mask or a folder of mask images)")
    scribbled = with_scribbles and props.use_scribbles
    if scribbled and len(props.layers) != 1:
        raise UserError(
            f"Split with Scribbles splits one object: keep exactly one foreground layer (the whole object's mask), "
            f"not {len(props.layers)}, or turn Split with Scribbles off"
        )
    plate, first_number = clip_plate(clip)
    first, last = clip_range(props)
    frames = list(range(first, last + 1))
    width, height = clip.size
    args = []
    scribble = scribble_args(clip, run_dir, frames, first_number) if scribbled else []
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
    args += ["--frames", f"{first - clip.frame_start}:{last - clip.frame_start}", *scribble]
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


class EngineSession:
    """What the modal operators drive: ``start()``, then ``step()`` until False, then ``result``."""

    scene_name: str
    log_path: str
    job: EP.EngineJob | None = None
    result: EP.JobResult | None = None

    def start(self) -> None:
        raise NotImplementedError

    def step(self) -> bool:
        raise NotImplementedError

    def status_text(self) -> str:
        raise NotImplementedError

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


class FitSession(EngineSession):
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

    def status_text(self) -> str:
        if self.job is None:
            return "starting…"
        st = self.job.state
        if self.phase == "export":
            return f"exporting passes {st.step}/{st.total}" if st.total else "exporting passes…"
        return st.summary()


def _fresh_dir(base: str) -> str:
    """``base``, else ``base_2``, ``base_3``...: the first that is missing or empty (masks are never overwritten,
    an artist may have fixed the last ones)."""
    candidate, n = base, 1
    while os.path.exists(candidate) and (not os.path.isdir(candidate) or os.listdir(candidate)):
        n += 1
        candidate = f"{base}_{n}"
    return candidate


def masks_result(log_path: str) -> tuple[bool | None, str]:
    """What a mask search found, from the engine's ``masks`` event (contract.EVENT_MASKS) in the log: (found,
    message); (None, "") when the log has none (the engine failed before it finished)."""
    found: bool | None = None
    message = ""
    try:
        with open(log_path, encoding="utf-8", errors="replace") as f:
            for ln in f:
                msg = C.parse_progress_line(ln)
                if msg is not None and msg.get("event") == C.EVENT_MASKS:
                    found, message = bool(msg.get("found")), str(msg.get("message", ""))
    except OSError:
        pass
    return found, message


class MasksSession(EngineSession):
    """Find Masks: ``engine masks CLIP --out RUN/auto_masks --frames A:B``; the operator then adds a layer."""

    def __init__(self, context: Any):
        scene = context.scene
        props = scene.neural_atlas
        self.scene_name = scene.name
        python = preferences.engine_python(context)
        if not python:
            raise UserError("no engine Python: run Set up engine in the add-on's preferences")
        clip = props.clip
        if clip is None:
            raise UserError("choose the clip to find masks in")
        run_dir = _run_dir(props)
        plate, _ = clip_plate(clip)
        first, last = clip_range(props)
        if last <= first:
            raise UserError("Find Masks needs at least two frames: the foreground is found by what moves")
        self.out_dir = _fresh_dir(os.path.join(run_dir, AUTO_MASKS_DIR))
        self.created = not os.path.exists(self.out_dir)
        self.log_path = run_dir + ".masks.log"
        frames = f"{first - clip.frame_start}:{last - clip.frame_start}"
        self.argv = ES.engine_argv(python, C.VERB_MASKS, plate, "--out", self.out_dir, "--frames", frames)
        self.summary = ""
        self.found: bool | None = None
        self.job = None
        self.result = None

    def start(self) -> None:
        os.makedirs(os.path.dirname(self.log_path) or ".", exist_ok=True)
        if os.path.exists(self.log_path):
            os.remove(self.log_path)  # the add-on's own log of the previous search
        self.job = EP.EngineJob(self.argv, self.log_path, env=ES.engine_env()).start()

    def step(self) -> bool:
        assert self.job is not None
        self.job.poll()
        if not self.job.done():
            return True
        self.result = self.job.result()
        self.found, self.summary = masks_result(self.log_path)
        return False

    def mask_files(self) -> list[str]:
        if not os.path.isdir(self.out_dir):
            return []
        return sorted(os.path.join(self.out_dir, n) for n in os.listdir(self.out_dir) if n.lower().endswith(".png"))

    def discard(self) -> None:
        """Remove the (empty) masks this search wrote into its fresh folder, and the folder if it made it."""
        for path in self.mask_files():
            os.remove(path)
        if self.created and os.path.isdir(self.out_dir) and not os.listdir(self.out_dir):
            os.rmdir(self.out_dir)

    def status_text(self) -> str:
        if self.job is None:
            return "starting…"
        return self.job.state.message or "finding what moves…"


def _show(props: Any, session: EngineSession) -> None:
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
    props.imported_layers = ", ".join(plan.layers)
    return plan


class _EngineOperator:
    """Blocking ``execute`` (background mode, scripts, tests), modal ``invoke`` polled by a 0.1 s timer (the UI;
    ESC or the Cancel button stops the engine). Subclasses make the session and finish it."""

    timeout: float
    _timer = None
    _session: EngineSession | None = None

    @classmethod
    def poll(cls, context):
        # the live session, not the saved flag: a .blend saved during a fit must not block the next one
        return context.scene is not None and not is_running(context.scene)

    def _make_session(self, context) -> EngineSession:
        raise NotImplementedError

    def _finish(self, context, session: EngineSession) -> set[str]:
        raise NotImplementedError

    def _prepare(self, context) -> EngineSession | None:
        props = context.scene.neural_atlas
        try:
            return self._make_session(context)
        except (UserError, RuntimeError, OSError) as exc:
            props.status = str(exc)
            self.report({"ERROR"}, str(exc))
            return None

    def _end(self, context, session: EngineSession) -> EP.JobResult:
        props = context.scene.neural_atlas
        _SESSIONS.pop(session.scene_name, None)
        props.running = False
        props.log_path = session.log_path
        assert session.result is not None
        return session.result

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


class NEURALATLAS_OT_fit(_EngineOperator, bpy.types.Operator):
    """Fit layered neural atlases to the clip with the engine, then import the result"""

    bl_idname = "neural_atlas.fit"
    bl_label = "Fit Atlas"

    resume: BoolProperty(name="Resume", default=False, options={"SKIP_SAVE"})
    timeout: FloatProperty(name="Timeout", default=0.0, options={"SKIP_SAVE", "HIDDEN"}, description="0: none")

    def _make_session(self, context) -> EngineSession:
        return FitSession(context, resume=self.resume)

    def _finish(self, context, session: FitSession) -> set[str]:
        props = context.scene.neural_atlas
        result = _EngineOperator._end(self, context, session)
        props.can_resume = os.path.exists(os.path.join(session.run_dir, C.RUN_CHECKPOINT))
        if result.status == EP.STATUS_OK and session.manifest:
            try:
                plan = import_manifest(context, session.manifest)
            except (C.ManifestError, P.PlanError, RuntimeError) as exc:
                props.status = f"import failed: {exc}"
                self.report({"ERROR"}, f"{props.status} (log: {session.log_path})")
                return {"CANCELLED"}
            props.progress = 1.0
            props.status = f"done: {len(plan.layers)} layers in the compositor ({', '.join(plan.layers)})"
            props.can_resume = False
            self.report({"INFO"}, f"Fit Atlas done; imported {session.manifest}")
            return {"FINISHED"}
        props.status = result.message
        level = "WARNING" if result.status == EP.STATUS_CANCELLED else "ERROR"
        self.report({level}, f"Fit Atlas {result.status}: {result.message} (log: {session.log_path})")
        return {"CANCELLED"}


class NEURALATLAS_OT_find_masks(_EngineOperator, bpy.types.Operator):
    """Find the moving object's masks from motion with the engine and add them as a foreground layer to check
    (and fix) before fitting"""

    bl_idname = "neural_atlas.find_masks"
    bl_label = "Find Masks"

    timeout: FloatProperty(name="Timeout", default=0.0, options={"SKIP_SAVE", "HIDDEN"}, description="0: none")

    def _make_session(self, context) -> EngineSession:
        return MasksSession(context)

    def _finish(self, context, session: MasksSession) -> set[str]:
        props = context.scene.neural_atlas
        result = _EngineOperator._end(self, context, session)
        if result.status == EP.STATUS_CANCELLED:
            session.discard()  # nothing to resume: a search starts over
            props.status = "Find Masks: cancelled. The layers are unchanged"
            self.report({"WARNING"}, f"{props.status} (log: {session.log_path})")
            return {"CANCELLED"}
        if result.status != EP.STATUS_OK:
            props.status = f"Find Masks: {result.message}"
            self.report({"ERROR"}, f"Find Masks {result.status}: {result.message} (log: {session.log_path})")
            return {"CANCELLED"}
        files = session.mask_files()
        if not files:
            props.status = f"Find Masks: the engine wrote no masks to {session.out_dir}"
            self.report({"ERROR"}, f"{props.status} (log: {session.log_path})")
            return {"CANCELLED"}
        summary = session.summary or f"{len(files)} masks"
        if session.found is False:
            session.discard()
            props.status = f"Find Masks: {summary}. The layers are unchanged"
            self.report({"WARNING"}, f"{props.status} (log: {session.log_path})")
            return {"CANCELLED"}
        layer = props.layers.add()
        layer.source = "FOLDER"
        layer.folder = session.out_dir
        props.layer_index = len(props.layers) - 1
        # the masks as a clip of their own, to scrub through in the clip editor (the plate stays the fitted clip)
        check = bpy.data.movieclips.load(files[0], check_existing=False)
        check.name = AUTO_MASKS_CLIP
        check.colorspace_settings.name = "Non-Color"
        props.progress = 1.0
        props.status = f"Find Masks: {summary}; check them (clip {check.name}) before fitting"
        self.report({"INFO"}, f"Find Masks: {summary} -> foreground layer {len(props.layers)} ({session.out_dir})")
        return {"FINISHED"}


class NEURALATLAS_OT_scribble_layers(bpy.types.Operator):
    """Add annotation layers in the scribble colours to the clip (part 1 red, part 2 green, ...); draw on them
    with the Annotate tool"""

    bl_idname = "neural_atlas.scribble_layers"
    bl_label = "Add Scribble Layers"

    parts: IntProperty(name="Parts", default=2, min=2, max=len(C.SCRIBBLE_COLOURS))

    def execute(self, context):
        props = context.scene.neural_atlas
        if props.clip is None:
            self.report({"ERROR"}, "choose the clip to scribble on")
            return {"CANCELLED"}
        data = bpy.data.annotations if hasattr(bpy.data, "annotations") else bpy.data.grease_pencils
        names = scribbles.ensure_scribble_layers(props.clip, self.parts, data.new)
        self.report({"INFO"}, f"scribble layers: {', '.join(names)}; draw on each with the Annotate tool")
        return {"FINISHED"}


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
            plate, masks_and_frames, sets = engine_inputs(props, run_dir, with_scribbles=False)
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
    NEURALATLAS_OT_find_masks,
    NEURALATLAS_OT_scribble_layers,
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
