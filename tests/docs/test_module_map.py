"""The module map of docs/architecture.md (the tree under "Layout") names every Python module of the engine, the
add-on and the bench, names nothing that does not exist, and keeps each folder's entries in name order.

**The tree's format.** One entry a line: the name at two spaces per level (a folder ends with ``/``), its
description from column ``DESCRIPTION_COLUMN`` on, or on the next line when the name reaches that column; a line
indented to the description column or further continues a description. A package's ``__init__.py`` may be left to
its folder's line. So a module added to the checkout without a line in the tree fails here, and so does a line
left behind by a module that moved or went.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.paths import ROOT

PAGE = ROOT / "docs" / "architecture.md"
WHERE = "docs/architecture.md"
#: The tree is the first fenced block after this heading.
HEADING = "## Layout"
#: Where a description starts; an entry's name is indented less than this.
DESCRIPTION_COLUMN = 22
INDENT = 2
#: The trees the map must cover: every Python module under these folders.
PACKAGES = ("engine", "addon", "bench")
SKIPPED_DIRS = {"__pycache__"}


@dataclass(frozen=True)
class Entry:
    """One line of the tree that names a file or a folder."""

    path: str  # relative to the checkout; a folder without its trailing slash
    is_folder: bool
    line: int  # line number in the page


def tree_block(text: str) -> tuple[int, list[str]]:
    """(line number of the block's first line, the block's lines) of the first fenced block after ``HEADING``."""
    lines = text.splitlines()
    start = next((i for i, line in enumerate(lines) if line.startswith(HEADING)), None)
    if start is None:
        raise AssertionError(f"{WHERE} has no '{HEADING}' section: the module map belongs under it")
    fence = next((i for i in range(start, len(lines)) if lines[i].startswith("```")), None)
    if fence is None:
        raise AssertionError(f"{WHERE}: no fenced tree under '{HEADING}'")
    end = next((i for i in range(fence + 1, len(lines)) if lines[i].startswith("```")), len(lines))
    return fence + 2, lines[fence + 1 : end]


def parse_tree(text: str) -> list[Entry]:
    """Every file and folder the tree names, with its path built from the folders above it."""
    first, block = tree_block(text)
    entries: list[Entry] = []
    folders: list[str] = []  # the open folder at each depth
    for number, raw in enumerate(block, first):
        indent = len(raw) - len(raw.lstrip(" "))
        if not raw.strip() or indent >= DESCRIPTION_COLUMN:
            continue  # a blank line or the rest of a description
        if indent % INDENT:
            raise AssertionError(f"{WHERE}:{number}: an entry is indented by {indent} spaces, not a multiple of 2")
        depth = indent // INDENT
        if depth > len(folders):
            raise AssertionError(f"{WHERE}:{number}: '{raw.strip()}' is deeper than the folder above it")
        name = raw.split()[0]
        del folders[depth:]
        is_folder = name.endswith("/")
        path = "/".join([*folders, name.rstrip("/")])
        entries.append(Entry(path, is_folder, number))
        if is_folder:
            folders.append(name.rstrip("/"))
    return entries


def modules(root: Path) -> list[str]:
    """Every Python module under ``PACKAGES``, relative to ``root``."""
    found = []
    for package in PACKAGES:
        for path in (root / package).rglob("*.py"):
            rel = path.relative_to(root)
            if not SKIPPED_DIRS & set(rel.parts):
                found.append(rel.as_posix())
    return sorted(found)


def problems(entries: list[Entry], root: Path) -> list[str]:
    """One line per disagreement between the tree and the files under ``root``, each naming its fix."""
    out = []
    named = {e.path for e in entries}
    folders = {e.path for e in entries if e.is_folder}
    seen: set[str] = set()
    for e in entries:
        if e.path in seen:
            out.append(f"{WHERE}:{e.line}: {e.path} is named twice in the module map; keep one line")
        seen.add(e.path)
        kind_ok = (root / e.path).is_dir() if e.is_folder else (root / e.path).is_file()
        if not kind_ok:
            what = "folder" if e.is_folder else "file"
            out.append(
                f"{WHERE}:{e.line}: the module map names {e.path}{'/' if e.is_folder else ''}, "
                f"but there is no such {what}; remove or rename its line"
            )
    for module in modules(root):
        parent, _, name = module.rpartition("/")
        if module in named or (name == "__init__.py" and parent in folders):
            continue
        out.append(
            f"{module} is not in the module map of {WHERE}: add a line for it under {parent}/ "
            "(name order), with what it does"
        )
    out += _order_problems(entries)
    return out


def _order_problems(entries: list[Entry]) -> list[str]:
    """Entries of one folder out of name order (a folder sorts by its name without the slash); the top level is
    in the page's own order (the engine, the add-on, the bench)."""
    by_parent: dict[str, list[Entry]] = {}
    for e in entries:
        by_parent.setdefault(e.path.rpartition("/")[0], []).append(e)
    out = []
    for parent, children in by_parent.items():
        if not parent:
            continue
        names = [c.path.rpartition("/")[2] for c in children]
        for before, after, entry in zip(names, names[1:], children[1:], strict=False):
            if after < before:
                out.append(
                    f"{WHERE}:{entry.line}: {after} comes after {before} in {parent}/; "
                    "the module map keeps each folder's entries in name order"
                )
    return out


# --- the checkout -------------------------------------------------------------------------------------------


def test_the_module_map_matches_the_checkout():
    found = problems(parse_tree(PAGE.read_text(encoding="utf-8")), ROOT)
    assert not found, "docs/architecture.md's module map and the checkout disagree:\n" + "\n".join(found)


def test_the_tree_is_read_as_the_page_writes_it():
    """A regression in the parser would check nothing: known entries of every kind are found where they are."""
    entries = {e.path: e for e in parse_tree(PAGE.read_text(encoding="utf-8"))}
    for path in ("engine/contract.py", "engine/fit/trainer.py", "addon/core/tree_plan.py", "addon/ops/driver.py"):
        assert path in entries and not entries[path].is_folder, path
    # a name too long for its column has its description on the next line
    assert "addon/core/engine_commands.py" in entries
    assert "engine/fit/expected_psnr.json" in entries
    assert entries["bench"].is_folder and entries["addon/core"].is_folder
    assert len([p for p in entries if p.endswith(".py")]) >= 100


# --- the checker on a made-up tree ------------------------------------------------------------------------------

PAGE_TEXT = """# Architecture

## Layout: a folder per stage

```
engine/
  __init__.py         the package
  cli.py              the command line
  fit/
    expected_psnr.json
                      data
    trainer.py        the training loop, whose description is long enough
                      to continue on a second line
addon/
  ui.py               the panel
```
"""


def _checkout(tmp_path: Path, files: list[str]) -> Path:
    for rel in files:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("", encoding="utf-8")
    return tmp_path


FILES = [
    "engine/__init__.py",
    "engine/cli.py",
    "engine/fit/__init__.py",
    "engine/fit/trainer.py",
    "engine/fit/expected_psnr.json",
    "addon/ui.py",
]


def test_a_tree_that_matches_passes(tmp_path):
    entries = parse_tree(PAGE_TEXT)
    assert [e.path for e in entries] == [
        "engine",
        "engine/__init__.py",
        "engine/cli.py",
        "engine/fit",
        "engine/fit/expected_psnr.json",
        "engine/fit/trainer.py",
        "addon",
        "addon/ui.py",
    ]
    # engine/fit/__init__.py is covered by the fit/ line
    assert problems(entries, _checkout(tmp_path, FILES)) == []


def test_a_module_the_map_does_not_name_fails(tmp_path):
    root = _checkout(tmp_path, [*FILES, "engine/fit/refine.py", "engine/data/__init__.py"])
    found = problems(parse_tree(PAGE_TEXT), root)
    assert found == [
        "engine/data/__init__.py is not in the module map of docs/architecture.md: add a line for it under "
        "engine/data/ (name order), with what it does",
        "engine/fit/refine.py is not in the module map of docs/architecture.md: add a line for it under engine/fit/ "
        "(name order), with what it does",
    ]


def test_a_line_for_a_module_that_went_fails(tmp_path):
    root = _checkout(tmp_path, [f for f in FILES if f != "engine/cli.py"])
    assert problems(parse_tree(PAGE_TEXT), root) == [
        "docs/architecture.md:8: the module map names engine/cli.py, but there is no such file; "
        "remove or rename its line"
    ]


def test_entries_out_of_name_order_fail(tmp_path):
    text = PAGE_TEXT.replace(
        "  __init__.py         the package\n  cli.py              the command line\n",
        "  cli.py              the command line\n  __init__.py         the package\n",
    )
    assert problems(parse_tree(text), _checkout(tmp_path, FILES)) == [
        "docs/architecture.md:8: __init__.py comes after cli.py in engine/; the module map keeps each folder's entries "
        "in name order"
    ]


@pytest.mark.parametrize(
    ("tree", "message"),
    [
        ("engine/\n   cli.py             odd indent\n", "indented by 3 spaces"),
        ("engine/\n    cli.py            too deep\n", "deeper than the folder above it"),
    ],
)
def test_a_malformed_tree_says_where(tree, message):
    with pytest.raises(AssertionError, match=message):
        parse_tree(f"## Layout\n\n```\n{tree}```\n")


def test_a_page_without_the_layout_section_says_so():
    with pytest.raises(AssertionError, match="no '## Layout' section"):
        parse_tree("# Architecture\n")
