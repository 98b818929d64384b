"""``bench export-cost RUN_DIR``: what following the flow costs an export, side by side in one run.

Why: the export follows the flow by default (``engine.export.follow_flow``), which keeps every layer's UV at
working size in memory and filters it along the flow; a user should know what that costs in wall time and
memory against an export of the UV as fitted, on their own clip and machine. One machine's load changes from
minute to minute, so the two kinds of export are run in turn (``repeats`` of each, the order swapped every
round) and compared by their medians, as ratios.

Each export is ``python -m engine export`` in a child process, timed by the wall clock, its peak resident memory
read from the kernel's accounting of that child alone (``os.wait4``). They write into a copy of the run folder
(hard links where the file system allows, else copies) that is removed afterwards: the user's run folder is only
read, its exports and edit layers are never touched.
"""

from __future__ import annotations

import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from engine import contract as C
from engine.errors import InputError
from engine.fit.run_folder import RunFolder

#: What the copy of the run folder leaves out: earlier exports, edit layers and the lock of the original.
NOT_COPIED = (C.EXPORTS_DIR, C.EDITS_DIR, C.RUN_LOCK)


def _link_or_copy(src: str, dst: str) -> None:
    """Hard-link a file of the run into the scratch copy; copy it where links cannot cross file systems."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def scratch_run(run: Path, work: Path) -> Path:
    """A copy of ``run`` under ``work`` that exports can write into (``NOT_COPIED`` left out)."""
    RunFolder(run).require_fit()
    dest = work / run.name
    shutil.copytree(run, dest, ignore=shutil.ignore_patterns(*NOT_COPIED), copy_function=_link_or_copy)
    return dest


def timed_export(run: Path, version: str, follow_flow: bool, threads: int | None) -> dict[str, Any]:
    """One ``export --into version`` of ``run`` in a child process: its wall seconds, its peak RSS (MB) and the
    layers whose UV follows the flow (from the manifest it wrote)."""
    flag = C.EXPORT_FOLLOW_FLOW_FLAG if follow_flow else C.EXPORT_NO_FOLLOW_FLOW_FLAG
    argv = [sys.executable, "-m", C.CLI_MODULE, "export", str(run), "--into", version, "--no-bar", "-q", flag]
    env = dict(os.environ)
    if threads:
        env["OMP_NUM_THREADS"] = str(threads)
    with tempfile.TemporaryFile() as err:
        start = time.perf_counter()
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here: Popen must not wait for it again
        if proc.returncode != 0:
            err.seek(0)
            said = " ".join(err.read().decode("utf-8", "replace").split())[-300:]
            raise RuntimeError(f"export {flag} of {run} exited {proc.returncode}: {said}")
    manifest = C.load_manifest(str(run / C.EXPORTS_DIR / version / C.MANIFEST_NAME))
    follows = [layer["name"] for layer in manifest["layers"] if layer.get("follows_flow")]
    return {
        "follow_flow": follow_flow,
        "wall_seconds": wall,
        "peak_rss_mb": usage.ru_maxrss / 1024.0,
        "follows": follows,
        "frames": len(manifest["clip"]["frame_numbers"]),
        "layers": len(manifest["layers"]),
    }


def _summary(exports: list[dict[str, Any]], follow_flow: bool) -> dict[str, float]:
    mine = [e for e in exports if e["follow_flow"] == follow_flow]
    return {
        "wall_seconds": statistics.median(e["wall_seconds"] for e in mine),
        "peak_rss_mb": statistics.median(e["peak_rss_mb"] for e in mine),
    }


def measure_export_cost(run: Path, repeats: int = 2, threads: int | None = None, work: Path | None = None) -> dict:
    """``repeats`` exports of ``run`` following the flow and as many of its UV as fitted, in turn; every export's
    numbers, each kind's medians and their ratios (following / as fitted)."""
    run = Path(run).expanduser().resolve()
    if repeats < 1:
        raise InputError(None, f"--repeats {repeats} measures nothing", "give --repeats 1 or more")
    if work is not None and not Path(work).is_dir():
        raise InputError(work, "is not a folder", "give --work an existing folder (or leave it out: the temp folder)")
    with tempfile.TemporaryDirectory(dir=work) as tmp:
        copy = scratch_run(run, Path(tmp))
        exports, version = [], 0
        for round_ in range(repeats):
            for follow in (True, False) if round_ % 2 == 0 else (False, True):
                version += 1
                exports.append(timed_export(copy, f"v{version:03d}", follow, threads))
    follow, fitted = _summary(exports, True), _summary(exports, False)
    return {
        "run": str(run),
        "repeats": repeats,
        "threads": threads,
        "exports": exports,
        "follow_flow": follow,
        "as_fitted": fitted,
        "wall_ratio": follow["wall_seconds"] / max(fitted["wall_seconds"], 1e-9),
        "peak_rss_ratio": follow["peak_rss_mb"] / max(fitted["peak_rss_mb"], 1e-9),
    }


def format_cost(report: dict) -> str:
    """The lines ``bench export-cost`` prints."""
    first = report["exports"][0]
    follows = next(e["follows"] for e in report["exports"] if e["follow_flow"])
    lines = [
        f"export-cost: {report['run']}: {first['frames']} frames, {first['layers']} layers, following the flow: "
        f"{', '.join(follows) or 'no layer (all under the gate)'}"
    ]
    for name, key in (("follow the flow", "follow_flow"), ("as fitted", "as_fitted")):
        s = report[key]
        lines.append(f"  {name:15s} median wall {s['wall_seconds']:7.1f} s, peak RSS {s['peak_rss_mb']:7.0f} MB")
    lines.append(f"  ratio           wall {report['wall_ratio']:.2f}x, peak RSS {report['peak_rss_ratio']:.2f}x")
    return "\n".join(lines)


__all__ = ["NOT_COPIED", "format_cost", "measure_export_cost", "scratch_run", "timed_export"]
