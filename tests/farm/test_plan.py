"""The farm's one plan: every task's exact engine command line and dependencies, from a shots file."""

from __future__ import annotations

import contextlib
import io
import json
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from engine import cli
from engine import contract as C
from engine.errors import InputError
from engine.farm.plan import TASK_KINDS, chunk_ranges, load_plan, next_version
from engine.terms.cli import EXPORT_PASS_PRECISION_ARG, EXPORT_STMAP_FLAG
from engine.terms.export_names import PASS_PRECISION_FULL
from engine.terms.farm import FARM_PLAN
from engine.terms.run_folder import FIT_AUTO_PARTS_FLAG
from engine.terms.versions import SCHEMA_VERSION
from tests.farm.farm_helpers import TINY_SET, two_shot_file, write_clip, write_shots
from tests.media_files import textured_frames, write_movie
from tests.paths import ROOT


@pytest.fixture(scope="module")
def seq(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("seq")
    two_shot_file(folder)
    return folder


def test_two_shots_give_these_command_lines_and_dependencies(seq):
    plan = load_plan(seq / "shots.json")
    a, b = f"{seq}/clips/a", f"{seq}/clips/b"
    run_a, run_b = f"{seq}/runs/sh010", f"{seq}/runs/sh020"
    sets = [x for s in TINY_SET for x in ("--set", s)]
    manifest = f"{run_a}/exports/v001/manifest.json"
    export_a = ["export", run_a, "--into", "v001", "--stage"]
    export_b = ["export", run_b, "--into", "v001", "--stage"]
    expected = [
        ("sh010.fit", ["fit", f"{a}/frames", "--out", run_a, "--resume-if-started", "--preset", "draft", *sets,
                       "--mask", f"{a}/masks", "--frames", "0-4", "--no-bar"], []),
        ("sh010.atlases", [*export_a, "atlases", "--frames", "0-4", "--no-bar"], ["sh010.fit"]),
        ("sh010.passes.0-1", [*export_a, "passes", "--frames", "0-1", "--no-bar"], ["sh010.atlases"]),
        ("sh010.passes.2-3", [*export_a, "passes", "--frames", "2-3", "--no-bar"], ["sh010.atlases"]),
        ("sh010.passes.4-4", [*export_a, "passes", "--frames", "4-4", "--no-bar"], ["sh010.atlases"]),
        ("sh010.publish", [*export_a, "publish", "--no-bar"],
         ["sh010.passes.0-1", "sh010.passes.2-3", "sh010.passes.4-4"]),
        ("sh010.render.0-4", ["render", manifest, "--out", f"{seq}/renders/sh010", "--frames", "0-4", "--no-bar"],
         ["sh010.publish"]),
        ("sh010.preview", ["preview", manifest], ["sh010.publish"]),
        ("sh020.masks", ["masks", f"{b}/frames", "--out", f"{run_b}/auto_masks", "--frames", "1-4"], []),
        ("sh020.fit", ["fit", f"{b}/frames", "--out", run_b, "--resume-if-started", "--preset", "draft", *sets,
                       "--auto-masks", "--frames", "1-4", "--no-bar"], ["sh020.masks"]),
        ("sh020.atlases", [*export_b, "atlases", "--frames", "1-4", "--no-bar"], ["sh020.fit"]),
        ("sh020.passes.1-2", [*export_b, "passes", "--frames", "1-2", "--no-bar"], ["sh020.atlases"]),
        ("sh020.passes.3-4", [*export_b, "passes", "--frames", "3-4", "--no-bar"], ["sh020.atlases"]),
        ("sh020.publish", [*export_b, "publish", "--no-bar"], ["sh020.passes.1-2", "sh020.passes.3-4"]),
    ]  # fmt: skip
    assert [(t.id, list(t.args), list(t.depends)) for t in plan.tasks] == expected
    assert plan.shots == ("sh010", "sh020")
    assert [t.id for t in plan.shot_tasks("sh020")] == [e[0] for e in expected[8:]]
    assert {t.id: t.accelerator for t in plan.tasks if t.accelerator} == {
        t.id: True for t in plan.tasks if t.kind in ("fit", "atlases", "passes")
    }
    assert [t.frames for t in plan.tasks if t.kind == "passes"] == [(0, 1), (2, 3), (4, 4), (1, 2), (3, 4)]
    assert all(t.kind in TASK_KINDS for t in plan.tasks)
    assert plan.tasks[0].argv("/opt/py") == ["/opt/py", "-m", "engine", *plan.tasks[0].args]


def test_every_option_of_a_shot_reaches_its_command(tmp_path):
    write_clip(tmp_path / "c")
    path = write_shots(tmp_path, [{
        "name": "x", "plate": "c/frames", "colorspace": "sRGB Encoded Rec.709 (sRGB)", "fps": 25, "device": "cpu",
        "atlas_size": 64, "render": "out", "render_format": "png", "render_chunk": 2, "frames": "1-3",
        "set": ["seed=2"], "follow_flow": False, "pass_precision": "full", "stmap": True,
    }])  # fmt: skip
    plan = load_plan(path)
    assert C.EXPORT_NO_FOLLOW_FLOW_FLAG in plan.task("x.atlases").args  # the passes and publish follow its record
    atlases = plan.task("x.atlases").args
    assert atlases[atlases.index(EXPORT_PASS_PRECISION_ARG) + 1] == PASS_PRECISION_FULL
    assert EXPORT_PASS_PRECISION_ARG not in plan.task("x.passes.1-3").args
    assert EXPORT_STMAP_FLAG in atlases and EXPORT_STMAP_FLAG not in plan.task("x.passes.1-3").args
    assert C.EXPORT_NO_FOLLOW_FLOW_FLAG not in plan.task("x.passes.1-3").args
    fit = plan.task("x.fit").args
    assert fit[fit.index("--colorspace") + 1] == "sRGB Encoded Rec.709 (sRGB)"
    assert fit[fit.index("--fps") + 1] == "25" and fit[fit.index("--device") + 1] == "cpu"
    assert fit[fit.index("--preset") + 1] == "balanced" and fit[fit.index("--set") + 1] == "seed=2"
    assert "--atlas-size" in plan.task("x.atlases").args and "--device" in plan.task("x.passes.1-3").args
    assert [t.id for t in plan.tasks if t.kind == "render"] == ["x.render.1-2", "x.render.3-3"]
    assert plan.task("x.render.3-3").args[-3:] == ("--format", "png", "--no-bar")


def test_every_command_of_a_plan_is_one_the_engines_parser_reads(tmp_path):
    """Each task's command line parses with the engine's own CLI parser, every option in it as that verb declares
    it (the plan names its flags from the parser: ``cli_parser.verb_flags``), with every optional field of a shot
    given, a movie's start frame and auto masks too."""
    write_clip(tmp_path / "c")
    shots = [
        {"name": "x", "plate": "c/frames", "colorspace": "sRGB Encoded Rec.709 (sRGB)", "fps": 25, "device": "cpu",
         "atlas_size": 64, "render": "out", "render_format": "png", "render_chunk": 2, "frames": "1-3",
         "set": ["seed=2"], "follow_flow": False, "masks": ["c/masks"], "auto_parts": False,
         "pass_precision": "full", "stmap": True},
        {"name": "y", "plate": "c/frames", "auto_masks": True, "preview": True},
    ]  # fmt: skip
    plan = load_plan(write_shots(tmp_path, shots))
    parser = cli.build_parser()
    assert {t.kind for t in plan.tasks} == set(TASK_KINDS)
    for task in plan.tasks:
        with contextlib.redirect_stderr(io.StringIO()) as err:
            try:
                args = parser.parse_args(list(task.args))
            except SystemExit:
                pytest.fail(f"{task.id}: {list(task.args)}: {err.getvalue()}")
        assert args.verb == task.args[0]


def test_auto_parts_reaches_the_fit_only(tmp_path):
    write_clip(tmp_path / "c")
    path = write_shots(tmp_path, [{"name": "x", "plate": "c/frames", "masks": ["c/masks"], "auto_parts": True}])
    plan = load_plan(path)
    assert plan.task("x.fit").args.count(FIT_AUTO_PARTS_FLAG) == 1
    assert all(FIT_AUTO_PARTS_FLAG not in t.args for t in plan.tasks if t.kind != "fit")
    plain = load_plan(write_shots(tmp_path, [{"name": "x", "plate": "c/frames", "masks": ["c/masks"]}]))
    assert not {FIT_AUTO_PARTS_FLAG, C.FIT_NO_AUTO_PARTS_FLAG} & set(plain.task("x.fit").args)  # the fit's default
    off = [{"name": "x", "plate": "c/frames", "masks": ["c/masks"], "auto_parts": False}]
    args = load_plan(write_shots(tmp_path, off)).task("x.fit").args
    assert args.count(C.FIT_NO_AUTO_PARTS_FLAG) == 1 and FIT_AUTO_PARTS_FLAG not in args


def test_a_movie_plate_is_counted_and_numbered_from_its_start_frame(tmp_path):
    movie = write_movie(tmp_path / "plate.mp4", textured_frames(7, (32, 32)))
    path = write_shots(tmp_path, [{"name": "m", "plate": movie.name, "start_frame": 1001, "export_chunk": 4,
                                   "auto_masks": True}])  # fmt: skip
    plan = load_plan(path)
    assert [t.frames for t in plan.tasks if t.kind == "passes"] == [(1001, 1004), (1005, 1007)]
    assert plan.task("m.fit").args[plan.task("m.fit").args.index("--frames") + 1 :][:3] == (
        "1001-1007", "--start-frame", "1001")  # fmt: skip
    # the masks verb numbers a movie's frames from 0
    assert plan.task("m.masks").args[-2:] == ("--frames", "0-6")


def test_a_frame_outside_the_plate_names_the_plates_frames(tmp_path):
    write_clip(tmp_path / "c")
    path = write_shots(tmp_path, [{"name": "x", "plate": "c/frames", "frames": "3-9"}])
    with pytest.raises(InputError, match=r"shot 'x': frame 9 of 'frames' is not in the plate \(its frames are 0..4\)"):
        load_plan(path)


def test_an_empty_plate_folder_is_one_line_naming_the_shot(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"shots.json: shot 'x': plate .*empty"):
        load_plan(write_shots(tmp_path, [{"name": "x", "plate": "empty"}]))


def test_the_export_version_is_the_next_free_one_past_chunked_and_dead_ones(tmp_path):
    run = tmp_path / "run"
    assert next_version(run) == "v001"
    (run / C.EXPORTS_DIR / "v001").mkdir(parents=True)
    assert next_version(run) == "v002"
    (run / C.EXPORTS_DIR / ".v004.chunks").mkdir()
    (run / C.EXPORTS_DIR / "notes").mkdir()
    assert next_version(run) == "v004", "the newest, unfinished chunked export is continued"
    (run / C.EXPORTS_DIR / "v004").mkdir()
    assert next_version(run) == "v005"
    (run / C.EXPORTS_DIR / ".v007.partial").mkdir()
    assert next_version(run) == "v008"
    (run / C.EXPORTS_DIR / ".v009.chunks").mkdir()
    (run / C.EXPORTS_DIR / "v010").mkdir()
    assert next_version(run) == "v011", "an older unfinished chunked export is left as it is"


@given(
    numbers=st.lists(st.integers(0, 10**5), min_size=1, max_size=200, unique=True).map(sorted),
    size=st.integers(1, 60),
)
def test_chunks_cover_every_frame_once_in_order(numbers, size):
    chunks = chunk_ranges(numbers, size)
    covered = [n for a, b in chunks for n in numbers if a <= n <= b]
    assert covered == numbers
    assert all(len([n for n in numbers if a <= n <= b]) <= size for a, b in chunks)
    assert len(chunks) == -(-len(numbers) // size)


def test_farm_plan_json_is_the_plan(seq):
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert cli.main([C.VERB_FARM, FARM_PLAN, str(seq / "shots.json"), "--json"]) == C.EXIT_OK
    printed = json.loads(out.getvalue())
    assert printed == {"schema": SCHEMA_VERSION, **load_plan(seq / "shots.json").to_json()}
    assert printed["tasks"][0]["id"] == "sh010.fit" and printed["tasks"][0]["frames"] is None


def test_the_plan_loads_without_torch(seq):
    script = (
        "import sys\nfrom engine.farm.plan import load_plan\nfrom engine.farm.openjd import write_bundle\n"
        f"load_plan({str(seq / 'shots.json')!r})\nprint(sorted(m for m in ('torch', 'bpy') if m in sys.modules))\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"
