"""Preferences: the engine's interpreter (``ops/setup.py`` holds the operators that set it up and check it) and
the farm Submit to Farm sends to (``ops/farm.py``)."""

from __future__ import annotations

import os
from typing import Any

import bpy
from bpy.props import EnumProperty, IntProperty, StringProperty

from .core import engine_setup as ES
from .core import farm as FM
from .core import running

#: the add-on's module name (``bl_ext.<repo>.neural_atlas`` when installed): preferences are keyed by it
ADDON_ID = __package__.rpartition(".")[0]
#: overrides the preference (CI, pipelines): the Python that runs ``python -m engine``
ENGINE_PYTHON_ENV = "NEURAL_ATLAS_ENGINE_PYTHON"
#: the engine's environment, in the extension's user folder
VENV_FOLDER = "engine_venv"


def addon_prefs(context: Any = None) -> Any:
    context = context or bpy.context
    addon = context.preferences.addons.get(ADDON_ID)
    return addon.preferences if addon is not None else None


def engine_python(context: Any = None) -> str:
    """The engine interpreter: the environment override, else the preference; '' if neither is set."""
    if os.environ.get(ENGINE_PYTHON_ENV):
        return os.environ[ENGINE_PYTHON_ENV]
    prefs = addon_prefs(context)
    return bpy.path.abspath(prefs.engine_python) if prefs is not None and prefs.engine_python else ""


def default_venv_dir() -> str:
    return bpy.utils.extension_path_user(ADDON_ID, path=VENV_FOLDER, create=True)


def torch_choice(context: Any = None) -> ES.TorchChoice:
    """The torch build Set up engine installs here (``ES.torch_choice`` of the Torch Build preference)."""
    prefs = addon_prefs(context)
    return ES.torch_choice(prefs.torch_build if prefs is not None else ES.TORCH_AUTO)


def online_refusal() -> tuple[str, ...]:
    """Why Set up engine may not download now (``ES.online_access_refusal`` of Blender's online-access state);
    () when it may. Read when asked: the artist can switch online access while Blender runs."""
    return ES.online_access_refusal(bpy.app.online_access, bpy.app.online_access_override)


def farm_settings(context: Any = None) -> FM.FarmSettings:
    """The farm Submit to Farm sends to (the defaults while the add-on has no preferences, e.g. in a script that
    registered it without enabling it)."""
    prefs = addon_prefs(context)
    if prefs is None:
        return FM.FarmSettings()
    bundle_dir = os.path.normpath(bpy.path.abspath(prefs.farm_bundle_dir)) if prefs.farm_bundle_dir else ""
    return FM.FarmSettings(prefs.farm_kind, prefs.farm_manager_url, prefs.farm_priority, bundle_dir)


def farm_refusal(context: Any = None) -> str:
    """Why Submit to Farm may not use the network now (``FM.online_refusal`` of Blender's state); '' when it may.
    Read when asked: the artist can switch online access, or the farm, while Blender runs."""
    return FM.online_refusal(farm_settings(context).kind, bpy.app.online_access, bpy.app.online_access_override)


class NEURALATLAS_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_ID

    engine_python: StringProperty(
        name="Engine Python",
        subtype="FILE_PATH",
        description="A Python 3.11 with the engine's requirements (Set up engine creates one)",
    )
    setup_status: StringProperty(default="", description="What Set up engine last said")
    torch_build: EnumProperty(
        name="Torch Build",
        items=[
            (ES.TORCH_AUTO, "Auto", "The CUDA build where this machine has an NVIDIA GPU, else the CPU build"),
            (ES.TORCH_CPU, "CPU", f"PyTorch's CPU wheels (about {ES.TORCH_DOWNLOAD_GB[ES.TORCH_CPU]:g} GB)"),
            (ES.TORCH_CUDA, "CUDA", f"The CUDA build (about {ES.TORCH_DOWNLOAD_GB[ES.TORCH_CUDA]:g} GB; NVIDIA GPU)"),
        ],
        default=ES.TORCH_AUTO,
        description="Which PyTorch Set up engine installs (macOS always takes the default wheel, with MPS)",
    )

    farm_kind: EnumProperty(
        name="Farm",
        items=[
            (FM.FARM_FLAMENCO, "Flamenco Manager", "Submit a job to a Flamenco Manager (needs online access)"),
            (FM.FARM_OPENJD, "OpenJD bundle (Deadline Cloud)", "Write an Open Job Description bundle to submit"),
        ],
        default=FM.FARM_FLAMENCO,
        description="Where Submit to Farm sends the shot",
    )
    farm_manager_url: StringProperty(
        name="Manager URL",
        default=FM.DEFAULT_MANAGER_URL,
        description="The Flamenco Manager's address (its neural-atlas job type installed; see docs/farm.md)",
    )
    farm_priority: IntProperty(
        name="Priority",
        default=FM.DEFAULT_PRIORITY,
        min=FM.PRIORITY_MIN,
        max=FM.PRIORITY_MAX,
        description="The Flamenco job's priority (higher runs first)",
    )
    farm_bundle_dir: StringProperty(
        name="Bundle Folder",
        subtype="DIR_PATH",
        default="",
        description="Where OpenJD bundles are written, one folder per shot; empty: beside the Run Folder "
        "(<Run Folder>.farm/openjd)",
    )

    def draw(self, context):
        col = self.layout.column()
        col.prop(self, "engine_python")
        col.prop(self, "torch_build")
        refusal = online_refusal()
        if refusal:  # Blender's rule for extensions: no download while online access is off
            box = col.box()
            for i, line in enumerate(refusal):
                box.label(text=line, icon="INTERNET_OFFLINE" if i == 0 else "BLANK1")
            box.operator("neural_atlas.copy_setup_command", icon="COPYDOWN")
        for i, line in enumerate(ES.torch_lines(torch_choice(context))):  # which torch, how large, and why
            col.label(text=line, icon="INFO" if i == 0 else "BLANK1")
        row = col.row()
        row.operator("neural_atlas.setup_engine", icon="IMPORT")
        if running.is_running(running.SETUP_KEY):  # the only way to stop it: ESC does not (ops/driver.py)
            row.operator("neural_atlas.cancel_setup", icon="CANCEL")
        row.operator("neural_atlas.check_engine", icon="CHECKMARK")
        if self.setup_status:
            col.label(text=self.setup_status)
        draw_farm(col.box(), self)


#: The preferences' line while Flamenco is chosen and online access is off.
FARM_OFFLINE_TEXT = "Flamenco needs Allow Online Access (System > Network)"


def draw_farm(box: Any, prefs: Any) -> None:
    """Submit to Farm's settings: the Manager's for Flamenco, the bundle folder for OpenJD."""
    box.label(text="Submit to Farm", icon="NETWORK_DRIVE")
    box.prop(prefs, "farm_kind")
    if prefs.farm_kind == FM.FARM_FLAMENCO:
        box.prop(prefs, "farm_manager_url")
        box.prop(prefs, "farm_priority")
        if FM.online_refusal(prefs.farm_kind, bpy.app.online_access, bpy.app.online_access_override):
            box.label(text=FARM_OFFLINE_TEXT, icon="INTERNET_OFFLINE")
    else:
        box.prop(prefs, "farm_bundle_dir")


classes = (NEURALATLAS_AP_preferences,)
