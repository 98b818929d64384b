"""The shell examples in README.md and docs/ are executed, so they never rot.

Convention: the line right before a ```bash fence says what the block is.

- ``<!-- test -->``: run it with ``bash -euo pipefail``; it must exit 0.
- ``<!-- test: fails "TEXT" -->``: run it; it must exit non-zero and print TEXT (a real error message).
- ``<!-- covered: tests/path.py -->``: too slow or too big to run here (the demo, the whole suite); the named
  test runs it. The file must exist and name the command's verb.
- ``<!-- manual: REASON -->``: needs what CI does not have (the Blender GUI, a GPU, the network, a
  ``blender`` binary, the real clips of tests/paths.py); the reason is shown.

In README.md and the docs pages listed in ``STRICT`` every bash block must carry one of these (the
commands documented for users are all accounted for); elsewhere only the tagged blocks run.

Blocks run in a scratch folder that holds ``.venv``, ``engine``, ``addon`` (symlinks to this checkout) and,
made once per session, ``clip/`` (a 64x48, 4-frame synthetic plate with ``frames/`` and ``masks/``). Blocks
of one page run in order in the same folder, so a later block can use what an earlier one wrote.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.paths import ROOT

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
STRICT = {"README.md", "guide.md", "troubleshooting.md", "architecture.md", "addon.md"}
TAG = re.compile(r"<!--\s*(test|covered|manual)(?::\s*(.*?))?\s*-->\s*$")
FENCE = re.compile(r"^```bash\s*$")
#: A whole page's examples: a tiny fit (60 steps) + export + renders, well under a minute on 2 cores.
BLOCK_TIMEOUT_S = 900


@dataclass
class Block:
    page: Path
    line: int
    kind: str | None  # test | covered | manual | None (untagged)
    arg: str
    code: str

    @property
    def id(self) -> str:
        return f"{self.page.name}:{self.line}"


def blocks(page: Path) -> list[Block]:
    lines = page.read_text(encoding="utf-8").splitlines()
    out = []
    i = 0
    while i < len(lines):
        if FENCE.match(lines[i]):
            j = i + 1
            while j < len(lines) and not lines[j].startswith("```"):
                j += 1
            prev = next((lines[k] for k in range(i - 1, -1, -1) if lines[k].strip()), "")
            m = TAG.search(prev)
            out.append(
                Block(
                    page, i + 1, m.group(1) if m else None, (m.group(2) or "") if m else "", "\n".join(lines[i + 1 : j])
                )
            )
            i = j
        i += 1
    return out


ALL = [b for page in PAGES for b in blocks(page)]


def test_every_user_facing_command_is_accounted_for():
    untagged = [b.id for b in ALL if b.kind is None and b.page.name in STRICT]
    assert not untagged, f"bash blocks without <!-- test/covered/manual --> before them: {untagged}"
    for b in ALL:
        if b.kind == "covered":
            target = ROOT / b.arg.split()[0]
            assert target.exists(), f"{b.id}: {target} does not exist"
            verb = next((w for w in ("demo", "test", "fit", "export", "render", "build") if w in b.code), None)
            assert verb is None or verb in target.read_text(encoding="utf-8"), f"{b.id}: {target} never runs {verb}"
        if b.kind == "manual":
            assert b.arg, f"{b.id}: say why it is manual"
    assert sum(b.kind == "test" for b in ALL) >= 8  # the examples really run


def _engine_commands() -> list[tuple[str, str, list[str]]]:
    """(block id, verb, --options) of every `python -m engine VERB ...` line in every bash block."""
    out = []
    for b in ALL:
        for line in b.code.replace("\\\n", " ").splitlines():
            line = line.split("#")[0]
            for m in re.finditer(r"-m engine ([a-z][a-z-]*)(.*?)(?:$|&&|;|\s\|\s)", line):
                out.append((b.id, m.group(1), re.findall(r"(?<![\w-])(--[a-z][a-z-]*)", m.group(2))))
    return out


def test_documented_engine_options_exist():
    """Synopsis blocks with placeholders cannot run; their verbs and options are checked against the CLI."""
    import argparse

    from engine.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    commands = _engine_commands()
    assert len(commands) >= 15
    for where, verb, options in commands:
        assert verb in sub.choices, f"{where}: `python -m engine {verb}` is not a verb ({sorted(sub.choices)})"
        parsers = [sub.choices[verb]]
        nested = [a for a in parsers[0]._actions if isinstance(a, argparse._SubParsersAction)]
        if nested:  # a verb of verbs (farm openjd ...): an option of any of them
            parsers += list(nested[0].choices.values())
        known = {o for parser in parsers for a in parser._actions for o in a.option_strings}
        missing = [o for o in options if o not in known]
        assert not missing, f"{where}: `engine {verb}` has no option {missing}"


@pytest.fixture(scope="session")
def scratch(tmp_path_factory) -> Path:
    """A folder that looks like the checkout (symlinks) plus a tiny synthetic clip."""
    d = tmp_path_factory.mktemp("docs")
    for name in (".venv", "engine", "addon", "__init__.py", "blender_manifest.toml"):
        os.symlink(ROOT / name, d / name)
    code = (
        "import sys; from pathlib import Path; from engine.data.synthetic import SceneSpec, make_scene, write_scene; "
        "write_scene(make_scene(SceneSpec(width=64, height=48, frames=4)), Path(sys.argv[1]))"
    )
    subprocess.run([sys.executable, "-c", code, str(d / "clip")], cwd=ROOT, check=True, timeout=120)
    return d


def _pages_with_tests() -> list[Path]:
    return [p for p in PAGES if any(b.kind == "test" for b in blocks(p))]


@pytest.mark.slow
@pytest.mark.parametrize("page", _pages_with_tests(), ids=lambda p: p.name)
def test_page_examples_run(page: Path, scratch: Path, tmp_path: Path):
    if not (ROOT / ".venv" / "bin" / "python").exists():
        pytest.skip("no .venv in the checkout")
    work = tmp_path / "work"
    shutil.copytree(scratch, work, symlinks=True)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for b in blocks(page):
        if b.kind != "test":
            continue
        proc = subprocess.run(
            ["bash", "-euo", "pipefail", "-c", b.code],
            cwd=work,
            env=env,
            capture_output=True,
            text=True,
            timeout=BLOCK_TIMEOUT_S,
        )
        out = proc.stdout + proc.stderr
        if b.arg.startswith("fails"):
            want = re.search(r'"(.*)"', b.arg)
            assert proc.returncode != 0, f"{b.id} should fail but exited 0:\n{out[-2000:]}"
            assert want and want.group(1) in out, (
                f"{b.id}: expected {want.group(1) if want else '?'!r} in:\n{out[-2000:]}"
            )
        else:
            assert proc.returncode == 0, f"{b.id} exited {proc.returncode}:\n{b.code}\n---\n{out[-3000:]}"
