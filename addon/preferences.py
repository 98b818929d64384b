"""Preferences: the engine's interpreter, and the operators that set it up and check it."""

from __future__ import annotations

import os
import sys

import bpy
from bpy.props import BoolProperty, StringProperty

from . import engine_process as EP
from . import engine_setup as ES

#: the add-on's module name (``bl_ext.<repo>.neural_atlas`` when installed): preferences are keyed by it
ADDON_ID = __package__.rpartition(".")[0]
#: overrides the preference (CI, pipelines): the Python that runs ``python -m engine``
ENGINE_PYTHON_ENV = "NEURAL_ATLAS_ENGINE_PYTHON"
SETUP_TIMEOUT_SECONDS = 3600


def addon_prefs(context=None):
    context = context or bpy.context
    addon = context.preferences.addons.get(ADDON_ID)
    return addon.preferences if addon is not None else None


def engine_python(context=None) -> str:
    """The engine interpreter: the environment override, else the preference; '' if neither is set."""
    if os.environ.get(ENGINE_PYTHON_ENV):
        return os.environ[ENGINE_PYTHON_ENV]
    prefs = addon_prefs(context)
    return bpy.path.abspath(prefs.engine_python) if prefs is not None and prefs.engine_python else ""


def default_venv_dir() -> str:
    return bpy.utils.extension_path_user(ADDON_ID, path="engine_venv", create=True)


class NEURALATLAS_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_ID

    engine_python: StringProperty(
        name="Engine Python",
        subtype="FILE_PATH",
        description="A Python 3.11 with the engine's requirements (Set up engine creates one)",
    )
    setup_status: StringProperty(default="")
    torch_cpu: BoolProperty(
        name="CPU-only torch",
        default=False,
        description="Install PyTorch's CPU wheels (far smaller than the CUDA build; for machines without NVIDIA GPU)",
    )

    def draw(self, context):
        col = self.layout.column()
        col.prop(self, "engine_python")
        col.prop(self, "torch_cpu")
        row = col.row()
        row.operator("neural_atlas.setup_engine", icon="IMPORT")
        row.operator("neural_atlas.check_engine", icon="CHECKMARK")
        if self.setup_status:
            col.label(text=self.setup_status)


class SetupSession:
    """Create the venv, then pip-install the pinned requirements: one process per step, polled."""

    def __init__(self, venv_dir: str, cpu_only: bool = False):
        self.python = ES.venv_python(venv_dir)
        self.log = os.path.join(venv_dir, "setup.log")
        os.makedirs(venv_dir, exist_ok=True)
        self.steps = []
        if not os.path.exists(self.python):
            self.steps.append(("creating the environment", ES.create_venv_argv(sys.executable, venv_dir)))
        pip = ES.pip_install_argv(self.python, cpu_only)
        self.steps.append(("installing torch and the engine's packages (about 1 GB)", pip))
        self.index = -1
        self.job: EP.EngineJob | None = None
        self.ok: bool | None = None
        self.message = ""

    @property
    def label(self) -> str:
        return self.steps[self.index][0] if 0 <= self.index < len(self.steps) else ""

    def status(self) -> str:
        """What the preferences show: the step, and pip's latest line (Collecting…, Downloading…)."""
        last = self.job.state.last_stdout if self.job is not None else ""
        return f"{self.index + 1}/{len(self.steps)} {self.label}" + (f": {last[:80]}" if last else "")

    def step(self) -> bool:
        """Advance; True while there is more to do."""
        if self.job is not None:
            self.job.poll()
            if not self.job.done():
                return True
            result = self.job.result()
            if result.status != EP.STATUS_OK:
                with open(self.log, encoding="utf-8", errors="replace") as f:
                    text = f.read()
                self.ok, self.message = False, f"{ES.explain_setup_failure(text)} (log: {self.log})"
                return False
        self.index += 1
        if self.index >= len(self.steps):
            self.ok, self.message = True, f"engine ready: {self.python}"
            return False
        self.job = EP.EngineJob(self.steps[self.index][1], self.log).start()
        return True

    def cancel(self) -> None:
        if self.job is not None:
            self.job.cancel()


def run_setup(
    venv_dir: str, on_line=None, timeout: float = SETUP_TIMEOUT_SECONDS, cpu_only: bool = False
) -> tuple[bool, str, str]:
    """The blocking set-up (background mode); (ok, message, python)."""
    import time

    session = SetupSession(venv_dir, cpu_only)
    deadline = time.monotonic() + timeout
    label = None
    while session.step():
        if on_line is not None and session.label != label:
            label = session.label
            on_line(label)
        if time.monotonic() > deadline:
            session.cancel()
        time.sleep(0.1)
    return bool(session.ok), session.message, session.python


class NEURALATLAS_OT_setup_engine(bpy.types.Operator):
    """Create a Python environment in the extension's user folder and install the engine's requirements"""

    bl_idname = "neural_atlas.setup_engine"
    bl_label = "Set up engine"

    venv_dir: StringProperty(name="Folder", default="", options={"SKIP_SAVE"})

    def execute(self, context):
        venv_dir = self.venv_dir or default_venv_dir()
        prefs = addon_prefs(context)
        wm = context.window_manager
        wm.progress_begin(0, 2)

        def show(label):
            self.report({"INFO"}, f"Set up engine: {label}…")
            if prefs is not None:
                prefs.setup_status = label

        try:
            ok, message, python = run_setup(venv_dir, show, cpu_only=prefs is not None and prefs.torch_cpu)
        finally:
            wm.progress_end()
        if prefs is not None:
            prefs.setup_status = message
        if not ok:
            self.report({"ERROR"}, message)
            return {"CANCELLED"}
        if prefs is not None:
            prefs.engine_python = python
        self.report({"INFO"}, message)
        return {"FINISHED"}

    _timer = None
    _session: SetupSession | None = None

    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)
        prefs = addon_prefs(context)
        self._session = SetupSession(self.venv_dir or default_venv_dir(), prefs is not None and prefs.torch_cpu)
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
        prefs = addon_prefs(context)
        if prefs is not None:
            prefs.setup_status = session.status() if more else session.message
        for window in context.window_manager.windows:
            for area in window.screen.areas:
                if area.type == "PREFERENCES":
                    area.tag_redraw()
        if more:
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self._timer)
        if not session.ok:
            self.report({"ERROR"}, session.message)
            return {"CANCELLED"}
        if prefs is not None:
            prefs.engine_python = session.python
        self.report({"INFO"}, session.message)
        return {"FINISHED"}


def check_engine(python: str) -> tuple[bool, str]:
    if not python:
        return False, "no engine Python set: run Set up engine, or choose one in the preferences"
    import tempfile

    log = os.path.join(tempfile.gettempdir(), "neural_atlas_check.log")
    job = EP.EngineJob(ES.version_argv(python), log, env=ES.engine_env()).start()
    result = job.wait(timeout=120)
    if result.status == EP.STATUS_OK and job.state.last_stdout:
        return True, job.state.last_stdout
    return False, f"the engine does not run with {python}: {result.message} (log: {log})"


class NEURALATLAS_OT_check_engine(bpy.types.Operator):
    """Run `python -m engine --version` with the engine Python"""

    bl_idname = "neural_atlas.check_engine"
    bl_label = "Check engine"

    def execute(self, context):
        ok, message = check_engine(engine_python(context))
        self.report({"INFO" if ok else "ERROR"}, message)
        prefs = addon_prefs(context)
        if prefs is not None:
            prefs.setup_status = message
        return {"FINISHED"} if ok else {"CANCELLED"}


classes = (NEURALATLAS_AP_preferences, NEURALATLAS_OT_setup_engine, NEURALATLAS_OT_check_engine)
