"""JSON values of any shape, for the fuzz tests of every loader (run files, manifests)."""

from __future__ import annotations

from hypothesis import strategies as st

#: A JSON value of any shape: what a hand-edited or foreign file may hold.
JSON_VALUES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**70), max_value=2**70)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=12),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=12), inner, max_size=4),
    max_leaves=12,
)
