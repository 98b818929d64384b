"""The "Where a change goes" table of docs/architecture.md names files and folders that exist, and a row for each
kind of change the page promises (a loss term, a config field, an export pass, a record field, a farm back end, a
panel setting): a module that moves or goes fails here, not in a reader's hands."""

from __future__ import annotations

import re

from tests.paths import ROOT

PAGE = ROOT / "docs" / "architecture.md"
HEADING = "## Where a change goes"
KINDS = ("a loss term", "a config field", "an export pass", "a run-folder record field", "a farm back end",
         "a panel setting or button")  # fmt: skip
#: A path in backticks: a folder ending in / or a file with an extension, under one of the checkout's trees.
PATH = re.compile(r"`((?:engine|addon|tests)/[\w./-]*)`")


def _table() -> list[str]:
    lines = PAGE.read_text(encoding="utf-8").splitlines()
    start = lines.index(HEADING)
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")), len(lines))
    return [line for line in lines[start:end] if line.startswith("| ") and not line.startswith("| change")]


def test_every_kind_of_change_has_a_row():
    assert [row.split("|")[1].strip() for row in _table()] == list(KINDS)


def test_every_path_the_table_names_exists():
    named = [m for row in _table() for m in PATH.findall(row)]
    assert len(named) >= 20, named
    missing = [p for p in named if "..." not in p and not (ROOT / p).exists()]
    assert not missing, f"docs/architecture.md, {HEADING}: no such file or folder: {missing}"
