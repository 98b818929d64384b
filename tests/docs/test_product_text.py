"""Product text is about the product: no passage narrates how it was developed, none cites a file outside
the repository, and every ``docs/<page>.md#<anchor>`` citation resolves.

Scanned: README.md, docs/, engine/, addon/, tests/, .ci/, run.sh, blender_manifest.toml and pyproject.toml
(every text file; measurement records that tools generate, ``docs/bench/*.json``, are data, not passages).
Measured numbers carry their date, machine and command instead of the round of work that produced them;
Blender facts are cited from ``docs/blender-compat.md``.

One exception: ``tests/paths.py`` is the one place that locates the optional real clips (a folder beside the
checkout, overridable with ``NEURAL_ATLAS_CLIPS``), so the outside-the-repository patterns are allowed there.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.paths import ROOT

#: What is scanned, relative to the repository root.
SCANNED = ("README.md", "docs", "engine", "addon", "tests", ".ci", "run.sh", "blender_manifest.toml", "pyproject.toml")
#: Generated measurement records (the bench's JSON: the command line and machine of a run), not passages.
GENERATED = ("docs/bench/",)
TEXT_SUFFIXES = {".md", ".py", ".toml", ".sh", ".txt", ".cfg", ".ini", ".yml", ".yaml", ".rst", ".json", ""}
SKIPPED_DIRS = {"__pycache__", ".pytest_cache", ".ruff_cache", ".mypy_cache", ".hypothesis"}
THIS_FILE = Path(__file__).resolve()

#: Passages that narrate the development history: a round of work, notes kept while developing, "when written".
HISTORY: dict[str, str] = {
    "a numbered work session": r"\bsessions?[ -]#?\d+",
    "a work session": r"\b(?:this|that|last|previous|earlier|later|next|other|another|past|first|second|third)"
    r"\s+sessions?\b",
    "a work session's": r"\bsession['’]s\b|\bsessions['’](?=\s)",
    "session notes": r"\bsession\s+notes\b",
    "a numbered round of work": r"\b(?:in|of|from|since|after|before|during)\s+(?:round|sprint)\s+\d+\b",
    "measured when written": r"\bwhen\s+(?:it\s+was\s+|this\s+was\s+)?written\b|\bat\s+the\s+time\s+of\s+writing\b",
    "we tried": r"\bwe\s+tried\b",
    "the task brief": r"\b(?:the|this)\s+brief\s+(?:says|asks|describes|wants|requires|calls)\b",
    "an issue number": r"\bissue\s+#?\d+\b",
}
#: Citations of files that are not in the repository.
OUTSIDE: dict[str, str] = {
    "../shared": r"\.\./shared\b",
    "shared/data": r"(?<![\w-])shared/data\b",
    "the folder beside the checkout": r"\.parent\s*/\s*['\"]shared['\"]",
    "BLENDER_NOTES": r"\bBLENDER_NOTES\b",
    "STYLE.md": r"(?<![\w/-])STYLE\.md\b",
    "a path on a development machine": r"(?<![\w.~-])/work/\w",
}
PATTERNS = {name: re.compile(p, re.IGNORECASE) for name, p in {**HISTORY, **OUTSIDE}.items()}
#: The one legitimate locator of the real clips: the outside-the-repository patterns are allowed there.
ALLOWED: dict[str, set[str]] = {"tests/paths.py": set(OUTSIDE)}


def scanned_files() -> list[Path]:
    out = []
    for name in SCANNED:
        top = ROOT / name
        paths = [top] if top.is_file() else sorted(p for p in top.rglob("*") if p.is_file()) if top.is_dir() else []
        for p in paths:
            rel = p.relative_to(ROOT).as_posix()
            if SKIPPED_DIRS & set(p.relative_to(ROOT).parts) or rel.startswith(GENERATED):
                continue
            if p.suffix.lower() in TEXT_SUFFIXES and p.resolve() != THIS_FILE:
                out.append(p)
    return out


def _text(path: Path) -> str | None:
    raw = path.read_bytes()
    if b"\0" in raw:
        return None
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return None


def scanned_texts() -> list[tuple[str, str]]:
    """(path relative to the checkout, text) of every scanned text file."""
    return [(p.relative_to(ROOT).as_posix(), t) for p in scanned_files() if (t := _text(p)) is not None]


def hits(text: str, allowed: set[str] = frozenset()) -> list[tuple[int, str, str]]:
    """(line number, names of the patterns it matches, line) for every line of ``text`` that matches a pattern
    not in ``allowed``."""
    out = []
    for n, line in enumerate(text.splitlines(), 1):
        names = [name for name, rx in PATTERNS.items() if name not in allowed and rx.search(line)]
        if names:
            out.append((n, ", ".join(names), line.strip()))
    return out


def test_no_development_history_or_outside_files_in_product_text():
    found = []
    for rel, text in scanned_texts():
        found += [f"{rel}:{n}: [{name}] {line[:140]}" for n, name, line in hits(text, ALLOWED.get(rel, set()))]
    assert not found, (
        "product text narrates the development history or cites a file outside the repository "
        "(state the date, machine and command of a number instead; cite docs/blender-compat.md for Blender "
        "facts; tests/paths.py locates the real clips):\n" + "\n".join(found)
    )


def test_the_scan_covers_what_it_says():
    rels = {p.relative_to(ROOT).as_posix() for p in scanned_files()}
    for must in ("README.md", "docs/blender-compat.md", "engine/contract.py", "tests/paths.py", ".ci/run", "run.sh"):
        assert must in rels, must
    assert not any(r.startswith(GENERATED) for r in rels)


@pytest.mark.parametrize(
    "line",
    [
        "balanced 28.73 dB (session 4, on the Xeon)",
        "session-6 work: one field pass per layer",
        "Not explained this session; the previous session's fit was within 7%",
        "earlier sessions' figures came from another machine",
        "see the session notes",
        "the slope measured in round 3",
        "Measured when written (2-core CPU): PSNR 32.8 dB",
        "measured 27.0 dB and alpha IoU 0.92 when written",
        "we tried a larger band first",
        "the failure the brief describes",
        "Issue 5: lone final fit",
        "a clip folder such as ../shared/data/blackswan",
        "CLIPS = ROOT.parent / 'shared' / 'data'",
        "the X11 libraries (BLENDER_NOTES §1)",
        "see /work/shared/STYLE.md",
    ],
)
def test_the_patterns_catch_history_and_outside_files(line):
    assert hits(line), line


@pytest.mark.parametrize(
    "line",
    [
        "start_new_session=True,  # a Ctrl-C in Blender's terminal must not kill the fit",
        "class EngineSession:",
        "for session in list(operators._SESSIONS.values()):",
        '@pytest.fixture(scope="session")',
        "@pytest.fixture(scope='session')",
        "made once per session, ``clip/``",
        "The first step of a session is left out of the rates",
        "interleaved blocks of steps, 3 rounds, median",
        "round(x * 255) to the nearest code value",
        "the shared decoders; shared_data marker; SHARED_FIELDS",
        "What was tried and what it did",
        "a brief pause before the next frame",
        "the DAVIS clips with masks and TAP-Vid tracks, passed by path",
        "the tests read the same folder from NEURAL_ATLAS_CLIPS",
        "docs/blender-compat.md#exit-hang",
        "/tmp/auto/blackswan and ~/work/clip",
    ],
)
def test_the_patterns_leave_product_words_alone(line):
    assert not hits(line), hits(line)


# --- citations of the docs ------------------------------------------------------------------------------

CITATION = re.compile(r"(?<![\w/.-])docs/([\w-]+\.md)(?:#([\w-]+))?")


def slug(heading: str) -> str:
    """The anchor GitHub gives a Markdown heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    found, seen, fenced = set(), {}, False
    for line in page.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            fenced = not fenced
        m = re.match(r"#{1,6}\s+(.*?)\s*#*\s*$", line)
        if m and not fenced:
            base = slug(m.group(1))
            n = seen.get(base, 0)
            seen[base] = n + 1
            found.add(base if n == 0 else f"{base}-{n}")
    return found


def test_every_cited_docs_page_and_anchor_exists():
    bad = []
    for rel, text in scanned_texts():
        for n, line in enumerate(text.splitlines(), 1):
            for m in CITATION.finditer(line):
                page = ROOT / "docs" / m.group(1)
                if not page.is_file():
                    bad.append(f"{rel}:{n}: docs/{m.group(1)} does not exist")
                elif m.group(2) and m.group(2) not in anchors(page):
                    bad.append(f"{rel}:{n}: docs/{m.group(1)} has no section #{m.group(2)}")
    assert not bad, "\n".join(bad)


#: A path into the repository as README.md and docs/ write it: ``engine/fit/trainer.py``, ``tests/addon/``.
REPO_PATH = re.compile(r"(?<![\w/.$-])((?:engine|addon|tests|docs)/[\w./-]*[\w/])")


def test_every_path_the_docs_name_exists():
    """Module and test paths in README.md and docs/ follow the code when it moves."""
    bad = []
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for n, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1):
            for m in REPO_PATH.finditer(line):
                path = m.group(1).split("#")[0]
                if not (ROOT / path).exists() and not any(c in path for c in "<*"):
                    bad.append(f"{page.relative_to(ROOT)}:{n}: {path} does not exist")
    assert not bad, "\n".join(bad)


def test_blender_compat_has_the_sections_code_cites():
    have = anchors(ROOT / "docs" / "blender-compat.md")
    want = {"versions", "install", "compositor-api", "multilayer-exr", "map-uv", "colour-spaces", "masks"}
    want |= {"headless", "painting", "modal-operators", "engine-python", "extensions", "exit-hang"}
    assert want <= have, sorted(want - have)
