"""``addon/core`` is the add-on's logic without Blender: every module imports where bpy cannot be imported."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
CORE = ROOT / "addon" / "core"

#: Imports every core module as the extension package does, in an interpreter where ``import bpy`` fails.
PROBE = """
import importlib, importlib.util, pathlib, sys
sys.modules["bpy"] = None  # any import of bpy now raises ImportError
root = pathlib.Path(sys.argv[1])
spec = importlib.util.spec_from_file_location(
    "neural_atlas", root / "__init__.py", submodule_search_locations=[str(root)]
)
package = importlib.util.module_from_spec(spec)
sys.modules["neural_atlas"] = package
spec.loader.exec_module(package)
for name in sys.argv[2:]:
    importlib.import_module(f"neural_atlas.addon.core.{name}")
print("imported", len(sys.argv) - 2)
"""


def _core_modules() -> list[str]:
    return sorted(p.stem for p in CORE.glob("*.py") if p.stem != "__init__")


def test_every_core_module_imports_without_bpy():
    names = _core_modules()
    assert {"engine_process", "jobs", "tree_plan", "running"} <= set(names)
    proc = subprocess.run([sys.executable, "-c", PROBE, str(ROOT), *names], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split() == ["imported", str(len(names))]


def test_no_core_module_mentions_bpy_in_an_import():
    for name in _core_modules():
        src = (CORE / f"{name}.py").read_text(encoding="utf-8")
        assert "import bpy" not in src and "from bpy" not in src, name
