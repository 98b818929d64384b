"""Every relative link and image of README.md and the docs pages (docs/bench/experiments.md included) opens a file
or folder of the checkout, so a page or a bench record that moves takes its readers with it."""

from __future__ import annotations

import re
from pathlib import Path

from tests.paths import ROOT

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
FENCED = re.compile(r"^```.*?^```", re.MULTILINE | re.DOTALL)
#: ``[text](target)`` and ``![alt](target)``; a target with a scheme (https:, mailto:) is not a file.
LINK = re.compile(r"\]\(([^)\s]+)\)")
SCHEME = re.compile(r"^[a-z][a-z0-9+.-]*:")


def broken_links(page: Path, root: Path = ROOT) -> list[str]:
    """``page:line: target`` (relative to ``root``) for each relative link outside code blocks whose file does not
    exist."""
    text = FENCED.sub(lambda m: "\n" * m.group(0).count("\n"), page.read_text(encoding="utf-8"))
    out = []
    for number, line in enumerate(text.splitlines(), 1):
        for m in LINK.finditer(line):
            target = m.group(1).split("#")[0]
            if target and not SCHEME.match(target) and not (page.parent / target).exists():
                out.append(f"{page.relative_to(root)}:{number}: {m.group(1)}")
    return out


def test_every_relative_link_of_the_pages_opens_a_file():
    assert (ROOT / "docs" / "bench" / "experiments.md") in PAGES
    bad = [b for page in PAGES for b in broken_links(page)]
    assert not bad, "links to files that do not exist (paths are relative to the page):\n" + "\n".join(bad)


def test_a_broken_link_is_found(tmp_path):
    (tmp_path / "images").mkdir()
    (tmp_path / "images" / "a.jpg").write_bytes(b"")
    page = tmp_path / "page.md"
    page.write_text(
        "![ok](images/a.jpg) [web](https://example.com) [here](#anchor)\n"
        "```\n[in code](nowhere.md)\n```\n"
        "![gone](images/b.jpg) and [log](bench/log.md#section)\n",
        encoding="utf-8",
    )
    assert broken_links(page, tmp_path) == ["page.md:5: images/b.jpg", "page.md:5: bench/log.md#section"]
