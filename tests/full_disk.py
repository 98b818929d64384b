"""Run a command on a really full file system, for tests of what a full disk does to a verb.

    result = run_on_full_disk([sys.executable, "-m", "engine", "masks", clip, "--out", disk / "masks"],
                              mount=disk, size_kb=12, cwd=ROOT)
    assert result.returncode == 2 and result.left == {}

``unshare --user --map-root-user --mount`` gives the command a private mount table (a user namespace, so no privileges
are needed where user namespaces are allowed; as root it works too). There a tmpfs of ``size_kb`` kilobytes is mounted
on ``mount`` (an existing folder, normally empty), so every write below ``mount`` fails with ENOSPC once that much is
used: a real full disk, not a patched writer. Everything else (the clip, the checkout) is the ordinary file system. When
the command exits the namespace and its mount are gone, so ``run_on_full_disk`` lists what the command left on the full
disk (path relative to ``mount`` -> size in bytes, hidden files and folders included) before that, and returns it with
the exit code and the output.

Where user namespaces or mounts are not permitted (some containers, macOS) the calling test is skipped with the
reason (``full_disk_unavailable``).
"""

from __future__ import annotations

import functools
import json
import os
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest

#: tmpfs allocates whole pages: every file and folder on the full disk costs at least this many bytes.
PAGE_BYTES = 4096

#: Runs inside the namespace: mount the tmpfs, run the command, list what it left, print one JSON line.
_DRIVER = r"""
import json, os, subprocess, sys
spec = json.loads(sys.argv[1])
mount = spec["mount"]
subprocess.run(["mount", "-t", "tmpfs", "-o", "size=%dk" % spec["size_kb"], "tmpfs", mount], check=True)
for path, data in spec["prefill"].items():
    full = os.path.join(mount, path)
    os.makedirs(os.path.dirname(full), exist_ok=True)
    with open(full, "wb") as f:
        f.write(bytes(data))
try:
    proc = subprocess.run(spec["argv"], cwd=spec["cwd"], env=spec["env"], capture_output=True, timeout=spec["timeout"])
    code, out, err = proc.returncode, proc.stdout, proc.stderr
except subprocess.TimeoutExpired as exc:
    code, out, err = None, exc.stdout or b"", exc.stderr or b""
left = {}
for folder, dirs, files in os.walk(mount):
    for name in dirs + files:
        path = os.path.join(folder, name)
        rel = os.path.relpath(path, mount)
        left[rel + ("/" if name in dirs else "")] = 0 if name in dirs else os.path.getsize(path)
sys.stdout.write(json.dumps({"returncode": code, "stdout": out.decode("utf-8", "replace"),
                             "stderr": err.decode("utf-8", "replace"), "left": left}))
"""


@dataclass(frozen=True)
class FullDiskRun:
    """What a command did on the full disk."""

    returncode: int | None
    """The command's exit status (None: it ran past the timeout and was killed)."""
    stdout: str
    stderr: str
    left: dict[str, int]
    """What was on the full disk when the command ended: relative path -> bytes (folders end with ``/``, size 0)."""

    @property
    def stderr_lines(self) -> list[str]:
        return [line for line in self.stderr.splitlines() if line.strip()]


@functools.cache
def full_disk_unavailable() -> str | None:
    """Why a full disk cannot be made here (None when it can): tries a 4 KB tmpfs in a private mount namespace."""
    if sys.platform != "linux" or shutil.which("unshare") is None or shutil.which("mount") is None:
        return "needs Linux with unshare and mount (a tmpfs in a private mount namespace)"
    with tempfile.TemporaryDirectory() as probe:
        try:
            proc = subprocess.run(
                ["unshare", "--user", "--map-root-user", "--mount", "mount", "-t", "tmpfs", "-o", "size=4k", "tmpfs",
                 probe],
                capture_output=True,
                text=True,
                timeout=30,
            )  # fmt: skip
        except (OSError, subprocess.SubprocessError) as exc:
            return f"cannot run unshare ({exc})"
    if proc.returncode != 0:
        return f"user namespaces or tmpfs mounts are not permitted here ({' '.join(proc.stderr.split())})"
    return None


def run_on_full_disk(
    argv: Sequence[str | os.PathLike[str]],
    mount: Path,
    size_kb: int,
    cwd: Path | None = None,
    env: dict[str, str] | None = None,
    timeout: float = 300.0,
    prefill: dict[str, int] | None = None,
) -> FullDiskRun:
    """Run ``argv`` with a ``size_kb`` KB tmpfs mounted on ``mount`` (created if missing) and return what it did
    and what it left there. ``prefill``: files written on the disk before the command runs (relative path ->
    bytes of zeros), to leave it with less room. Skips the calling test where a full disk cannot be made."""
    reason = full_disk_unavailable()
    if reason is not None:
        pytest.skip(reason)
    mount.mkdir(parents=True, exist_ok=True)
    spec = {
        "mount": str(mount),
        "size_kb": int(size_kb),
        "argv": [os.fspath(a) for a in argv],
        "cwd": str(cwd) if cwd is not None else os.getcwd(),
        "env": dict(os.environ if env is None else env),
        "timeout": timeout,
        "prefill": dict(prefill or {}),
    }
    proc = subprocess.run(
        ["unshare", "--user", "--map-root-user", "--mount", sys.executable, "-c", _DRIVER, json.dumps(spec)],
        capture_output=True,
        text=True,
        timeout=timeout + 60,
    )
    assert proc.returncode == 0, f"the full-disk driver failed: {proc.stderr[-2000:]}"
    return FullDiskRun(**json.loads(proc.stdout))
