"""The house rules that keep engine and add-on apart, enforced by walking the imports."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

from tests.paths import ROOT


def _imports(path: Path) -> list[tuple[str, int]]:
    """(module, level) for every import in a file; level > 0 for relative imports."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(a.name, 0) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            out.append((node.module or "", node.level))
            if node.module is None or node.module.split(".")[-1] == "engine":
                out += [(f"{node.module or ''}.{a.name}".lstrip("."), node.level) for a in node.names]
    return out


def test_engine_never_imports_bpy_or_addon():
    for py in (ROOT / "engine").rglob("*.py"):
        for mod, _level in _imports(py):
            top = mod.split(".")[0]
            assert top not in ("bpy", "addon", "bmesh", "mathutils"), f"{py} imports {mod}"


def test_contract_is_standard_library_only():
    for mod, level in _imports(ROOT / "engine" / "contract.py"):
        assert level == 0 and mod.split(".")[0] in sys.stdlib_module_names | {"__future__"}, mod


def test_addon_imports_only_the_contract_of_the_engine():
    for py in (ROOT / "addon").rglob("*.py"):
        for mod, level in _imports(py):
            parts = mod.split(".")
            assert parts[0] not in ("torch", "numpy", "cv2", "OpenImageIO", "OpenEXR"), f"{py} imports {mod}"
            if "engine" in parts:
                assert parts[parts.index("engine") + 1 :] in (["contract"], []), f"{py} imports {mod}"
                assert level > 0 or parts[0] == "engine", f"{py}: use a relative import of the contract"


def test_root_shim_is_two_lines():
    lines = [ln for ln in (ROOT / "__init__.py").read_text().splitlines() if ln.strip()]
    assert len(lines) == 2 and "from .addon import register, unregister" in lines[1]
