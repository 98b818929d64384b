"""The checkout's root ``__init__.py`` (the extension root Blender loads) imported the two ways it is: as the
extension's package, and on its own, as pytest imports it when the checkout's folder name is not a Python name
(``git clone ... neural-atlas``): every test's set-up imported it and failed there."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_the_root_init_imports_alone_without_a_package() -> None:
    spec = importlib.util.spec_from_file_location("__init__", ROOT / "__init__.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert not hasattr(module, "register")


def test_the_root_init_as_the_extension_package_exposes_register() -> None:
    name = "neural_atlas_extension_root"
    spec = importlib.util.spec_from_file_location(name, ROOT / "__init__.py", submodule_search_locations=[str(ROOT)])
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
        assert callable(module.register) and callable(module.unregister)
    finally:
        for key in [k for k in sys.modules if k == name or k.startswith(name + ".")]:
            del sys.modules[key]
