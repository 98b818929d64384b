"""The bits the pass files keep (``export --pass-precision``): compact (the default) rounds alpha and coverage to half
float's precision and u, v to multiples of 2^-17, in float32 channels; full keeps every bit. The manifest and a
staged export's record say which; the values of the two differ by no more than the rounding. The STMap copy
(``export --stmap``) is chosen, recorded and staged the same way."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from engine import contract as C
from engine.edit.render import render_manifest
from engine.errors import InputError
from engine.export import exporter
from engine.export.pass_files import kept_precision
from engine.io.images import read_exr, write_png
from engine.terms.cli import (
    EXPORT_INTO_ARG,
    EXPORT_PASS_PRECISION_ARG,
    EXPORT_STAGE_ARG,
    EXPORT_STAGES,
    EXPORT_STMAP_FLAG,
)
from engine.terms.export_names import EXR_LAYER, PASS_PRECISION_COMPACT, PASS_PRECISION_FULL, PASS_UV_STEP, PASSES_DIR
from engine.terms.manifest import validate_manifest
from tests.engine.export.tiny_run import ATLAS_SIZE, copy_root, make_run
from tests.engine_cli import run_cli

#: Half float's largest step in 0..1 is 2^-11 (between 0.5 and 1): rounding towards zero moves a value by less.
HALF_ERROR = 2.0**-11
UV_ERROR = PASS_UV_STEP / 2
SIZE = ("--atlas-size", str(ATLAS_SIZE))


def test_compact_rounds_by_at_most_half_a_step_and_full_keeps_every_bit():
    rng = np.random.default_rng(0)
    u, v = (rng.uniform(-0.5, 1.5, 10_000).astype(np.float32) for _ in range(2))
    alpha = rng.uniform(0, 1, 10_000).astype(np.float32)
    alpha[:3] = (0.0, 1.0, 1e-7)
    coverage = alpha * (rng.uniform(0, 1, 10_000) > 0.3)
    u[5], alpha[6] = np.nan, np.nan
    cu, cv, cc, ca = kept_precision(u, v, coverage, alpha, PASS_PRECISION_COMPACT)
    assert all(x.dtype == np.float32 for x in (cu, cv, cc, ca))
    bounds = ((cu, u, UV_ERROR), (cv, v, UV_ERROR), (cc, coverage, HALF_ERROR), (ca, alpha, HALF_ERROR))
    for kept, given, bound in bounds:
        both = np.isfinite(given)
        assert np.array_equal(np.isnan(kept), np.isnan(given))
        assert 0 < np.abs(kept[both] - given[both]).max() <= bound
    assert np.array_equal((cu[np.isfinite(cu)] / PASS_UV_STEP) % 1, np.zeros(np.isfinite(cu).sum()))
    assert ca[:2].tolist() == [0.0, 1.0] and ca[2] > 0  # the ends stay exact; a tiny opacity is not lost
    assert (ca[np.isfinite(ca)] <= alpha[np.isfinite(alpha)]).all() and (cc <= coverage).all()  # never rounded up
    assert np.array_equal(cc == 0, coverage == 0)  # no coverage appears or goes
    full = kept_precision(u, v, coverage, alpha, PASS_PRECISION_FULL)
    assert all(a is b for a, b in zip(full, (u, v, coverage, alpha), strict=True))
    with pytest.raises(ValueError, match="unknown pass precision"):
        kept_precision(u, v, coverage, alpha, "half")


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    root = tmp_path_factory.mktemp("pass_precision") / "root"
    make_run(root)
    return root


def _export(run: Path, *args: str) -> tuple[int, list[str]]:
    return run_cli("export", run, "--no-bar", *SIZE, *args)


def _passes(export: Path) -> dict[str, dict[str, np.ndarray]]:
    return {p.name: read_exr(p) for p in sorted((export / PASSES_DIR).glob("*.exr"))}


def test_an_export_is_compact_by_default_and_full_on_request(base, tmp_path):
    run = copy_root(base, tmp_path / "root") / "run"
    assert _export(run, EXPORT_STMAP_FLAG) == (0, [])
    assert _export(run, EXPORT_PASS_PRECISION_ARG, PASS_PRECISION_FULL, EXPORT_STMAP_FLAG) == (0, [])
    compact, full = run / C.EXPORTS_DIR / "v001", run / C.EXPORTS_DIR / "v002"
    said = [json.loads((e / C.MANIFEST_NAME).read_text())["passes"]["precision"] for e in (compact, full)]
    assert said == [PASS_PRECISION_COMPACT, PASS_PRECISION_FULL]
    a, b = _passes(compact), _passes(full)
    assert sorted(a) == sorted(b) and len(a) == 4
    for name in a:
        assert sorted(a[name]) == sorted(b[name])
        for channel, kept in a[name].items():
            given = b[name][channel]
            assert kept.dtype == given.dtype == np.float32, channel
            uv = channel.endswith((".U", ".V", ".R", ".G")) and not channel.startswith(f"{EXR_LAYER}.Alpha")
            error = np.abs(kept.astype(np.float64) - given).max()
            assert error <= (UV_ERROR if uv else HALF_ERROR), (channel, error)
    # the STMap copy is the UV pass's own values, rounded alike
    first = a[sorted(a)[0]]
    layer = json.loads((compact / C.MANIFEST_NAME).read_text())["layers"][1]
    uv_channels = [C.channel_name(layer["uv_pass"], c) for c in C.UV_CHANNELS]
    for stmap, uv in zip(layer["stmap_channels"][:2] + layer["stmap_channels"][3:], uv_channels, strict=True):
        assert np.array_equal(first[stmap], first[uv])
    size = [sum(p.stat().st_size for p in (e / PASSES_DIR).glob("*.exr")) for e in (compact, full)]
    assert size[0] < 0.8 * size[1], size
    # `render` reads both: the same paint gives the same frames within the rounding
    edits = {}
    for layer in json.loads((compact / C.MANIFEST_NAME).read_text())["layers"]:
        w, h = layer["atlas_size"]
        paint = np.zeros((h, w, 4), np.float32)
        paint[: h // 2] = (0.9, 0.3, 0.1, 1.0)
        edits[layer["name"]] = str(write_png(tmp_path / f"{layer['name']}.png", paint, 8))
    frames = []
    for export in (compact, full):
        out = render_manifest(export / C.MANIFEST_NAME, tmp_path / export.name, edits, progress_bar=False)
        frames.append([read_exr(p) for p in sorted(Path(out).glob("*.exr"))])
    assert len(frames[0]) == 4
    for a_frame, b_frame in zip(*frames, strict=True):
        error = max(np.abs(a_frame[c] - b_frame[c]).max() for c in "RGB")
        assert error < 2e-3, error  # an alpha's 2.4e-4 and a 0.03-texel shift of the paint's edge


def test_a_staged_export_keeps_the_precision_its_atlases_stage_chose(base, tmp_path):
    run = copy_root(base, tmp_path / "root") / "run"
    into = (EXPORT_INTO_ARG, "v004")
    stage = EXPORT_STAGE_ARG
    full = (EXPORT_PASS_PRECISION_ARG, PASS_PRECISION_FULL)
    assert _export(run, *into, stage, EXPORT_STAGES[0], *full) == (0, [])
    record = json.loads((run / C.EXPORTS_DIR / ".v004.chunks" / exporter.STAGE_RECORD).read_text())
    assert record["precision"] == PASS_PRECISION_FULL
    code, err = _export(run, *into, stage, EXPORT_STAGES[1], EXPORT_PASS_PRECISION_ARG, PASS_PRECISION_COMPACT)
    assert code == C.EXIT_BAD_INPUT and len(err) == 1
    assert f"staged with {EXPORT_PASS_PRECISION_ARG} full, not compact" in err[0] and exporter.STAGE_RECORD in err[0]
    assert _export(run, *into, stage, EXPORT_STAGES[1]) == (0, [])  # asked nothing: the record's
    assert _export(run, *into, stage, EXPORT_STAGES[2]) == (0, [])
    manifest = json.loads((run / C.EXPORTS_DIR / "v004" / C.MANIFEST_NAME).read_text())
    assert manifest["passes"]["precision"] == PASS_PRECISION_FULL
    with pytest.raises(SystemExit):  # argparse's own refusal, naming the choices
        _export(run, EXPORT_PASS_PRECISION_ARG, "half")
    with pytest.raises(InputError, match="unknown --pass-precision 'half'"):
        exporter.export_run(run, precision="half", progress_bar=False)


def test_a_record_or_manifest_from_before_the_choice_reads_as_full(base, tmp_path):
    from engine.export.plan import Plan
    from engine.export.stage_record import read_stage
    from engine.fit.run_folder import RunFolder

    run = copy_root(base, tmp_path / "root") / "run"
    assert _export(run, EXPORT_INTO_ARG, "v002", EXPORT_STAGE_ARG, EXPORT_STAGES[0]) == (0, [])
    path = run / C.EXPORTS_DIR / ".v002.chunks" / exporter.STAGE_RECORD
    record = json.loads(path.read_text())
    assert record.pop("precision") == PASS_PRECISION_COMPACT and record.pop("stmap") is False
    path.write_text(json.dumps(record))
    before = Plan.from_record(read_stage(path.parent), RunFolder(run).read_clip())
    assert before.precision == PASS_PRECISION_FULL and before.stmap  # what exports wrote before the choices
    path.write_text(json.dumps({**record, "precision": "half"}))
    code, err = _export(run, EXPORT_INTO_ARG, "v002", EXPORT_STAGE_ARG, EXPORT_STAGES[1])
    assert code == C.EXIT_BAD_INPUT and len(err) == 1 and "pass precision 'half'" in err[0]
    assert _export(run) == (0, [])
    manifest = json.loads((run / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME).read_text())
    del manifest["passes"]["precision"]
    assert validate_manifest(manifest)["passes"].get("precision", PASS_PRECISION_FULL) == PASS_PRECISION_FULL
    manifest["passes"]["precision"] = "half"
    with pytest.raises(C.ManifestError, match="unknown precision 'half'"):
        validate_manifest(manifest)


def test_a_staged_export_keeps_the_stmap_choice_of_its_atlases_stage(base, tmp_path):
    """``--stmap`` asked in the atlases stage: every chunk writes the copy and the manifest names it; a chunk that
    asks for it on a stage made without it is refused in one line."""
    run = copy_root(base, tmp_path / "root") / "run"
    stage = EXPORT_STAGE_ARG
    assert _export(run, EXPORT_INTO_ARG, "v001", stage, EXPORT_STAGES[0]) == (0, [])
    code, err = _export(run, EXPORT_INTO_ARG, "v001", stage, EXPORT_STAGES[1], EXPORT_STMAP_FLAG)
    assert code == C.EXIT_BAD_INPUT and len(err) == 1
    assert "staged without the STMap copy" in err[0] and exporter.STAGE_RECORD in err[0]
    assert _export(run, EXPORT_INTO_ARG, "v002", stage, EXPORT_STAGES[0], EXPORT_STMAP_FLAG) == (0, [])
    assert _export(run, EXPORT_INTO_ARG, "v002", stage, EXPORT_STAGES[1]) == (0, [])  # asked nothing: the record's
    assert _export(run, EXPORT_INTO_ARG, "v002", stage, EXPORT_STAGES[2]) == (0, [])
    export = run / C.EXPORTS_DIR / "v002"
    layers = json.loads((export / C.MANIFEST_NAME).read_text())["layers"]
    for chans in _passes(export).values():
        for layer in layers:
            u, v, coverage = (chans[C.channel_name(layer["uv_pass"], c)] for c in C.UV_CHANNELS)
            r, g, b, a = (chans[name] for name in layer["stmap_channels"])
            assert np.array_equal(r, u) and np.array_equal(g, v) and np.array_equal(a, coverage) and not b.any()
