"""``bench export-cost``: exports of a tiny run following the flow and as fitted, in turn, each timed in its own
process with its own peak memory, into a copy of the run folder; the run's own exports are never touched."""

from __future__ import annotations

import json

import pytest

from bench.__main__ import main as bench_main
from bench.export_cost import measure_export_cost
from engine import contract as C
from engine.errors import InputError
from tests.engine.export.tiny_run import make_run


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    _, _, run = make_run(tmp_path_factory.mktemp("export_cost"))
    return run


def _tree(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.mark.slow
def test_both_kinds_are_timed_in_turn_and_the_run_is_left_as_it_was(tiny, tmp_path, capsys):
    before = _tree(tiny)
    out = tmp_path / "cost.json"
    assert bench_main(["export-cost", str(tiny), "--repeats", "2", "--threads", "1", "--json", str(out)]) == 0
    assert _tree(tiny) == before  # nothing exported into the user's run, no copy left behind in it
    report = json.loads(out.read_text())
    assert report["tool"] == "export-cost" and report["repeats"] == 2
    kinds = [e["follow_flow"] for e in report["exports"]]
    assert kinds == [True, False, False, True]  # in turn, the order swapped each round
    for e in report["exports"]:
        assert e["wall_seconds"] > 0.0 and e["peak_rss_mb"] > 50.0  # a Python process with torch loaded
        assert e["frames"] == 4 and e["layers"] == 2
        assert set(e["follows"]) <= {"Background", "Foreground"} and (e["follow_flow"] or e["follows"] == [])
    follow = sorted(e["wall_seconds"] for e in report["exports"] if e["follow_flow"])
    assert report["follow_flow"]["wall_seconds"] == pytest.approx(sum(follow) / 2)  # the median of two
    for ratio, key in (("wall_ratio", "wall_seconds"), ("peak_rss_ratio", "peak_rss_mb")):
        assert report[ratio] == pytest.approx(report["follow_flow"][key] / report["as_fitted"][key])
    printed = capsys.readouterr().out
    assert "ratio" in printed and printed.strip().endswith(str(out.resolve()))


def test_a_folder_without_a_fit_no_repeats_and_no_work_folder_are_one_line_each(tmp_path):
    with pytest.raises(InputError, match="this is not a fitted run folder") as caught:
        measure_export_cost(tmp_path, repeats=1)
    assert "\n" not in str(caught.value) and str(tmp_path) in str(caught.value)
    with pytest.raises(InputError, match="--repeats 0 measures nothing"):
        measure_export_cost(tmp_path, repeats=0)
    with pytest.raises(InputError, match="is not a folder") as caught:  # not a traceback from the temp folder
        measure_export_cost(tmp_path, repeats=1, work=tmp_path / "absent")
    assert "\n" not in str(caught.value) and "--work" in str(caught.value)
    assert bench_main(["export-cost", str(tmp_path)]) == C.EXIT_BAD_INPUT
