"""``bench paint-gaps``: the by-gap curves read from paint tables, and the picture drawn from them."""

from __future__ import annotations

import json
import math

import numpy as np
import OpenImageIO as oiio
import pytest

from bench.__main__ import main
from bench.paint_gaps import gap_series, plot_paint_gaps, read_table, table_label
from engine import contract as C
from engine.errors import InputError


def _curve(values: list[float | None]) -> list[dict]:
    gaps = [[1, 3], [3, 8], [8, 16], [16, None]]
    return [{"gap": g, "delta_avg": v} for g, v in zip(gaps, values, strict=True)]


TABLE = {
    "preset": "draft",
    "degrade": "exact",
    "sets": ["long_flow_max_gap=8"],
    "rows": [
        {"clip": "dog", "paint_by_gap": _curve([0.9, 0.7, 0.5, None]), "flow_by_gap": _curve([0.95, 0.6, 0.3, None])},
        {"clip": "no_tracks", "paint": None},
    ],
}


def test_each_row_gives_its_bins_and_values_nan_where_a_bin_is_empty():
    series = gap_series(TABLE)
    assert list(series) == ["dog"]  # a row without curves is left out
    dog = series["dog"]
    assert dog.bins == ("1-3", "3-8", "8-16", "16+")
    assert dog.paint[:3] == (0.9, 0.7, 0.5) and math.isnan(dog.paint[3])
    assert dog.flow[:3] == (0.95, 0.6, 0.3) and math.isnan(dog.flow[3])
    assert dog.label == table_label(TABLE) == "draft, masks exact, long_flow_max_gap=8"
    assert table_label({"preset": "draft", "degrade": "exact", "scribbles": True, "scribble_frames": 6}).endswith(
        "scribbles on 6 frames"
    )


def test_differently_binned_curves_are_refused():
    row = {"clip": "dog", "paint_by_gap": _curve([0.9, 0.7, 0.5, 0.1]), "flow_by_gap": _curve([0.9, 0.7, 0.5, 0.1])}
    row["flow_by_gap"][0]["gap"] = [1, 2]
    with pytest.raises(ValueError, match="binned differently"):
        gap_series({"rows": [row]})


def test_the_picture_has_a_panel_per_clip_and_the_cli_writes_it(tmp_path):
    other = {**TABLE, "sets": [], "rows": [{**TABLE["rows"][0], "clip": "horse"}, TABLE["rows"][0]]}
    assert plot_paint_gaps([TABLE, other], tmp_path / "a.png") == ["dog", "horse"]
    assert plot_paint_gaps([TABLE, other], tmp_path / "b.png", only=["horse"]) == ["horse"]
    two, one = (oiio.ImageBuf(str(tmp_path / n)) for n in ("a.png", "b.png"))
    assert two.spec().width > 1.8 * one.spec().width  # two panels side by side against one
    pixels = two.get_pixels(oiio.FLOAT)
    assert float(np.std(pixels)) > 0.05  # lines drawn, not a blank canvas
    (tmp_path / "t.json").write_text(json.dumps(TABLE))
    assert main(["paint-gaps", str(tmp_path / "t.json"), "--out", str(tmp_path / "c.png")]) == C.EXIT_OK
    assert (tmp_path / "c.png").stat().st_size > 1000


def test_a_file_that_is_not_a_paint_table_is_one_line_naming_it(tmp_path, capsys):
    bad = tmp_path / "bench.json"
    bad.write_text(json.dumps({"clips": []}))
    with pytest.raises(InputError, match=r"bench\.json: is not a paint table"):
        read_table(bad)
    (tmp_path / "t.json").write_text(json.dumps(TABLE))
    args = ["paint-gaps", str(tmp_path / "t.json"), "--label", "a", "--label", "b", "--out", str(tmp_path / "x.png")]
    assert main(args) == C.EXIT_BAD_INPUT
    assert "2 --label for 1 tables" in capsys.readouterr().err
    assert main(["paint-gaps", str(bad), "--out", str(tmp_path / "x.png")]) == C.EXIT_BAD_INPUT
    with pytest.raises(InputError, match="no clip of these tables"):
        plot_paint_gaps([{"rows": []}], tmp_path / "y.png")
