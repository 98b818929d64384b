"""A staged export never mixes two fits: the atlases stage records the fit it was made from (the digests of
``checkpoint.pt`` and ``config.json``), and every later stage run after the fit changed (``fit --refine``) refuses
in one line, exit 2, naming the staging folder and the fix; the farm's plan then takes a new version, and that
version, staged from the refined fit, publishes. Every test hashes the tree around the run before and after."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from engine import contract as C
from engine.errors import InputError
from engine.export import exporter, stage_record
from engine.farm.plan import next_version
from engine.terms.cli import EXPORT_INTO_ARG, EXPORT_STAGE_ARG, EXPORT_STAGES
from engine.terms.export_names import EXPORT_CHUNKS_SUFFIX
from engine.terms.run_folder import RUN_CONFIG
from tests.engine.export.tiny_run import ATLAS_SIZE, copy_root, make_run
from tests.engine_cli import run_cli
from tests.folders import tree_digest
from tests.untouched import digest_outside

INTO, STAGE = EXPORT_INTO_ARG, EXPORT_STAGE_ARG
ATLASES, PASSES, PUBLISH = EXPORT_STAGES
SIZE = ("--atlas-size", str(ATLAS_SIZE))


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """A tiny fitted run (frames 0-3) under ``root``."""
    root = tmp_path_factory.mktemp("export_stage_fit") / "root"
    make_run(root)
    return root


@pytest.fixture
def root(base, tmp_path):
    return copy_root(base, tmp_path / "root")


def _export(run: Path, *args: str) -> tuple[int, list[str]]:
    return run_cli("export", run, "--no-bar", *args)


def _other_fit_line(chunks: Path, version: str, free: str) -> str:
    return (
        f"error: {chunks}: {version} was staged from another fit ({C.RUN_CHECKPOINT} and {RUN_CONFIG} changed since "
        f"its atlases were made: a fit --refine or --refit), and one version never mixes frames of two fits — stage "
        f"this fit as a new version ({INTO} {free} {STAGE} {ATLASES}; a farm job submitted again takes a new version "
        f"itself), or delete {chunks.name} to stage {version} again from this fit"
    )


def test_a_refine_between_chunks_stops_the_staged_version_and_a_new_one_takes_the_refined_fit(root):
    run = root / "run"
    chunks = run / C.EXPORTS_DIR / f".v001{EXPORT_CHUNKS_SUFFIX}"
    outside = digest_outside(root.parent, run)
    assert _export(run, INTO, "v001", STAGE, ATLASES, *SIZE) == (0, [])
    assert _export(run, INTO, "v001", STAGE, PASSES, "--frames", "0-1") == (0, [])
    record = json.loads((chunks / stage_record.STAGE_RECORD).read_text(encoding="utf-8"))
    assert record["source"] == stage_record.fit_source(run)

    code, err = run_cli("fit", "--out", run, "--refine", "2", "--no-bar")
    assert code == 0, err
    staged = tree_digest(chunks)
    refused = (C.EXIT_BAD_INPUT, [_other_fit_line(chunks, "v001", "v002")])
    assert _export(run, INTO, "v001", STAGE, PASSES, "--frames", "2-3") == refused
    assert _export(run, INTO, "v001", STAGE, PUBLISH) == refused
    assert _export(run, INTO, "v001", STAGE, ATLASES, *SIZE) == refused
    assert tree_digest(chunks) == staged and not (run / C.EXPORTS_DIR / "v001").exists()

    # the farm submitted again: the plan leaves v001 and stages the refined fit as v002, which publishes
    assert next_version(run) == "v002"
    assert _export(run, INTO, "v002", STAGE, ATLASES, *SIZE) == (0, [])
    assert _export(run, INTO, "v002", STAGE, PASSES, "--frames", "0-3") == (0, [])
    assert _export(run, INTO, "v002", STAGE, PUBLISH) == (0, [])
    manifest = json.loads((run / C.EXPORTS_DIR / "v002" / C.MANIFEST_NAME).read_text(encoding="utf-8"))
    metrics = json.loads((run / C.RUN_METRICS).read_text(encoding="utf-8"))
    assert manifest["fit"]["steps"] == metrics["steps"] == 14  # 12 steps, then 2 more
    assert tree_digest(chunks) == staged
    assert digest_outside(root.parent, run) == outside


def test_the_plan_continues_a_staged_version_of_the_same_fit(root):
    run = root / "run"
    outside = digest_outside(root.parent, run)
    assert next_version(run) == "v001"
    assert _export(run, INTO, "v001", STAGE, ATLASES, *SIZE) == (0, [])
    assert next_version(run) == "v001"  # an interrupted submission is picked up, as before
    (run / C.EXPORTS_DIR / f".v001{EXPORT_CHUNKS_SUFFIX}" / stage_record.STAGE_RECORD).write_text("{", "utf-8")
    assert next_version(run) == "v002"  # a damaged record is left alone
    assert digest_outside(root.parent, run) == outside


def test_a_fit_changed_while_a_chunk_loads_it_writes_no_pass(root, monkeypatch):
    """The passes stage holds no lock (chunks run on several hosts at once): the fit is checked again once loaded,
    so a refine that replaced it meanwhile stops the chunk before it writes a frame."""
    run = root / "run"
    chunks = run / C.EXPORTS_DIR / f".v001{EXPORT_CHUNKS_SUFFIX}"
    assert _export(run, INTO, "v001", STAGE, ATLASES, *SIZE) == (0, [])
    outside, staged = digest_outside(root.parent, run), tree_digest(chunks)
    load = exporter.load_fitted

    def load_then_refit(run_dir, device_name):  # type: ignore[no-untyped-def]
        fitted = load(run_dir, device_name)
        config = Path(run_dir) / RUN_CONFIG
        config.write_text(config.read_text(encoding="utf-8") + "\n", encoding="utf-8")
        return fitted

    monkeypatch.setattr(exporter, "load_fitted", load_then_refit)
    with pytest.raises(InputError) as info:
        exporter.export_run(run, into="v001", stage=PASSES, progress_bar=False, stream=None)
    assert str(info.value) == _other_fit_line(chunks, "v001", "v002").removeprefix("error: ").replace(
        f"{C.RUN_CHECKPOINT} and {RUN_CONFIG}", RUN_CONFIG
    )
    assert tree_digest(chunks) == staged and digest_outside(root.parent, run) == outside


def test_a_stage_record_of_an_earlier_engine_is_refused_in_one_line(root):
    """A record without ``source`` cannot say what it was made from: it is not continued."""
    run = root / "run"
    chunks = run / C.EXPORTS_DIR / f".v001{EXPORT_CHUNKS_SUFFIX}"
    assert _export(run, INTO, "v001", STAGE, ATLASES, *SIZE) == (0, [])
    path = chunks / stage_record.STAGE_RECORD
    old = json.loads(path.read_text(encoding="utf-8"))
    del old["source"]
    path.write_text(json.dumps({**old, "schema": stage_record.STAGE_SCHEMA_WITHOUT_SOURCE}), encoding="utf-8")
    outside, staged = digest_outside(root.parent, run), tree_digest(chunks)
    code, err = _export(run, INTO, "v001", STAGE, PASSES, "--frames", "0-1")
    assert (code, err) == (
        C.EXIT_BAD_INPUT,
        [
            f"error: {path}: this staged export does not record the fit it was made from (an earlier engine staged "
            f"it) — {stage_record.DAMAGED_FIX}"
        ],
    )
    assert tree_digest(chunks) == staged and digest_outside(root.parent, run) == outside


GOOD_STAGE = {
    "schema": stage_record.STAGE_SCHEMA,
    "frames": [0, 3],
    "atlas_size": 64,
    "layers": [{"name": "Background", "atlas_box": [-1.0, -1.0, 1.0, 1.0], "atlas_size": [64, 64]}],
    "source": {key: "0" * 64 for key in stage_record.SOURCE_FILES},
    "follow_flow": True,
    "follows": [0],
}


@pytest.mark.parametrize(
    ("change", "said"),
    [
        ({"atlas_size": "64"}, "staged export record 'atlas_size' is not an int: '64'"),
        ({"frames": [0]}, "staged export record 'frames' is not an int pair"),
        ({"follows": [3]}, "it follows layers [3] of its 1"),
        ({"source": {"checkpoint_sha256": "0"}}, "its source names ['checkpoint_sha256'], not the digests of"),
        ({"layers": [{"name": "B", "atlas_box": [0, 0, 1], "atlas_size": [1, 1]}]}, "'layers' is not a layer list"),
        ({"source": {key: 1 for key in stage_record.SOURCE_FILES}}, "'source' is not a dict of str"),
        ({"extra": 1}, "staged export record has an unknown key 'extra'"),
        ({"schema": "other/9"}, "staged export record of schema 'other/9'"),
    ],
)
def test_a_stage_record_is_checked_field_by_field_in_one_line(tmp_path, change, said):
    """Every field of ``stage.json`` has its type in one declaration (``stage_record.StageFile``); what is wrong is
    named in one line with the fix, and a good record reads back as it was written."""
    path = tmp_path / stage_record.STAGE_RECORD
    path.write_text(json.dumps(GOOD_STAGE), encoding="utf-8")
    read = stage_record.read_stage(tmp_path)
    assert read is not None
    assert {"schema": stage_record.STAGE_SCHEMA, **read.model_dump(exclude_unset=True)} == GOOD_STAGE
    path.write_text(json.dumps({**GOOD_STAGE, **change}), encoding="utf-8")
    with pytest.raises(InputError) as info:
        stage_record.read_stage(tmp_path)
    assert said in str(info.value) and stage_record.DAMAGED_FIX in str(info.value) and "\n" not in str(info.value)
