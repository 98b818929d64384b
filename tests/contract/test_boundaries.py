"""The house rules that keep the engine, its development bench and the add-on apart, checked on the source.

Every import is resolved to the module it loads, whatever its spelling: ``import engine.cli``,
``from ..engine import cli``, ``from .. import engine``, the extension's package name
(``neural_atlas.engine.cli``), and ``importlib.import_module`` / ``__import__`` with a literal name. A
dynamic import whose name is not a literal cannot be checked, so it is refused.

A string that names a file or module of the other side reaches into it as surely as an import does (a
script path handed to ``subprocess``, a module name handed to ``importlib``), so string literals are checked
too; docstrings are prose and may mention files.

The engine's one way into the add-on is a process, and it is named once: ``engine.terms.cli.HEADLESS_SCRIPT``.
``engine demo`` ends with the artist's Blender steps done headless (import the export, build the compositor
tree, render) and compares Blender's render with its own; that is product behaviour, and the script that does
it must run inside Blender, so it belongs to the add-on. The contract's terms already name everything that
crosses the process boundary the other way (the CLI verbs the add-on runs); the headless script is the same
kind of entry point in the reverse direction, so it is defined among them, next to the verbs. The engine refers
to it only through that name: no engine file spells an ``addon`` path or module itself, and none imports bpy or
add-on code (the script runs in its own process).

The contract says exactly what crosses: ``engine.contract.__all__`` is every name the add-on reaches through
it, plus the contract's own requirement names, and nothing else.
"""

from __future__ import annotations

import ast
import re
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from engine import contract as C
from engine.terms.cli import HEADLESS_SCRIPT
from tests.paths import ROOT

#: The package Blender loads the extension as (``addon/headless.py`` loads the checkout under it too); an
#: absolute import through it names the same modules as a relative one.
EXTENSION_PACKAGE = "neural_atlas"
BLENDER_MODULES = ("bpy", "bmesh", "mathutils", "gpu", "bl_math", "blf", "aud")
#: What the engine's fit runs on; the add-on runs it in another process and imports none of it.
ENGINE_THIRD_PARTY = ("torch", "numpy", "cv2", "OpenImageIO", "OpenEXR", "av", "scipy", "tqdm")
#: Of those, what Blender's own Python ships with (every Blender bundles numpy; the bpy wheels depend on it): the
#: add-on may use it to move pixels (``Image.pixels.foreach_get``) without adding a dependency.
BUNDLED_WITH_BLENDER = ("numpy",)
DYNAMIC_IMPORTS = ("import_module", "__import__", "run_module")
_ADDON_IN_STRING = re.compile(r"(?:^|[/\\.])addon(?:$|[/\\.])")
_ENGINE_IN_STRING = re.compile(r"(?:^|[/\\.])engine[/\\.](?!contract(?:$|\.py$|\.))")


def _package(path: Path) -> list[str]:
    """The package a file's relative imports start from (``engine/fit/trainer.py`` -> engine.fit)."""
    return list(path.relative_to(ROOT).parts[:-1])


def _absolute(name: str, level: int, package: list[str]) -> str:
    """A module name as the repository root names it: relative levels resolved, the extension's prefix dropped."""
    if level:
        base = package[: len(package) - (level - 1)] if level - 1 <= len(package) else []
        name = ".".join([*base, name] if name else base)
    prefix = f"{EXTENSION_PACKAGE}."
    return name[len(prefix) :] if name.startswith(prefix) else name


def _docstrings(tree: ast.AST) -> set[int]:
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                out.add(id(first.value))
    return out


def imports(path: Path) -> Iterator[tuple[str, int]]:
    """(module the statement loads, line) for every import in a file, resolved against the repository root.

    ``from M import a`` yields ``M.a`` (a submodule or an attribute of M: either way it is inside M), so
    ``from .. import engine`` yields ``engine`` and ``from ..engine import contract`` yields ``engine.contract``.
    A dynamic import with a name that is not a literal yields ``<dynamic>``."""
    package = _package(path)
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield _absolute(alias.name, 0, package), node.lineno
        elif isinstance(node, ast.ImportFrom):
            module = _absolute(node.module or "", node.level, package)
            for alias in node.names:
                yield (f"{module}.{alias.name}" if module else alias.name), node.lineno
        elif isinstance(node, ast.Call):
            func = node.func
            name = func.id if isinstance(func, ast.Name) else func.attr if isinstance(func, ast.Attribute) else ""
            if name not in DYNAMIC_IMPORTS:
                continue
            arg = node.args[0] if node.args else None
            if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                level = len(arg.value) - len(arg.value.lstrip("."))
                yield _absolute(arg.value.lstrip("."), level, package), node.lineno
            else:
                yield "<dynamic>", node.lineno


def strings(path: Path) -> Iterator[tuple[str, int]]:
    """Every string literal of a file but its docstrings (f-string parts included), with its line."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = _docstrings(tree)
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in skip:
            yield node.value, node.lineno


def _top(module: str) -> str:
    return module.split(".")[0]


def _inside(module: str, package: str) -> bool:
    return module == package or module.startswith(f"{package}.")


def _files(folder: str) -> list[Path]:
    files = sorted((ROOT / folder).rglob("*.py"))
    assert files, folder
    return files


def _addon_module(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, text: str) -> Path:
    """``text`` as the add-on module ``addon/ops/x.py`` of a checkout rooted at ``tmp_path`` (ROOT while the test
    runs)."""
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    src = tmp_path / "addon" / "ops" / "x.py"
    src.parent.mkdir(parents=True)
    src.write_text(text)
    return src


def test_imports_are_resolved_whatever_the_spelling(tmp_path, monkeypatch):
    """The resolver itself: each spelling of an engine import from the add-on names the module it loads."""
    src = _addon_module(
        tmp_path,
        monkeypatch,
        "from ... import engine\n"
        "from ...engine import contract, cli\n"
        "from ...engine.contract import EXIT_OK\n"
        "from ..core import plan\n"
        "import neural_atlas.engine.fit.trainer\n"
        "import importlib\n"
        "importlib.import_module('...engine.demo', __package__)\n"
        "__import__(name)\n",
    )
    assert [m for m, _ in imports(src)] == [
        "engine",
        "engine.contract",
        "engine.cli",
        "engine.contract.EXIT_OK",
        "addon.core.plan",
        "engine.fit.trainer",
        "importlib",
        "engine.demo",
        "<dynamic>",
    ]


def test_engine_never_imports_bpy_or_the_addon():
    for py in _files("engine"):
        for mod, line in imports(py):
            assert mod != "<dynamic>", f"{py}:{line}: a dynamic import the boundary cannot check"
            assert _top(mod) not in ("addon", *BLENDER_MODULES), f"{py}:{line} imports {mod}"


def test_engine_reaches_the_addon_only_through_the_contracts_headless_script():
    """No engine file names an add-on file or module; the one entry point is ``terms.cli.HEADLESS_SCRIPT``."""
    named = {
        (py.relative_to(ROOT).as_posix(), text)
        for py in _files("engine")
        for text, _ in strings(py)
        if _ADDON_IN_STRING.search(text)
    }
    assert named == {("engine/terms/cli.py", HEADLESS_SCRIPT)}
    script = ROOT / HEADLESS_SCRIPT
    assert script.is_file() and '__name__ == "__main__"' in script.read_text(encoding="utf-8")


def test_product_never_imports_the_development_bench():
    """The bench (``bench/``: accuracy-vs-time curves, speed tables) is a tool beside the product, in neither the
    wheel nor the extension zip: nothing in engine/ or addon/ may import it, or the installed product would fail on
    a missing module."""
    for py in [*_files("engine"), *_files("addon")]:
        for mod, line in imports(py):
            assert not _inside(mod, "bench"), f"{py}:{line} imports {mod}"


def test_contract_is_standard_library_only():
    """engine/contract.py and every module of its terms (engine/terms/) import the standard library and one another
    only: the add-on imports them all, inside Blender's Python."""
    files = [ROOT / "engine" / "contract.py", *sorted((ROOT / "engine" / "terms").glob("*.py"))]
    assert len(files) > 2
    for py in files:
        for mod, line in imports(py):
            ok = _top(mod) in sys.stdlib_module_names | {"__future__"} or _inside(mod, "engine.terms")
            assert ok, f"{py.relative_to(ROOT)}:{line} imports {mod}"


def test_each_terms_module_declares_its_own_names_only():
    """Each terms module's ``__all__`` is every public name it defines, none it imports: ``engine.terms`` names every
    term once, and no ``Path`` or ``Any`` rides along."""
    for py in sorted((ROOT / "engine" / "terms").glob("*.py")):
        if py.name == "__init__.py":
            continue
        tree = ast.parse(py.read_text(encoding="utf-8"))
        declared = _declared_all(tree)
        public = {name for name in _defined(tree) if not name.startswith("_")} - {"__all__"}
        assert sorted(declared) == sorted(public), f"{py.relative_to(ROOT)}: __all__ != its public names"
    assert not hasattr(C, "Any") and not hasattr(C, "json")


def _defined(tree: ast.Module) -> set[str]:
    """The names a module's top level defines (assignments, functions, classes), not those it imports."""
    defined: set[str] = set()
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.ClassDef):
            defined.add(node.name)
        targets = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
        for t in targets:
            if isinstance(t, ast.Name) and isinstance(node, ast.Assign | ast.AnnAssign):
                defined.add(t.id)
    return defined


def _declared_all(tree: ast.Module) -> list[str]:
    for node in tree.body:
        targets = node.targets if isinstance(node, ast.Assign) else [getattr(node, "target", None)]
        if any(isinstance(t, ast.Name) and t.id == "__all__" for t in targets) and node.value is not None:
            return list(ast.literal_eval(node.value))
    return []


def contract_names_used(py: Path) -> set[str]:
    """The names a file reaches through the contract: ``X.NAME`` where X is bound to the contract module
    (``from ..engine import contract as C``, however spelt), and ``from ..engine.contract import NAME``."""
    package = _package(py)
    tree = ast.parse(py.read_text(encoding="utf-8"))
    bound: set[str] = set()
    used: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            module = _absolute(node.module or "", node.level, package)
            for alias in node.names:
                if f"{module}.{alias.name}" == "engine.contract":
                    bound.add(alias.asname or alias.name)
                elif module == "engine.contract":
                    used.add(alias.name)
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if _absolute(alias.name, 0, package) == "engine.contract" and alias.asname:
                    bound.add(alias.asname)
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in bound:
            used.add(node.attr)
    return used


def test_contract_names_are_resolved_whatever_the_spelling(tmp_path, monkeypatch):
    """The reader of contract uses itself: each way the add-on binds the contract counts, other modules do not."""
    src = _addon_module(
        tmp_path,
        monkeypatch,
        "from ...engine import contract as C\n"
        "from ...engine.contract import EXIT_OK\n"
        "def f():\n"
        "    from neural_atlas.engine import contract\n"
        "    return C.VERB_FIT, contract.MANIFEST_NAME, D.NOT_THE_CONTRACT, C.RunLocked\n",
    )
    assert contract_names_used(src) == {"EXIT_OK", "VERB_FIT", "MANIFEST_NAME", "RunLocked"}


def test_contract_says_exactly_what_crosses_to_the_addon():
    """``engine.contract.__all__`` is the names the add-on reaches through it plus the contract's own definitions
    (its requirements): a name the add-on uses that the contract lacks fails here (not first inside Blender), and so
    does a name the contract exports that nothing in the add-on uses. The contract imports each term by name from
    its subject module (no star import), and exports nothing it does not list."""
    used: dict[str, list[str]] = {}
    for py in _files("addon"):
        for name in contract_names_used(py):
            used.setdefault(name, []).append(py.relative_to(ROOT).as_posix())
    assert used, "the add-on reaches nothing through the contract: the reader is broken"
    tree = ast.parse((ROOT / "engine" / "contract.py").read_text(encoding="utf-8"))
    own = {name for name in _defined(tree) if not name.startswith("_")} - {"__all__"}
    exported = set(C.__all__)
    assert len(C.__all__) == len(exported), "engine.contract.__all__ lists a name twice"
    lacking = {name: files for name, files in sorted(used.items()) if name not in exported}
    assert not lacking, f"the add-on reaches these through the contract, which does not list them: {lacking}"
    unused = sorted(exported - set(used) - own)
    assert not unused, f"the contract exports these and nothing in the add-on uses them: {unused}"
    assert own <= exported, f"the contract's own names missing from __all__: {sorted(own - exported)}"
    for name in C.__all__:
        assert hasattr(C, name), f"engine.contract.__all__ lists {name}, which it does not define"
    stars = [n.lineno for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and any(a.name == "*" for a in n.names)]
    assert not stars, f"engine/contract.py:{stars}: a star import; import each term that crosses by name"


def test_addon_imports_only_the_contract_of_the_engine():
    for py in _files("addon"):
        for mod, line in imports(py):
            assert mod != "<dynamic>", f"{py}:{line}: a dynamic import the boundary cannot check"
            top = _top(mod)
            assert top not in ENGINE_THIRD_PARTY or top in BUNDLED_WITH_BLENDER, f"{py}:{line} imports {mod}"
            if top == "engine":
                assert _inside(mod, "engine.contract"), f"{py}:{line} imports {mod}: only engine.contract"


def test_addon_imports_the_contract_relatively():
    """``import engine.contract`` would load whatever ``engine`` is first on sys.path, not the copy shipped in
    the extension beside the add-on: the contract is imported relatively (or through the extension package)."""
    for py in _files("addon"):
        for node in ast.walk(ast.parse(py.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module or ""]
            else:
                continue
            assert not any(_top(n) == "engine" for n in names), f"{py}:{node.lineno}: import the contract relatively"


def test_addon_names_no_engine_module_or_file_but_the_contract():
    for py in _files("addon"):
        for text, line in strings(py):
            assert not _ENGINE_IN_STRING.search(text), f"{py}:{line} names {text!r}"


def test_root_shim_only_imports_the_addon():
    """The extension root holds no logic: comments, then the add-on's register/unregister, imported only as a package
    (tests/packaging/test_extension_root.py imports it both ways)."""
    code = [ln for ln in (ROOT / "__init__.py").read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    assert code == ["if __package__:", "    from .addon import register, unregister  # noqa: F401"]
