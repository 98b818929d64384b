"""``bench export-cost``: exports of a tiny run following the flow and as fitted, in turn, each timed in its own
process with its own peak memory, into a copy of the run folder; the run's own exports are never touched."""

from __future__ import annotations

import json

import pytest

from bench.__main__ import main as bench_main
from bench.export_cost import COMPARISONS, measure_export_cost, paint_edits, scratch_run, timed_export, timed_render
from engine import contract as C
from engine.errors import InputError
from engine.terms.export_names import PASSES_DIR
from tests.engine.export.tiny_run import make_run
from tests.folders import tree_digest


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
    assert report["tool"] == "export-cost" and report["repeats"] == 2 and report["compare"] == "follow-flow"
    follow, fitted = report["kinds"]
    assert (follow, fitted) == ("follow the flow", "as fitted")
    assert [e["kind"] for e in report["exports"]] == [follow, fitted, fitted, follow]  # in turn, swapped each round
    for e in report["exports"]:
        assert e["wall_seconds"] > 0.0 and e["peak_rss_mb"] > 50.0  # a Python process with torch loaded
        assert e["frames"] == 4 and e["layers"] == 2
        assert set(e["follows"]) <= {"Background", "Foreground"} and (e["kind"] == follow or e["follows"] == [])
    walls = sorted(e["wall_seconds"] for e in report["exports"] if e["kind"] == follow)
    assert report["summary"][follow]["wall_seconds"] == pytest.approx(sum(walls) / 2)  # the median of two
    for ratio, key in (("wall_ratio", "wall_seconds"), ("peak_rss_ratio", "peak_rss_mb")):
        assert report[ratio] == pytest.approx(report["summary"][follow][key] / report["summary"][fitted][key])
    printed = capsys.readouterr().out
    assert "ratio" in printed and printed.strip().endswith(str(out.resolve()))


@pytest.mark.slow
def test_passes_and_frames_written_ahead_and_in_turn_are_the_same_files(tiny, tmp_path):
    """The look-ahead changes when a file is written, never what: both kinds' pass files, and both kinds' rendered
    frames, are byte for byte one."""
    work = tmp_path / "work"
    work.mkdir()
    copy = scratch_run(tiny, work)
    ahead, in_turn = COMPARISONS["write-ahead"]
    runs = [timed_export(copy, version, kind, 1) for version, kind in (("v001", ahead), ("v002", in_turn))]
    assert [r["kind"] for r in runs] == ["write ahead", "in turn"] and all(r["wall_seconds"] > 0 for r in runs)
    a, b = (tree_digest(copy / C.EXPORTS_DIR / v / PASSES_DIR) for v in ("v001", "v002"))
    assert a == b and len(a) == 4
    # renders of the export, painted, written ahead and in turn: the same frames, byte for byte
    manifest = copy / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME
    edits = paint_edits(manifest, work / "paint")
    assert len(edits) == 4 and edits[1].startswith("Background=")
    ahead, in_turn = COMPARISONS["render-write-ahead"]
    renders = [timed_render(manifest, work / name, kind, edits, 1) for name, kind in (("a", ahead), ("b", in_turn))]
    assert [r["verb"] for r in renders] == ["render", "render"] and all(r["frames"] == 4 for r in renders)
    a, b = (tree_digest(work / name) for name in ("a", "b"))
    assert a == b and len([n for n in a if n.endswith(".exr")]) == 4
    report = measure_export_cost(tiny, repeats=1, threads=1, compare="render-write-ahead")  # an export, then renders
    assert report["kinds"] == ["write ahead", "in turn"] and [e["verb"] for e in report["exports"]] == ["render"] * 2


def test_a_folder_without_a_fit_no_repeats_and_no_work_folder_are_one_line_each(tmp_path):
    with pytest.raises(InputError, match="this is not a fitted run folder") as caught:
        measure_export_cost(tmp_path, repeats=1)
    assert "\n" not in str(caught.value) and str(tmp_path) in str(caught.value)
    with pytest.raises(InputError, match="--compare 'faster' is not a comparison"):
        measure_export_cost(tmp_path, repeats=1, compare="faster")
    with pytest.raises(InputError, match="--repeats 0 measures nothing"):
        measure_export_cost(tmp_path, repeats=0)
    with pytest.raises(InputError, match="is not a folder") as caught:  # not a traceback from the temp folder
        measure_export_cost(tmp_path, repeats=1, work=tmp_path / "absent")
    assert "\n" not in str(caught.value) and "--work" in str(caught.value)
    assert bench_main(["export-cost", str(tmp_path)]) == C.EXIT_BAD_INPUT
