"""The engine as a Python package: ``pip install .`` and a wheel build give the ``neural-atlas`` command and the
import package ``neural_atlas`` (the repository's ``engine/`` under a name of its own), with compatible ranges as
its requirements and the exact versions tested in ``engine/constraints.txt``.

Offline and in seconds: the source is a copy of the checkout (so a build leaves no ``build/`` or ``*.egg-info``
in it), built with ``--no-build-isolation`` (setuptools from this venv) and installed with ``--no-deps`` into a
fresh virtual environment whose one ``.pth`` line makes this venv's installed packages (torch, OpenImageIO, ...)
importable, so nothing is downloaded; a dummy package named ``engine`` is installed beside it, as another
project's would be.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import tomllib
import venv
import zipfile
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

from engine import contract as C
from engine.cli import CONSOLE_SCRIPT
from engine.terms.cli import INSTALLED_MODULE, VERB_DEMO, VERB_NUKE, VERB_PREVIEW, VERB_RENDER
from engine.terms.versions import ENGINE_VERSION
from tests.paths import ROOT

PYPROJECT = ROOT / "pyproject.toml"
WHEEL_NAME = f"neural_atlas-{ENGINE_VERSION}-py3-none-any.whl"
#: The installed import package (pyproject.toml maps it onto engine/).
PACKAGE = INSTALLED_MODULE
ENTRY_POINT = f"{PACKAGE}.cli:console_main"
#: What a copy of the checkout leaves out: environments, caches, outputs of earlier builds and runs.
NOT_SOURCE = shutil.ignore_patterns(
    ".venv*", ".git", "__pycache__", "*.pyc", ".*_cache", "build", "dist", "*.egg-info", "runs", "demo_out"
)
PIP_TIMEOUT = 300


def _requirements(lines: list[str] | tuple[str, ...]) -> list[tuple[str, str, str]]:
    """Name, specifiers (order-free) and marker of each requirement: how pip compares them."""
    out = []
    for line in lines:
        req = Requirement(line)
        out.append((req.name, str(sorted(str(s) for s in req.specifier)), str(req.marker or "")))
    return out


def _constraints() -> dict[str, Version]:
    """engine/constraints.txt: canonical name -> exact version."""
    pins = {}
    for line in C.requirement_lines(C.CONSTRAINTS_FILE):
        req = Requirement(line)
        (spec,) = req.specifier
        assert spec.operator == "==", line
        pins[canonicalize_name(req.name)] = Version(spec.version)
    return pins


def test_pyproject_reads_the_requirements_from_the_engines_files_and_lists_every_package():
    pyproject = tomllib.loads(PYPROJECT.read_text(encoding="utf-8"))
    project, setuptools = pyproject["project"], pyproject["tool"]["setuptools"]
    assert project["dynamic"] == ["dependencies", "optional-dependencies"]
    assert setuptools["dynamic"]["dependencies"] == {"file": [f"engine/{C.REQUIREMENTS_FILE}"]}
    assert setuptools["dynamic"]["optional-dependencies"] == {"farm": {"file": [f"engine/{C.FARM_REQUIREMENTS_FILE}"]}}
    assert project["name"] == "neural-atlas" and project["version"] == ENGINE_VERSION
    assert project["scripts"] == {CONSOLE_SCRIPT: ENTRY_POINT}
    assert setuptools["package-dir"] == {PACKAGE: "engine"}
    # every folder of engine/ with Python in it is a package of the wheel
    folders = {p.parent for p in (ROOT / "engine").rglob("*") if p.suffix in (".py", ".js")}
    folders = {f.relative_to(ROOT / "engine").parts for f in folders if "__pycache__" not in f.parts}
    assert sorted(setuptools["packages"]) == sorted(".".join((PACKAGE, *parts)) for parts in folders)


def test_requirements_are_ranges_and_the_constraints_pin_each_inside_its_range():
    """A library install gets ranges (no ``==``); the constraints file pins every requirement, the farm's too,
    to one version inside its range, and this test environment holds exactly the pinned versions."""
    pins = _constraints()
    for line in C.ENGINE_REQUIREMENTS + C.FARM_REQUIREMENTS:
        req = Requirement(line)
        assert req.specifier and all(s.operator in (">=", "<", "~=", "!=", "<=") for s in req.specifier), line
        assert canonicalize_name(req.name) in pins, f"{req.name} has no exact version in {C.CONSTRAINTS_FILE}"
        assert req.specifier.contains(pins[canonicalize_name(req.name)]), (line, pins[canonicalize_name(req.name)])
    for name, version in pins.items():
        installed = Version(metadata.version(name))
        assert Version(installed.public) == version, f"{name}: {installed} installed, {version} pinned"


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    src = tmp_path_factory.mktemp("src") / "neural-atlas"
    shutil.copytree(ROOT, src, ignore=NOT_SOURCE, symlinks=True)
    return src


@pytest.fixture(scope="module")
def wheel(source, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    argv = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w", str(out), str(source)]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=PIP_TIMEOUT, cwd=out)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return out / WHEEL_NAME


def test_wheel_holds_the_engine_under_its_own_name_and_nothing_else(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    dist_info = f"neural_atlas-{ENGINE_VERSION}.dist-info"
    assert {n.split("/")[0] for n in names} == {PACKAGE, dist_info}
    engine_files = {"engine/" + n.split("/", 1)[1] for n in names if n.startswith(f"{PACKAGE}/")}
    # every file of the engine in the checkout (a data file too: pyproject.toml's package-data must name it)
    files = [p.relative_to(ROOT).as_posix() for p in (ROOT / "engine").rglob("*") if p.is_file()]
    files = [f for f in files if "__pycache__" not in f]
    ignored = subprocess.run(  # none without git: then every file counts
        ["git", "check-ignore", "--stdin"], input="\n".join(files), capture_output=True, text=True, cwd=ROOT
    ).stdout.split()
    expected = set(files) - set(ignored)
    assert engine_files == expected
    shipped = {"engine/py.typed", "engine/fit/expected_psnr.json", "engine/cli.py", "engine/constraints.txt"}
    assert shipped <= engine_files


def test_wheel_metadata_declares_the_ranges_and_the_command(wheel):
    z = zipfile.ZipFile(wheel)
    dist_info = f"neural_atlas-{ENGINE_VERSION}.dist-info"
    metadata = z.read(f"{dist_info}/METADATA").decode("utf-8").splitlines()
    requires = [line.split(": ", 1)[1] for line in metadata if line.startswith("Requires-Dist: ")]
    farm_marker = 'extra == "farm"'
    assert _requirements([r for r in requires if farm_marker not in r]) == _requirements(C.ENGINE_REQUIREMENTS)
    # the farm extra: exactly the contract's FARM_REQUIREMENTS, each under the extra's marker
    assert "Provides-Extra: farm" in metadata
    farm = [r.split(";")[0].strip() for r in requires if farm_marker in r]
    assert _requirements(farm) == _requirements(C.FARM_REQUIREMENTS)
    assert "Requires-Python: >=3.11" in metadata
    assert "License-Expression: GPL-3.0-or-later" in metadata
    entry_points = z.read(f"{dist_info}/entry_points.txt").decode("utf-8").split()
    assert entry_points == ["[console_scripts]", CONSOLE_SCRIPT, "=", ENTRY_POINT]
    assert not any(s.operator == "==" for r in requires for s in Requirement(r).specifier)


#: Another project's top-level ``engine`` package, installed beside ours.
DUMMY_ENGINE = "WHO = 'another project'\n"


@pytest.fixture(scope="module")
def installed(source, tmp_path_factory) -> Path:
    """A fresh venv with ``pip install .`` done in it (this venv's packages reachable through one .pth line), after
    another project that installs a top-level package named ``engine``."""
    env_dir = tmp_path_factory.mktemp("venv") / "env"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    site = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    (Path(site) / "reuse_test_venv.pth").write_text(sysconfig.get_paths()["purelib"] + "\n", encoding="utf-8")
    other = tmp_path_factory.mktemp("other") / "other-engine"
    (other / "engine").mkdir(parents=True)
    (other / "engine" / "__init__.py").write_text(DUMMY_ENGINE, encoding="utf-8")
    (other / "pyproject.toml").write_text(
        '[build-system]\nrequires = ["setuptools"]\nbuild-backend = "setuptools.build_meta"\n'
        '[project]\nname = "other-engine"\nversion = "1.0"\n[tool.setuptools]\npackages = ["engine"]\n',
        encoding="utf-8",
    )
    argv = [str(python), "-m", "pip", "install", "--no-deps", "--no-build-isolation", "--no-index"]
    for folder in (other, source):
        proc = subprocess.run([*argv, str(folder)], capture_output=True, text=True, timeout=PIP_TIMEOUT, cwd=folder)
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return env_dir


def _run(installed: Path, *argv: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["COLUMNS"] = "120"  # argparse wraps help to the terminal's width: the same width for both commands
    return subprocess.run(
        list(argv), capture_output=True, text=True, timeout=PIP_TIMEOUT, cwd=cwd or installed.parent, env=env
    )


@pytest.mark.slow
def test_pip_install_gives_the_neural_atlas_command_with_the_engines_verbs(installed):
    command = installed / "bin" / CONSOLE_SCRIPT
    helped = _run(installed, str(command), "--help")
    assert helped.returncode == 0, helped.stderr
    assert helped.stdout.startswith(f"usage: {CONSOLE_SCRIPT} [-h] [--version] [-q] [-v] VERB ...")
    # the same verbs, options and text as `python -m engine` from the checkout, under the command's name
    module = _run(installed, sys.executable, "-m", C.CLI_MODULE, "--help", cwd=ROOT)
    assert helped.stdout == module.stdout.replace("python -m engine", CONSOLE_SCRIPT)
    for verb in (C.VERB_FIT, C.VERB_ESTIMATE, C.VERB_EXPORT, VERB_RENDER, C.VERB_PROJECT_FRAME, C.VERB_MASKS):
        assert f"    {verb}" in helped.stdout, verb
    as_module = _run(installed, str(installed / "bin" / "python"), "-m", PACKAGE, "--help")
    assert as_module.stdout == module.stdout.replace("python -m engine", f"python -m {PACKAGE}")
    version = _run(installed, str(command), "--version")
    assert version.stdout.strip() == f"neural-atlas engine {ENGINE_VERSION}"
    render = _run(installed, str(command), VERB_RENDER, "--help")
    assert render.returncode == 0 and render.stdout.startswith(f"usage: {CONSOLE_SCRIPT} {VERB_RENDER} ")
    bad = _run(installed, str(command), VERB_RENDER, str(installed / "no_such_manifest.json"), "--out", "x")
    assert bad.returncode == C.EXIT_BAD_INPUT
    assert "no manifest here" in bad.stderr


@pytest.mark.slow
def test_installed_engine_is_the_package_not_the_checkout(installed):
    """Every module of the installed engine imports from the venv (its data files and py.typed beside it), beside
    another project's ``engine``, which stays that project's; the engine's farm tasks name the installed package."""
    script = (
        "import importlib, pkgutil, pathlib, engine, neural_atlas\n"
        "from neural_atlas import contract\n"
        "mods = [m.name for m in pkgutil.walk_packages(neural_atlas.__path__, 'neural_atlas.')]\n"
        "mods = [m for m in mods if not m.endswith('__main__')]\n"
        "[importlib.import_module(m) for m in mods]\n"
        "root = pathlib.Path(neural_atlas.__file__).parent\n"
        "print(root)\n"
        "print(len(mods), (root / 'py.typed').is_file(), (root / 'fit' / 'expected_psnr.json').is_file())\n"
        "print(engine.WHO, contract.CLI_MODULE, len(contract.ENGINE_REQUIREMENTS), "
        "contract.CONSTRAINTS_PATH.is_file())\n"
    )
    proc = _run(installed, str(installed / "bin" / "python"), "-c", script)
    assert proc.returncode == 0, proc.stderr[-3000:]
    root, counts, names = proc.stdout.split("\n")[:3]
    assert Path(root).is_relative_to(installed)
    assert names == f"another project {PACKAGE} {len(C.ENGINE_REQUIREMENTS)} True"
    shipped = [p for p in (ROOT / "engine").rglob("*.py") if p.name != "__main__.py"]
    assert counts == f"{len(shipped) - 1} True True"  # every module but engine/__init__.py itself


@pytest.mark.slow
def test_every_verb_runs_from_an_empty_folder_with_the_installed_wheel(installed, tmp_path):
    """The installed command, in a folder that holds nothing of the checkout, runs each verb's happy path on a tiny
    clip: masks, parts, estimate, fit (and --refine), export (twice), render, project-frame, realign, preview,
    nuke, the farm's plan, OpenJD bundle and Flamenco job type, and the demo on its embedded clip (each of these
    reads files shipped with the package, not the checkout's)."""
    from engine.data.synthetic import SceneSpec, make_scene, write_scene

    work = tmp_path / "empty"
    work.mkdir()
    frames, masks = write_scene(
        make_scene(SceneSpec(width=48, height=32, frames=4, fg_size=(16, 12), fg_start=(10.0, 8.0))), work / "clip"
    )
    command = str(installed / "bin" / CONSOLE_SCRIPT)
    tiny = ["--preset", "draft", "--no-bar", "--set", "steps=4", "--set", "batch=128", "--set", "eval_pixels=256"]
    manifest = work / "run" / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME
    later = work / "run" / C.EXPORTS_DIR / "v002" / C.MANIFEST_NAME
    paint = work / "paint.png"
    shots = work / "shots.toml"
    shots.write_text(
        f'{C.SHOTS_TAG} = {C.SHOTS_VERSION}\n[[{C.SHOTS_LIST_KEY}]]\nname = "sh010"\nplate = "clip/frames"\n'
        'masks = ["clip/masks"]\n',
        encoding="utf-8",
    )
    steps: list[tuple[list[str], Path | None]] = [
        ([C.VERB_MASKS, str(frames), "--out", str(work / "found")], work / "found"),
        ([C.VERB_PARTS, str(frames), "--mask", str(masks), "--out", str(work / "strokes")], None),
        ([C.VERB_ESTIMATE, str(frames), "--mask", str(masks), "--presets", "draft", "--calib-seconds", "0.01"], None),
        ([C.VERB_FIT, str(frames), "--mask", str(masks), "--out", str(work / "run"), *tiny], work / "run"),
        ([C.VERB_EXPORT, str(work / "run"), "--atlas-size", "32"], manifest),
        ([VERB_RENDER, str(manifest), "--out", str(work / "rendered"), "--no-bar"], work / "rendered"),
        ([C.VERB_PROJECT_FRAME, str(manifest), "--frame", "1", "--edit", str(paint)], None),
        ([C.VERB_FIT, "--out", str(work / "run"), "--refine", "2", "--no-bar"], None),
        ([C.VERB_EXPORT, str(work / "run"), "--atlas-size", "32"], later),
        ([C.VERB_REALIGN, str(later)], None),
        ([VERB_PREVIEW, str(manifest), "--out", str(work / "preview"), "--no-movies"], work / "preview"),
        ([VERB_NUKE, str(manifest), "--out", str(work / "edit.nk")], work / "edit.nk"),
        ([C.VERB_FARM, "plan", str(shots)], None),
        ([C.VERB_FARM, "openjd", str(shots), "--out", str(work / "bundle")], work / "bundle" / "template.json"),
        ([C.VERB_FARM, "flamenco", "--job-type-out", str(work / "flamenco")], work / "flamenco"),
        ([VERB_DEMO, "--out", str(work / "demo"), *tiny[3:]], work / "demo" / "contact_sheet.png"),
    ]
    for argv, made in steps:
        if argv[0] == C.VERB_PROJECT_FRAME:
            import numpy as np

            from tests.media_files import write_image

            pixels = np.zeros((32, 48, 4), np.uint8)
            pixels[10:20, 15:30] = (255, 0, 0, 255)
            write_image(paint, pixels)
        proc = _run(installed, command, *argv, cwd=work)
        assert proc.returncode == C.EXIT_OK, (argv[:2], proc.stderr[-3000:])
        assert made is None or made.exists(), (argv[:2], proc.stdout[-2000:], proc.stderr[-2000:])
    assert sorted(p.name for p in (work / "flamenco").iterdir()) == ["neural-atlas.js"]
