"""What a pipeline TD expects of a command line: no verb is an error (help on stderr, exit 2); -q and -v on the
engine and on every verb; every path said once, last, after one ``written`` message; a finished fit's last
whole-job fraction is 1.0; the colour docs name the built-in config for what it is."""

from __future__ import annotations

import json
import re

import OpenImageIO as oiio
import pytest

from engine import cli
from engine import contract as C
from engine.fit.progress import LineTap, quiet_lines
from engine.terms.run_folder import RUN_CLIP
from tests.paths import ROOT
from tests.td_cli.conftest import run_main


def test_no_verb_prints_the_help_on_stderr_and_exits_2() -> None:
    """Before: the help on stdout and exit 0, so a pipeline that lost its verb succeeded doing nothing."""
    ran = run_main()
    assert (ran.code, ran.out) == (C.EXIT_BAD_INPUT, "")
    assert ran.err.startswith("usage: python -m engine [-h] [--version] [-q] [-v] VERB ...")
    assert "\n    fit " in ran.err and "\n    farm " in ran.err


@pytest.mark.parametrize(
    "argv",
    [["-q", "fit", "c", "--out", "r"], ["fit", "c", "--out", "r", "-q"], ["export", "r", "--quiet"],
     ["farm", "plan", "s", "-v"], ["-v", "render", "m", "--out", "o"], ["masks", "c", "--out", "o", "--verbose"]],
)  # fmt: skip
def test_q_and_v_are_taken_before_or_after_the_verb(argv: list[str]) -> None:
    args = cli.build_parser().parse_args(argv)
    assert (args.quiet, args.verbose) == ("-q" in argv or "--quiet" in argv, "-v" in argv or "--verbose" in argv)


def test_q_and_v_together_are_refused() -> None:
    with pytest.raises(SystemExit) as exc:
        run_main("-q", "preview", "m", "-v")
    assert exc.value.code == C.EXIT_BAD_INPUT


def test_quiet_keeps_errors_warnings_and_tracebacks_only() -> None:
    import io

    sink = io.StringIO()
    tap = LineTap(sink, quiet_lines())
    tap.write("note: plate.1001.exr: colour space assumed 'Linear Rec.709 (sRGB)' (...)\nfit done: PSNR 30 dB\n")
    tap.write("warning: NaN/Inf pixels replaced\nerror: x: bad — fix\nTraceback (most recent call last):\n")
    tap.write('  File "x.py", line 1\nValueError: boom')
    tap.close()
    assert sink.getvalue() == (
        "warning: NaN/Inf pixels replaced\nerror: x: bad — fix\nTraceback (most recent call last):\n"
        '  File "x.py", line 1\nValueError: boom'
    )


def test_quiet_leaves_out_a_verbs_summary_and_verbose_says_each_stage(assumed_run, tmp_path) -> None:
    said = run_main("fit", assumed_run.plate, "--out", assumed_run.run, "--resume-if-started", "--preset", "draft",
                    *[x for s in _tiny_set() for x in ("--set", s)], "--mask", _masks(assumed_run))  # fmt: skip
    quiet = run_main("fit", assumed_run.plate, "--out", assumed_run.run, "--resume-if-started", "--preset", "draft",
                     *[x for s in _tiny_set() for x in ("--set", s)], "--mask", _masks(assumed_run), "-q")  # fmt: skip
    assert said.code == quiet.code == C.EXIT_OK
    assert said.err.startswith("already fitted: 30 steps") and quiet.err == ""
    masks = run_main("masks", assumed_run.plate, "--out", tmp_path / "found", "-v")
    assert masks.code == C.EXIT_OK
    messages = [m for m in map(C.parse_progress_line, masks.out.splitlines()) if m is not None]
    stages = [m["message"] for m in messages if m["event"] == C.EVENT_STAGE]
    assert stages and masks.err.splitlines() == [f"[     ] masks: {message}" for message in stages]


def test_preview_says_each_path_once_after_one_written_message(assumed_run, tmp_path) -> None:
    """Before: each file on stderr ("preview: ...") and again on stdout."""
    ran = run_main("preview", assumed_run.manifest, "--out", tmp_path / "sheets", "--no-movies")
    assert ran.code == C.EXIT_OK and ran.err == ""
    lines = ran.out.splitlines()
    written = C.parse_progress_line(lines[0])
    assert written == {"neural_atlas": 1, "event": "written", "paths": lines[1:]}
    assert sorted(p.rsplit("/", 1)[-1] for p in lines[1:]) == ["atlases.png", "frames.png"]
    assert len(set(lines[1:])) == len(lines[1:])


def test_export_ends_with_written_then_the_manifest_path(assumed_run) -> None:
    again = run_main("export", assumed_run.run, "--into", assumed_run.manifest.parent.name, "--atlas-size", "64")
    assert again.code == C.EXIT_OK
    *_, written, last = again.out.splitlines()
    assert last == str(assumed_run.manifest)
    assert C.parse_progress_line(written)["paths"] == [str(assumed_run.manifest)]


def test_a_finished_fits_last_job_fraction_is_one(assumed_run) -> None:
    """Before: its last message said the share it left to the export that follows (0.2 here, 0.6 on a real clip)."""
    messages = [m for m in map(C.parse_progress_line, assumed_run.fit_out.splitlines()) if m is not None]
    fractions = [m["job_fraction"] for m in messages if m.get("job_fraction") is not None]
    assert messages[-1]["event"] == C.EVENT_DONE and (messages[-1]["job_fraction"], messages[-1]["job_eta"]) == (1, 0)
    assert fractions == sorted(fractions) and fractions[-1] == 1.0 and fractions[-2] < 1.0


# --- the colour docs --------------------------------------------------------------------------------------------

#: The config OpenImageIO 3.0's OpenColorIO 2.4 resolves "ocio://default" to (PyOpenColorIO 2.4:
#: ResolveConfigPath("ocio://default")): the ACES CG config, not the studio config.
CG_CONFIG = "cg-config-v2.2.0_aces-v1.3_ocio-v2.4"
STUDIO_CONFIG = "studio-config-v2.2.0_aces-v1.3_ocio-v2.4"


def test_ocio_default_is_the_cg_config_and_the_docs_say_so() -> None:
    """Before: docs/colour.md, colour.py and fit --help called it the ACES studio config."""
    names = {name: oiio.ColorConfig(f"ocio://{name}").getColorSpaceNames() for name in ("default", CG_CONFIG)}
    studio = oiio.ColorConfig(f"ocio://{STUDIO_CONFIG}").getColorSpaceNames()
    assert names["default"] == names[CG_CONFIG] and len(names["default"]) == 23 and len(studio) == 54
    docs = (ROOT / "docs" / "colour.md").read_text(encoding="utf-8")
    code = (ROOT / "engine" / "io" / "colour.py").read_text(encoding="utf-8")
    fit_help = cli.build_parser()._subparsers._group_actions[0].choices["fit"].format_help()  # type: ignore[union-attr]
    for text in (docs, code, " ".join(fit_help.split())):
        assert not re.search(r"studio config|ACES studio", text)
    assert f"`ocio://default`, the ACES CG config (`{CG_CONFIG}`" in docs
    assert "the built-in ACES CG config" in " ".join(fit_help.split())


def _tiny_set() -> list[str]:
    from tests.farm.farm_helpers import TINY_SET

    return TINY_SET


def _masks(assumed_run) -> str:
    clip = json.loads((assumed_run.run / RUN_CLIP).read_text(encoding="utf-8"))
    return clip["masks"][0]
