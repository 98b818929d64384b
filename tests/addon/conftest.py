"""Add-on tests: the checkout is imported as the extension package ``neural_atlas`` (relative imports
resolve as they do inside Blender); bpy tests reset to factory settings before each test."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = "neural_atlas"


def load_package():
    """Import the checkout as the package ``neural_atlas`` (its root ``__init__.py`` is the shim)."""
    if PACKAGE not in sys.modules:
        spec = importlib.util.spec_from_file_location(
            PACKAGE, ROOT / "__init__.py", submodule_search_locations=[str(ROOT)]
        )
        module = importlib.util.module_from_spec(spec)
        sys.modules[PACKAGE] = module
        spec.loader.exec_module(module)
    return sys.modules[PACKAGE]


load_package()

_exit_status = 0


@pytest.fixture(scope="session")
def registered():
    """The add-on registered once per session (the fastest path; the zip install is its own test)."""
    pytest.importorskip("bpy")
    from neural_atlas import addon

    addon.register()
    yield addon
    addon.unregister()


@pytest.fixture
def blender(registered):
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy


def pytest_sessionfinish(session, exitstatus):
    global _exit_status
    _exit_status = int(exitstatus)


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    # bpy < 5 can hang at interpreter exit (docs/blender-compat.md); the summary is printed by now
    bpy = sys.modules.get("bpy")
    if bpy is not None and bpy.app.version < (5, 0, 0):
        from neural_atlas.addon.headless import remove_session_temp

        sys.stdout.flush()
        sys.stderr.flush()
        remove_session_temp()  # Blender's exit would have; os._exit does not
        os._exit(_exit_status)
