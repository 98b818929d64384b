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


def test_a_runtime_error_on_a_full_disk_is_one_line_disk_full(tmp_path, monkeypatch):
    """torch.save and OpenEXR raise RuntimeError, not OSError, when the disk fills: with no free space left the
    write is a DiskFullError naming the folder and how much to free; the earlier file and no temp remain."""
    import engine.io.atomic as atomic
    from engine.errors import MB, DiskFullError

    (tmp_path / "checkpoint.pt").write_text("earlier")
    monkeypatch.setattr(atomic, "free_bytes", lambda folder: 0)

    def fail(tmp: str) -> None:
        with open(tmp, "wb") as f:
            f.write(b"x" * 1000)
        raise RuntimeError("PytorchStreamWriter failed writing file data/0: file write failed")

    with pytest.raises(DiskFullError) as info:
        atomic_write(tmp_path / "checkpoint.pt", fail, need=5 * MB)
    assert str(info.value).startswith(f"disk full: free 5 MB at {tmp_path} — ")
    assert "\n" not in str(info.value)
    assert (tmp_path / "checkpoint.pt").read_text() == "earlier"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint.pt"]


def test_a_runtime_error_with_space_left_is_not_called_a_full_disk(tmp_path):
    def fail(tmp: str) -> None:
        raise RuntimeError("a real bug")

    with pytest.raises(RuntimeError, match="a real bug"):
        atomic_write(tmp_path / "x.bin", fail)
    assert list(tmp_path.iterdir()) == []


def test_enospc_is_a_full_disk_whatever_the_free_space_says(tmp_path):
    import errno

    from engine.errors import DiskFullError
    from engine.io.atomic import disk_full_error

    full = disk_full_error(OSError(errno.ENOSPC, "No space left on device"), tmp_path, written=0, need=3 * 1024**2)
    assert isinstance(full, DiskFullError) and str(full).startswith("disk full: free ")
    assert disk_full_error(OSError(errno.EACCES, "Permission denied"), tmp_path) is None
    assert disk_full_error(KeyboardInterrupt(), tmp_path) is None
