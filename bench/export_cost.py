"""``bench export-cost RUN_DIR [--compare follow-flow|write-ahead|render-write-ahead]``: what an export or render
choice costs, side by side in one run.

Why: the export follows the flow by default (``engine.export.follow_flow``), which keeps every layer's UV at
working size in memory and filters it along the flow; a user should know what that costs in wall time and
memory against an export of the UV as fitted, on their own clip and machine. ``write-ahead``: the pass files
written while the next frame is evaluated (``engine.export.pass_writer``) against one after another, what a 2K-4K
export gains in time and pays in memory; ``render-write-ahead``: the same for ``render``'s frames. One machine's
load changes from minute to minute, so the two kinds are run in turn (``repeats`` of each, the order swapped every
round) and compared by their medians, as ratios.

Each export or render is ``python -m engine`` in a child process, timed by the wall clock, its peak resident memory
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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from engine import contract as C
from engine.errors import InputError
from engine.fit.run_folder import RunFolder
from engine.terms.cli import EXPORT_FOLLOW_FLOW_FLAG
from engine.terms.export_names import EDITS_DIR
from engine.terms.lock import RUN_LOCK

#: What the copy of the run folder leaves out: earlier exports, edit layers and the lock of the original.
NOT_COPIED = (C.EXPORTS_DIR, EDITS_DIR, RUN_LOCK)


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


@dataclass(frozen=True)
class Kind:
    """One kind of run a comparison times: its name, the verb (``export``, or ``render`` of one export made first),
    its flags and, where it differs from the product's, how many frames wait to be written while the next is computed
    (``PASS_WRITE_AHEAD`` of ``engine.export.pass_writer``, ``RENDER_WRITE_AHEAD`` of ``engine.edit.render``)."""

    name: str
    flags: tuple[str, ...] = ()
    write_ahead: int | None = None
    verb: str = "export"


#: What ``--compare`` sets side by side: two kinds of run of the same fit, the first over the second in the ratios.
COMPARISONS: dict[str, tuple[Kind, Kind]] = {
    "follow-flow": (
        Kind("follow the flow", (EXPORT_FOLLOW_FLOW_FLAG,)),
        Kind("as fitted", (C.EXPORT_NO_FOLLOW_FLOW_FLAG,)),
    ),
    "write-ahead": (Kind("write ahead"), Kind("in turn", write_ahead=0)),
    "render-write-ahead": (Kind("write ahead", verb="render"), Kind("in turn", write_ahead=0, verb="render")),
}
#: Where each verb keeps its look-ahead (module, name).
_WRITE_AHEAD_AT = {"export": ("engine.export.pass_writer", "PASS_WRITE_AHEAD"), "render": ("engine.edit.render",
                   "RENDER_WRITE_AHEAD")}  # fmt: skip
#: A child that sets a module's look-ahead (argv[1], argv[2] = argv[3]) and then runs ``engine``'s command line.
_WITH_WRITE_AHEAD = (
    "import importlib, sys; setattr(importlib.import_module(sys.argv[1]), sys.argv[2], int(sys.argv[3])); "
    "from engine.cli import main; sys.exit(main(sys.argv[4:]))"
)
#: The paint a timed render lays on every layer: this share of each atlas, in its middle, an opaque colour.
PAINT_SHARE = 0.5


def _child(kind: Kind, args: list[str], threads: int | None, what: str) -> tuple[float, float]:
    """``engine ARGS`` as ``kind`` in a child process: its wall seconds and peak RSS (MB), read from the kernel's
    accounting of that child alone."""
    if kind.write_ahead is None:
        argv = [sys.executable, "-m", C.CLI_MODULE, *args]
    else:
        module, name = _WRITE_AHEAD_AT[kind.verb]
        argv = [sys.executable, "-c", _WITH_WRITE_AHEAD, module, name, str(kind.write_ahead), *args]
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
            raise RuntimeError(f"{kind.verb} ({kind.name}) of {what} exited {proc.returncode}: {said}")
    return wall, usage.ru_maxrss / 1024.0


def _record(kind: Kind, manifest_path: Path, wall: float, peak_mb: float) -> dict[str, Any]:
    manifest = C.load_manifest(str(manifest_path))
    return {
        "kind": kind.name,
        "verb": kind.verb,
        "wall_seconds": wall,
        "peak_rss_mb": peak_mb,
        "follows": [layer["name"] for layer in manifest["layers"] if layer.get("follows_flow")],
        "frames": len(manifest["passes"]["frames"]),
        "layers": len(manifest["layers"]),
    }


def timed_export(run: Path, version: str, kind: Kind, threads: int | None) -> dict[str, Any]:
    """One ``export --into version`` of ``run`` as ``kind`` in a child process: its wall seconds, its peak RSS (MB)
    and the layers whose UV follows the flow (from the manifest it wrote)."""
    args = ["export", str(run), "--into", version, "--no-bar", "-q", *kind.flags]
    wall, peak = _child(kind, args, threads, str(run))
    return _record(kind, run / C.EXPORTS_DIR / version / C.MANIFEST_NAME, wall, peak)


def paint_edits(manifest_path: Path, folder: Path) -> list[str]:
    """``--edit LAYER=IMAGE`` for every layer of the export: an opaque block over ``PAINT_SHARE`` of its atlas (a
    render's cost depends on how much of the plate paint covers), written under ``folder``."""
    from engine.io.images import write_png

    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for layer in C.load_manifest(str(manifest_path))["layers"]:
        w, h = layer["atlas_size"]
        paint = np.zeros((h, w, 4), np.float32)
        side = PAINT_SHARE**0.5
        y0, x0 = int(h * (1 - side) / 2), int(w * (1 - side) / 2)
        paint[y0 : h - y0, x0 : w - x0] = (0.9, 0.2, 0.1, 1.0)
        path = write_png(folder / f"{layer['name']}.png", paint, 8)
        out += ["--edit", f"{layer['name']}={path}"]
    return out


def timed_render(manifest: Path, out: Path, kind: Kind, edits: list[str], threads: int | None) -> dict[str, Any]:
    """One ``render`` of ``manifest`` with ``edits`` into ``out`` (EXR frames) as ``kind`` in a child process."""
    args = ["render", str(manifest), "--out", str(out), "--format", "exr", "--no-bar", *edits, *kind.flags]
    wall, peak = _child(kind, args, threads, str(manifest))
    return _record(kind, manifest, wall, peak)


def _summary(runs: list[dict[str, Any]], kind: Kind) -> dict[str, float]:
    mine = [e for e in runs if e["kind"] == kind.name]
    return {
        "wall_seconds": statistics.median(e["wall_seconds"] for e in mine),
        "peak_rss_mb": statistics.median(e["peak_rss_mb"] for e in mine),
    }


def measure_export_cost(
    run: Path, repeats: int = 2, threads: int | None = None, work: Path | None = None, compare: str = "follow-flow"
) -> dict:
    """``repeats`` runs of each kind ``compare`` names (``COMPARISONS``) on ``run``, in turn, the order swapped every
    round (renders: of one export made first, untimed, with paint on every layer); every run's numbers, each kind's
    medians and their ratios (the first kind over the second)."""
    run = Path(run).expanduser().resolve()
    if compare not in COMPARISONS:
        raise InputError(None, f"--compare {compare!r} is not a comparison", f"use one of {', '.join(COMPARISONS)}")
    if repeats < 1:
        raise InputError(None, f"--repeats {repeats} measures nothing", "give --repeats 1 or more")
    if work is not None and not Path(work).is_dir():
        raise InputError(work, "is not a folder", "give --work an existing folder (or leave it out: the temp folder)")
    first, second = COMPARISONS[compare]
    with tempfile.TemporaryDirectory(dir=work) as tmp:
        copy = scratch_run(run, Path(tmp))
        runs, version, manifest, edits = [], 1, None, []
        if first.verb == "render":  # one export to render, untimed
            timed_export(copy, "v001", Kind("once"), threads)
            manifest = copy / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME
            edits = paint_edits(manifest, Path(tmp) / "paint")
        for round_ in range(repeats):
            for kind in (first, second) if round_ % 2 == 0 else (second, first):
                version += 1
                if manifest is None:
                    runs.append(timed_export(copy, f"v{version:03d}", kind, threads))
                else:
                    runs.append(timed_render(manifest, Path(tmp) / f"render{version}", kind, edits, threads))
    a, b = _summary(runs, first), _summary(runs, second)
    return {
        "run": str(run),
        "compare": compare,
        "kinds": [first.name, second.name],
        "repeats": repeats,
        "threads": threads,
        "exports": runs,
        "summary": {first.name: a, second.name: b},
        "wall_ratio": a["wall_seconds"] / max(b["wall_seconds"], 1e-9),
        "peak_rss_ratio": a["peak_rss_mb"] / max(b["peak_rss_mb"], 1e-9),
    }


def format_cost(report: dict) -> str:
    """The lines ``bench export-cost`` prints."""
    first = report["exports"][0]
    follows = sorted({name for e in report["exports"] for name in e["follows"]})
    lines = [
        f"export-cost: {report['run']}: {first['frames']} frames, {first['layers']} layers, following the flow: "
        f"{', '.join(follows) or 'no layer'}"
    ]
    for name in report["kinds"]:
        s = report["summary"][name]
        lines.append(f"  {name:15s} median wall {s['wall_seconds']:7.1f} s, peak RSS {s['peak_rss_mb']:7.0f} MB")
    lines.append(f"  ratio           wall {report['wall_ratio']:.2f}x, peak RSS {report['peak_rss_ratio']:.2f}x")
    return "\n".join(lines)


__all__ = [
    "COMPARISONS",
    "NOT_COPIED",
    "PAINT_SHARE",
    "Kind",
    "format_cost",
    "measure_export_cost",
    "paint_edits",
    "scratch_run",
    "timed_export",
    "timed_render",
]
