"""The run folder's files against their versioned schemas (engine.fit.run_files.validate_run_file): what a fit writes
reads back exactly, and a file of another version, damaged or edited by hand is ONE line naming the file and the fix."""

from __future__ import annotations

import dataclasses
import json

import pytest
import torch

from engine import contract as C
from engine.config import preset_config
from engine.errors import InputError
from engine.fit import run_files
from engine.fit.run_folder import ClipRecord, RunFolder
from engine.terms.colour import COLOUR_SOURCE_ASSUMED
from engine.terms.run_folder import (
    RUN_CHECKPOINT_KEYS,
    RUN_CHECKPOINT_SCHEMA,
    RUN_CLIP,
    RUN_CLIP_SCHEMA,
    RUN_FILE_DAMAGED_FIX,
    RUN_METRICS_SCHEMA,
)
from engine.terms.versions import ENGINE_VERSION

RECORD = ClipRecord(
    source="/plates/shot",
    kind="sequence",
    frame_range=(2, 4),
    frame_numbers=(1002, 1003, 1004),
    frame_files=("/plates/shot/f.1002.exr", "/plates/shot/f.1003.exr", "/plates/shot/f.1004.exr"),
    native_size=(1920, 1080),
    working_size=(768, 432),
    fps=None,
    colorspace="linear",
    masks=("/plates/mask",),
    scribbles=None,
    layers=2,
    fingerprint="0123abcd",
    colour_source=COLOUR_SOURCE_ASSUMED,
    flow_key="0123456789abcdef" * 4,
    scribbles_fingerprint="89abcdef",
)
METRICS = {
    "psnr": 27.5,
    "mse": 0.0018,
    "alpha_iou": [0.91],
    "steps": 800,
    "train_seconds": 106.0,
    "seconds_per_step": 0.1325,
    "preset": "draft",
    "model": "fast",
    "device": "cpu",
    "working_size": [768, 432],
    "frames": 3,
    "engine_version": ENGINE_VERSION,
    "torch_version": torch.__version__,
}


def _one_line(err: pytest.ExceptionInfo, path, *needles: str) -> None:
    text = str(err.value)
    assert text.startswith(f"{path}: ") and "\n" not in text and " — " in text, text
    for n in needles:
        assert n in text, text


def test_what_is_written_reads_back(tmp_path):
    run = RunFolder(tmp_path)
    cfg = preset_config("draft")
    run.write_config(cfg)
    run.write_clip(RECORD)
    run.write_metrics(METRICS)
    assert run.read_config() == cfg
    assert run.read_clip() == RECORD and run.read_clip().num_frames == 3
    assert run.read_metrics() == {"schema": RUN_METRICS_SCHEMA, **METRICS}
    data = json.loads(run.clip.read_text())
    written = {"schema", *run_files.RUN_FILE_FIELDS[RUN_CLIP], *run_files.RUN_CLIP_OPTIONAL_FIELDS}
    assert data["schema"] == RUN_CLIP_SCHEMA and set(data) == written
    assert RunFolder(tmp_path / "nothing").read_metrics() is None  # an unfinished fit has none


@pytest.mark.parametrize(
    ("edit", "needles"),
    [
        (lambda d: d.update(schema=1), ("clip record schema 1 is not supported (this engine writes 2)", "new run")),
        (lambda d: d.pop("layers"), ("clip record has no 'layers'", "restore it")),
        (lambda d: d.update(native_size=[1920]), ("'native_size' is not an int pair",)),
        (lambda d: d.update(fps="25"), ("'fps' is not a number or null",)),
        (lambda d: d.update(frame_range=[2, 9]), ("frame_range 2..9 does not span its 3 frames",)),
        (lambda d: d.update(frame_files=["/a.exr"]), ("1 frame files for 3 frames",)),
        (lambda d: d.update(kind="stream"), ("unknown kind",)),
        (lambda d: d.update(layers=0), ("layers and sizes must be positive",)),
        (lambda d: d.update(rate=[24000]), ("'rate' is not an int pair or null",)),
        (lambda d: d.update(rate=[24000, 0]), ("rate [24000, 0] is not a positive fraction",)),
        (lambda d: d.update(pixel_aspect=-2.0), ("pixel_aspect -2.0 is not a positive number",)),
        (lambda d: d.update(timecode="1:00:00"), ("timecode '1:00:00' is not HH:MM:SS:FF",)),
        (lambda d: d.update(start_frame=-1), ("start_frame is negative",)),
        (lambda d: d.update(flow_key="../../other/flow"), ("flow_key is not the name of a flow cache file",)),
        (lambda d: d.update(flow_key=7), ("'flow_key' is not a str or null",)),
    ],
)
def test_a_clip_record_off_its_schema_is_one_line(tmp_path, edit, needles):
    run = RunFolder(tmp_path)
    data = RECORD.to_dict()
    edit(data)
    run.clip.write_text(json.dumps(data))
    with pytest.raises(InputError) as err:
        run.read_clip()
    _one_line(err, run.clip, *needles)


def test_the_plate_timing_reads_back_and_a_record_written_before_it_reads_as_before(tmp_path):
    """rate, pixel_aspect, timecode, start_frame and flow_key are optional: clip.json of schema 2 without them (what
    the engine wrote before it kept them) reads as square pixels, no exact rate or timecode, a movie from 0, and no
    flow key (the export finds the fit's flow by the key of the plate it fitted)."""
    run = RunFolder(tmp_path)
    timed = dataclasses.replace(RECORD, rate=(24000, 1001), pixel_aspect=2.0, timecode="01:00:00:00", start_frame=0)
    run.write_clip(timed)
    assert run.read_clip() == timed and json.loads(run.clip.read_text())["rate"] == [24000, 1001]
    old = {k: v for k, v in RECORD.to_dict().items() if k not in run_files.RUN_CLIP_OPTIONAL_FIELDS}
    run.clip.write_text(json.dumps(old))
    back = run.read_clip()
    assert back == dataclasses.replace(RECORD, flow_key=None, scribbles_fingerprint=None)
    assert (back.rate, back.pixel_aspect, back.timecode, back.start_frame) == (None, 1.0, None, 0)
    assert back.frame_range == (2, 4) and back.frame_numbers == (1002, 1003, 1004)  # positions and plate numbers


def test_damaged_or_missing_files_are_one_line(tmp_path):
    run = RunFolder(tmp_path)
    with pytest.raises(InputError) as err:
        run.read_config()
    _one_line(err, run.config, "no fit to resume here — run `fit` without --resume first")
    with pytest.raises(InputError) as err:
        run.read_clip()
    _one_line(err, run.clip, "no record of its clip")
    run.metrics.write_text('{"schema": 1, "psnr": ')
    with pytest.raises(InputError) as err:
        run.read_metrics()
    _one_line(err, run.metrics, "not valid JSON — restore it")
    run.metrics.write_text(json.dumps({"schema": 1, **METRICS, "steps": "800"}))
    with pytest.raises(InputError) as err:
        run.read_metrics()
    _one_line(err, run.metrics, "metrics 'steps' is not an int")
    with pytest.raises(InputError) as err:
        run.read_scene()
    _one_line(err, run.scene, "no scene analysis", "fit into a new --out")
    with pytest.raises(InputError) as err:
        run.require_fit()
    _one_line(err, run.config, "this is not a fitted run folder — pass the --out folder of a `fit`")


def test_config_of_another_version_says_so(tmp_path):
    """The message docs/robustness.md shows for a --resume of a run with config schema 0."""
    run = RunFolder(tmp_path)
    run.write_config(preset_config("draft"))
    data = json.loads(run.config.read_text())
    data["schema"] = 0
    run.config.write_text(json.dumps(data))
    with pytest.raises(InputError) as err:
        run.read_config()
    _one_line(
        err,
        run.config,
        "config schema 0 is not supported (this engine writes 1) — fit into a new run folder or use the engine "
        "version that made this run",
    )


def test_an_engine_bug_never_writes_a_file_off_its_schema(tmp_path):
    run = RunFolder(tmp_path)
    with pytest.raises(InputError, match="metrics has no 'frames'"):
        run.write_metrics({k: v for k, v in METRICS.items() if k != "frames"})
    assert not run.metrics.exists()


#: A checkpoint with every key of its schema, of the types the readers check (no model behind it).
CHECKPOINT = {
    "model": {"w": torch.zeros(2)},
    "optim": {},
    "sched": {},
    "gen": torch.Generator().get_state(),
    "step": 0,
    "train_seconds": 0.0,
    "fingerprint": RECORD.fingerprint,
    "config": {},
    "motions": None,
}


def test_checkpoint_keys_and_version_are_checked(tmp_path):
    run = RunFolder(tmp_path)
    cpu = torch.device("cpu")
    assert set(CHECKPOINT) | {"schema"} == set(RUN_CHECKPOINT_KEYS)
    state = dict(CHECKPOINT)
    run.save_checkpoint(state)
    assert run.load_checkpoint(cpu)["schema"] == RUN_CHECKPOINT_SCHEMA
    run.save_checkpoint({**state, "schema": 99})
    with pytest.raises(InputError) as err:
        run.load_checkpoint(cpu)
    _one_line(err, run.checkpoint, "checkpoint schema 99 is not supported")
    del state["motions"]
    run.save_checkpoint(state)
    with pytest.raises(InputError) as err:
        run.load_checkpoint(cpu)
    _one_line(err, run.checkpoint, "checkpoint has no 'motions'")


def test_the_contract_validates_without_the_engine():
    """The schemas live in the contract (standard library only): what the add-on could check on its own."""
    assert run_files.validate_run_file(RUN_CLIP, RECORD.to_dict())["layers"] == 2
    with pytest.raises(run_files.RunFileError) as err:
        run_files.validate_run_file(C.RUN_METRICS, [1, 2])
    assert err.value.problem == "metrics is not a JSON object" and err.value.fix == RUN_FILE_DAMAGED_FIX
    assert run_files.validate_run_file(C.RUN_METRICS, {"schema": 1, **METRICS, "psnr": float("inf")})  # a perfect fit
    with pytest.raises(run_files.RunFileError, match="'steps' is not an int"):
        run_files.validate_run_file(C.RUN_METRICS, {"schema": 1, **METRICS, "steps": True})


@pytest.mark.parametrize(
    ("edit", "needles"),
    [
        (lambda s: s.update(step="12"), ("checkpoint 'step' is damaged", "--refit")),
        (lambda s: s.update(gen=[1, 2]), ("checkpoint 'gen' is damaged",)),
        (lambda s: s.update(model={"w": torch.tensor([1.0, float("nan")])}), ("NaN/Inf values (model/w)",)),
    ],
)
def test_a_damaged_checkpoint_is_one_line(tmp_path, edit, needles):
    run = RunFolder(tmp_path)
    state = dict(CHECKPOINT)
    edit(state)
    run.save_checkpoint(state)
    with pytest.raises(InputError) as err:
        run.load_checkpoint(torch.device("cpu"))
    _one_line(err, run.checkpoint, *needles)
