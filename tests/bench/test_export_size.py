"""``bench export-size``: a tiny export's pass files rewritten with each choice of channels, precision and
compression; the sizes are real files' sizes, the errors are the choices' own bounds, and the export is only read."""

from __future__ import annotations

import json
import os

import pytest

from bench.__main__ import main as bench_main
from bench.export_size import DEFAULT_VARIANT, VARIANTS, measure_export_size
from engine import contract as C
from engine.errors import InputError
from engine.terms.export_names import PASS_PRECISION_FULL, PASSES_DIR
from tests.engine.export.tiny_run import export, make_run
from tests.folders import tree_digest


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    _, _, run = make_run(tmp_path_factory.mktemp("export_size"))
    # every bit and the STMap copy: the rounding and the copy are what is measured
    return export(run, precision=PASS_PRECISION_FULL, stmap=True).parent


def test_each_choice_is_measured_within_its_error_bound(exported):
    before = tree_digest(exported)
    rows = {r.variant: r for r in measure_export_size(exported, frames=3)}
    assert list(rows) == [v[0] for v in VARIANTS] and tree_digest(exported) == before
    first = sorted((exported / PASSES_DIR).glob("*.exr"))[0]
    today = rows["as exported: float32, STMap copy, ZIP"]
    assert today.channels == 16 and today.max_half_error == 0.0 and today.max_uv_error == 0.0  # 2 layers
    assert today.mb_per_frame == pytest.approx(os.path.getsize(first) / 1e6, rel=0.25)
    half = rows["alpha and coverage in half float, STMap copy left out"]
    assert half.channels == 8 and 0.0 < half.max_half_error <= 2.0**-12  # half's rounding in 0.5..1
    rounded = rows["the same, u and v rounded to 2^-17 (float32)"]
    assert 0.0 < rounded.max_uv_error <= 2.0**-18 and rounded.mb_per_frame < today.mb_per_frame
    default = rows[DEFAULT_VARIANT]  # what export writes by default: half the channels, every reader's types
    assert default.channels == 8 and default.max_uv_error == rounded.max_uv_error
    for row in rows.values():
        assert row.mb_per_frame > 0.0 and row.write_seconds > 0.0


def test_the_command_prints_the_table_and_writes_its_report(exported, tmp_path, capsys):
    out = tmp_path / "size.json"
    assert bench_main(["export-size", str(exported / C.MANIFEST_NAME), "--frames", "2", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"export-size {exported} (48x32)" in printed and "| as exported: float32, STMap copy, ZIP | 16 |" in printed
    report = json.loads(out.read_text())
    assert report["tool"] == "export-size" and len(report["rows"]) == len(VARIANTS)
    with pytest.raises(InputError, match="holds no pass files"):
        measure_export_size(tmp_path)
