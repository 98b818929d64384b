"""Submit to Farm without Blender (``core.farm``): the shots file of one shot, the shot's name and colour space,
the online-access rule, the Manager's URL, the bundle folders, the engine's command lines, and the job's one-line
result with a stand-in engine."""

from __future__ import annotations

import json
import os
import time
from dataclasses import replace
from pathlib import Path

import pytest
from helpers import fake_python
from neural_atlas.addon.core import engine_process as EP
from neural_atlas.addon.core import farm as FM
from neural_atlas.addon.core.engine_setup import ONLINE_ACCESS_SETTING
from neural_atlas.addon.core.errors import UserError

from engine import contract as C
from engine.terms.farm import SHOT_DEFAULT_KEYS


def _shot(tmp_path: Path, masks: tuple[str, ...] = ("/m/layer1",), colorspace: str | None = "ACEScg") -> FM.FarmShot:
    return FM.FarmShot(
        name="sh010",
        plate="/plates/sh010.####.exr",
        masks=masks,
        first=1001,
        last=1048,
        preset="draft",
        sets=FM.set_items(512, "steps=30 'lr=0.01'"),
        run_dir=str(tmp_path / "run"),
        colorspace=colorspace,
    )


def test_the_shots_file_of_one_shot(tmp_path):
    doc = FM.shots_document(_shot(tmp_path, masks=("/m/layer1", "/m/layer2")))
    assert doc == {
        C.SHOTS_TAG: C.SHOTS_VERSION,
        C.SHOTS_DEFAULTS_KEY: {"preset": "draft", "set": ["long_edge=512", "steps=30", "lr=0.01"]},
        C.SHOTS_LIST_KEY: [
            {
                "name": "sh010",
                "plate": "/plates/sh010.####.exr",
                "masks": ["/m/layer1", "/m/layer2"],
                "frames": "1001-1048",
                "colorspace": "ACEScg",
                "run": str(tmp_path / "run"),
            }
        ],
    }
    assert set(doc[C.SHOTS_DEFAULTS_KEY]) <= set(SHOT_DEFAULT_KEYS)
    assert set(doc[C.SHOTS_LIST_KEY][0]) <= set(C.SHOT_KEYS)


def test_follow_flow_off_is_written_in_the_shots_files_defaults(tmp_path):
    doc = FM.shots_document(replace(_shot(tmp_path), follow_flow=False))
    assert doc[C.SHOTS_DEFAULTS_KEY]["follow_flow"] is False
    assert set(doc[C.SHOTS_DEFAULTS_KEY]) <= set(SHOT_DEFAULT_KEYS)


def test_no_masks_means_auto_masks_and_no_colour_space_means_the_engines_rules(tmp_path):
    (entry,) = FM.shots_document(_shot(tmp_path, masks=(), colorspace=None))[C.SHOTS_LIST_KEY]
    assert entry["auto_masks"] is True and "masks" not in entry and "colorspace" not in entry


def test_written_shots_file_reads_back_and_replaces_the_last(tmp_path):
    path = str(tmp_path / "run.farm" / "shots.json")
    assert FM.write_shots_file(_shot(tmp_path), path) == path
    assert json.loads(Path(path).read_text()) == FM.shots_document(_shot(tmp_path))
    FM.write_shots_file(_shot(tmp_path, masks=()), path)
    assert json.loads(Path(path).read_text())[C.SHOTS_LIST_KEY][0]["auto_masks"] is True
    assert os.listdir(tmp_path / "run.farm") == ["shots.json"]  # no temporary file left


@pytest.mark.parametrize(
    ("clip", "sequence", "name"),
    [
        ("sh010_plate.1001.exr", True, "sh010_plate"),
        ("plate.####.exr", True, "plate"),
        ("plate_0001.png", True, "plate"),
        ("00000.png", True, "00000"),
        ("interview take 2.mov", False, "interview_take_2"),
        ("sh020_01.mp4", False, "sh020_01"),
        ("...", True, FM.FALLBACK_SHOT_NAME),
        ("_" + "a" * 70 + ".mov", False, "a" * FM.SHOT_NAME_MAX),
    ],
)
def test_shot_name_from_the_clips_name(clip, sequence, name):
    assert FM.shot_name(clip, sequence) == name


def test_colour_space_in_the_engines_words():
    assert FM.engine_colorspace("sRGB") == C.COLOUR_SRGB
    assert FM.engine_colorspace("Linear Rec.709") == C.COLOUR_SCENE_LINEAR
    assert FM.engine_colorspace("ACEScg") == "ACEScg"
    assert FM.engine_colorspace("AgX Log") is None


def test_online_access_gates_flamenco_only():
    assert FM.online_refusal(FM.FARM_FLAMENCO, True, False) == ""
    assert FM.online_refusal(FM.FARM_OPENJD, False, False) == ""
    assert FM.online_refusal(FM.FARM_OPENJD, False, True) == ""
    off = FM.online_refusal(FM.FARM_FLAMENCO, False, False)
    assert off.startswith("Submit to Farm: online access is off in Blender") and ONLINE_ACCESS_SETTING in off
    assert "OpenJD" in off and "\n" not in off
    forced = FM.online_refusal(FM.FARM_FLAMENCO, False, True)
    assert "--offline-mode" in forced and "OpenJD" in forced


def test_manager_url(tmp_path):
    assert FM.check_manager_url(" http://farm:8080/ ") == "http://farm:8080"
    assert FM.check_manager_url("https://flamenco.studio.lan") == "https://flamenco.studio.lan"
    for bad in ("", "farm:8080", "ftp://farm", "http://"):
        with pytest.raises(UserError, match="is not an http\\(s\\) address: set it in the add-on's preferences"):
            FM.check_manager_url(bad)


def test_bundle_folders_are_never_reused(tmp_path):
    run = str(tmp_path / "run")
    beside = FM.FarmSettings(FM.FARM_OPENJD)
    assert FM.fresh_bundle_dir(beside, run, "sh010") == str(tmp_path / "run.farm" / "openjd")
    (tmp_path / "run.farm" / "openjd").mkdir(parents=True)
    assert FM.fresh_bundle_dir(beside, run, "sh010") == str(tmp_path / "run.farm" / "openjd")  # empty: reused
    (tmp_path / "run.farm" / "openjd" / "template.json").write_text("{}")
    assert FM.fresh_bundle_dir(beside, run, "sh010") == str(tmp_path / "run.farm" / "openjd_2")
    elsewhere = FM.FarmSettings(FM.FARM_OPENJD, bundle_dir=str(tmp_path / "bundles"))
    assert FM.fresh_bundle_dir(elsewhere, run, "sh010") == str(tmp_path / "bundles" / "sh010" / "openjd")


def test_the_engines_farm_command_lines():
    flamenco = FM.FarmSettings(FM.FARM_FLAMENCO, "http://farm:8080/", 70)
    assert FM.farm_argv("py", flamenco, "/r.farm/shots.json") == [
        "py", "-m", C.CLI_MODULE, C.VERB_FARM, C.FARM_FLAMENCO, "/r.farm/shots.json",
        "--manager", "http://farm:8080", "--priority", "70",
    ]  # fmt: skip
    openjd = FM.FarmSettings(FM.FARM_OPENJD)
    assert FM.farm_argv("py", openjd, "/s.json", "/b") == [
        "py", "-m", C.CLI_MODULE, C.VERB_FARM, C.FARM_OPENJD, "/s.json", "--out", "/b",
    ]  # fmt: skip
    with pytest.raises(UserError, match="no folder for the OpenJD bundle"):
        FM.farm_argv("py", openjd, "/s.json")
    with pytest.raises(UserError, match="unknown farm 'slurm'"):
        FM.farm_argv("py", FM.FarmSettings("slurm"), "/s.json")


def _drive(job: FM.FarmJob) -> EP.JobResult:
    job.start()
    for _ in range(2000):
        if not job.step():
            assert job.result is not None
            return job.result
        time.sleep(0.01)
    raise AssertionError("the job never finished")


def test_job_reports_the_bundle_folder(tmp_path):
    shots = FM.write_shots_file(_shot(tmp_path), str(tmp_path / "run.farm" / "shots.json"))
    bundle = str(tmp_path / "run.farm" / "openjd")
    job = FM.FarmJob(fake_python(tmp_path), FM.FarmSettings(FM.FARM_OPENJD), shots, str(tmp_path / "farm.log"), bundle)
    result = _drive(job)
    assert (result.status, result.message) == (EP.STATUS_OK, f"OpenJD bundle for Deadline Cloud: {bundle}")
    assert sorted(os.listdir(bundle)) == ["parameter_values.json", "template.json"]
    first = Path(job.log_path).read_text().splitlines()[0]
    assert first.endswith(f" -m engine farm openjd {shots} --out {bundle}")


def test_job_reports_the_managers_answer(tmp_path):
    shots = FM.write_shots_file(_shot(tmp_path), str(tmp_path / "shots.json"))
    settings = FM.FarmSettings(FM.FARM_FLAMENCO, "http://farm:8080/", 40)
    result = _drive(FM.FarmJob(fake_python(tmp_path), settings, shots, str(tmp_path / "farm.log")))
    assert result.status == EP.STATUS_OK
    assert result.message == "submitted to Flamenco at http://farm:8080: job fake-0001"


def test_job_passes_the_engines_one_line_error_on(tmp_path, monkeypatch):
    monkeypatch.setenv("FAKE_ENGINE_MODE", "bad_input")
    shots = str(tmp_path / "shots.json")
    settings = FM.FarmSettings(FM.FARM_FLAMENCO)
    result = _drive(FM.FarmJob(fake_python(tmp_path), settings, shots, str(tmp_path / "farm.log")))
    assert result.status == EP.STATUS_BAD_INPUT
    assert result.message == f'{shots}: no shot has a plate — add "plate" to each shot'
