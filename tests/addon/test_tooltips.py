"""Every operator, property and menu entry of the add-on has a tooltip as Blender writes its own: one sentence on
one line, without a closing period (Blender's tooltips add none), in the artist's words. An operator's docstring is
its tooltip, so a docstring wrapped over two lines showed the artist a line break and the indentation mid-sentence."""

from __future__ import annotations

import re

import pytest
from neural_atlas.addon import registration

#: A full stop (or ? !) followed by a new sentence: two sentences.
TWO_SENTENCES = re.compile(r"[.!?] +[A-Z]")


def tooltip_problem(text: str) -> str | None:
    """What is wrong with ``text`` as a tooltip (None: nothing)."""
    if not text.strip():
        return "no tooltip"
    if "\n" in text or "  " in text or text != text.strip():
        return "a line break or a run of spaces"
    if TWO_SENTENCES.search(text):
        return "more than one sentence"
    if text.endswith("."):
        return "a closing period"
    return None


def test_the_rule_reads_tooltips_as_blender_writes_them():
    assert tooltip_problem("Fit layered neural atlases to the clip, then import the result") is None
    assert tooltip_problem("Stop the engine; a fit writes a checkpoint (e.g. 2.5 s) that Resume continues from") is None
    assert tooltip_problem("") == "no tooltip"
    assert tooltip_problem("Land the paint on the atlases, so it\n    shows on every frame") is not None
    assert tooltip_problem("Send the clip. The farm fills the Run Folder") == "more than one sentence"
    assert tooltip_problem("Add a layer.") == "a closing period"


def _tooltips(bpy) -> dict[str, str]:  # type: ignore[no-untyped-def]
    """Every tooltip the add-on registers: each operator's and each property's (of its operators, property groups
    and preferences) and each menu entry's, by where it is shown."""
    found = {}
    for cls in registration.classes:
        if issubclass(cls, bpy.types.Operator):
            module, name = cls.bl_idname.split(".")
            rna = getattr(getattr(bpy.ops, module), name).get_rna_type()
            found[cls.bl_idname] = rna.description
            owned = {p.identifier for p in rna.properties} - {"rna_type"}
        else:
            rna = cls.bl_rna
            owned = set(getattr(cls, "__annotations__", {}))
        for prop in rna.properties:
            if prop.identifier in owned:
                found[f"{cls.__name__}.{prop.identifier}"] = prop.description
                for item in getattr(prop, "enum_items", ()):  # a menu's entries: each its own tooltip
                    found[f"{cls.__name__}.{prop.identifier}[{item.identifier!r}]"] = item.description
    return found


def test_every_operator_and_property_has_a_one_sentence_tooltip(registered):
    bpy = pytest.importorskip("bpy")
    tooltips = _tooltips(bpy)
    assert len(tooltips) > 60  # the operators and the properties were found
    problems = {where: (tooltip_problem(text), text) for where, text in tooltips.items() if tooltip_problem(text)}
    assert not problems, "\n".join(f"{where}: {why}: {text!r}" for where, (why, text) in sorted(problems.items()))
