"""Float edit layers' pixel conversion (``core.float_edit``) and path (``contract.float_edit_layer``)."""

from __future__ import annotations

import array

import pytest
from neural_atlas.addon.core import float_edit

from engine import contract as C
from engine.terms.colour import SRGB_ENCODED_CUTOFF


def test_straight_srgb_becomes_premultiplied_linear_with_the_contracts_decode():
    px = array.array("f", [0.5, 0.25, 1.0, 0.5, 0.0, 0.04, 0.2, 1.5, 1.0, 1.0, 1.0, -0.2])
    out = float_edit.straight_srgb_to_premultiplied_linear(px)
    lin = [C.srgb_to_linear(c) for c in (0.5, 0.25, 1.0)]
    assert list(out[:4]) == pytest.approx([lin[0] * 0.5, lin[1] * 0.5, lin[2] * 0.5, 0.5], abs=1e-7)
    assert list(out[4:8]) == pytest.approx([0.0, 0.04 / 12.92, C.srgb_to_linear(0.2), 1.0], abs=1e-7)  # alpha clamped
    assert list(out[8:]) == [0.0, 0.0, 0.0, 0.0]  # a negative alpha is none
    assert out.typecode == "f" and len(out) == len(px)


def test_the_contracts_decode_is_the_iec_curve():
    assert C.srgb_to_linear(0.0) == 0.0 and C.srgb_to_linear(1.0) == pytest.approx(1.0)
    assert C.srgb_to_linear(SRGB_ENCODED_CUTOFF) == pytest.approx(SRGB_ENCODED_CUTOFF / 12.92)
    assert C.srgb_to_linear(0.5) == pytest.approx(((0.5 + 0.055) / 1.055) ** 2.4)
    assert C.srgb_to_linear(-0.5) == -C.srgb_to_linear(0.5)  # extended symmetrically, as the engine's


def test_the_float_twin_of_an_edit_layer():
    assert C.float_edit_layer("/run/edits/Foreground.png") == "/run/edits/Foreground.exr"
    assert C.float_edit_layer("/run/edits/Foreground.PNG") == "/run/edits/Foreground.exr"
