"""No function of the product or the bench takes more than ``MAX_PARAMETERS`` parameters unless its docstring says
why (a sentence naming its "parameters"): a longer list is a value that wants a name (``FitInputs``, ``FitPlan``,
``TableFit``, ``BenchPlan``, ``RenderSettings``), and one that grows unseen is how a call site starts passing
fifteen loose arguments."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: Folders whose functions are counted.
FOLDERS = ("engine", "addon", "bench")
#: The most parameters a function takes without a reason (``self`` and ``cls`` not counted).
MAX_PARAMETERS = 8


def parameter_count(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Every parameter a caller may pass: positional, keyword-only, ``*args`` and ``**kwargs`` not counted."""
    args = node.args
    names = [a.arg for a in (*args.posonlyargs, *args.args, *args.kwonlyargs)]
    return len(names) - (1 if names[:1] in (["self"], ["cls"]) else 0)


def long_signatures(source: str) -> list[tuple[str, int, bool]]:
    """(name, parameters, whether its docstring gives a reason) of each function over ``MAX_PARAMETERS``."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and parameter_count(node) > MAX_PARAMETERS:
            doc = ast.get_docstring(node) or ""
            found.append((node.name, parameter_count(node), "parameters" in doc.lower()))
    return found


def test_the_counter_counts_what_a_caller_passes():
    source = '''
def loose(a, b, c, d, e, f, g, h, i): pass
def named(a, b, c, d, e, f, g, h, i):
    """Nine parameters: the CLI's flags one for one."""
class K:
    def method(self, a, b, c, d, e, f, g, h): pass
def short(a, /, b, *rest, c, **more): pass
'''
    assert long_signatures(source) == [("loose", 9, False), ("named", 9, True)]


def test_no_function_takes_more_than_eight_parameters_without_a_reason():
    unexplained = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            for name, count, reason in long_signatures(path.read_text(encoding="utf-8")):
                if not reason:
                    unexplained.append(f"{path.relative_to(ROOT)}: {name} takes {count}")
    assert not unexplained, "group them into a value, or say why in the docstring: " + "; ".join(unexplained)
