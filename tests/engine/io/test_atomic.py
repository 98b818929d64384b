"""Atomic writes leave whole files with ordinary permissions, and nothing behind on failure."""

from __future__ import annotations

import os
import stat

import pytest

from engine.io.atomic import atomic_write, atomic_write_text


@pytest.mark.skipif(os.name != "posix", reason="POSIX permission bits")
@pytest.mark.parametrize("umask", [0o022, 0o027, 0o002])
def test_written_files_follow_the_umask_not_the_temp_files_0600(tmp_path, umask):
    before = os.umask(umask)
    try:
        atomic_write_text(tmp_path / "manifest.json", "{}")
        plain = tmp_path / "plain.json"
        plain.write_text("{}")
    finally:
        os.umask(before)
    mode = stat.S_IMODE((tmp_path / "manifest.json").stat().st_mode)
    assert mode == 0o666 & ~umask == stat.S_IMODE(plain.stat().st_mode)
    assert (tmp_path / "manifest.json").read_text() == "{}"


def test_a_failed_write_leaves_neither_the_file_nor_its_temp(tmp_path):
    (tmp_path / "keep.json").write_text("earlier")

    def fail(tmp: str) -> None:
        with open(tmp, "w") as f:
            f.write("half")
        raise OSError("disk full")

    with pytest.raises(OSError):
        atomic_write(tmp_path / "keep.json", fail)
    assert (tmp_path / "keep.json").read_text() == "earlier"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.json"]
