"""What the Dask back end buys: the same shots run one after another, then through ``farm dask`` with local workers.

``python -m bench farm CLIP CLIP ... --out OUT`` writes a shots file for the clips (each a clip folder with
frames/ and masks/), plans it once per route (``engine.farm.plan``), and times

1. one after another: every task's engine command of the plan, in plan order, each in a subprocess with all the
   machine's cores as torch threads;
2. Dask: a ``dask scheduler`` and N ``dask worker`` processes started here on 127.0.0.1 (one task at a time each),
   the same plan through ``run_plan``, the cores split between the workers' engines.

Both routes write their own run folders from the same argv but for the run folder, so their exports must agree;
the result is a markdown table (date, machine, the exact command) and OUT/farm_bench.json.
"""

from __future__ import annotations

import contextlib
import datetime
import json
import math
import os
import platform
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from bench.bench_clip import BenchClip
from engine import contract as C
from engine.errors import InputError
from engine.farm.dask_backend import engine_argv, run_plan

FARM_BENCH_JSON = "farm_bench.json"
ROUTE_SEQUENTIAL = "sequential"
ROUTE_DASK = "dask"
#: Seconds for the scheduler to write its address, and for the workers to join it.
START_SECONDS = 60.0
#: Seconds a process gets to stop after SIGTERM before SIGKILL, and to go after SIGKILL.
STOP_SECONDS = 10.0


def stop_process(proc: subprocess.Popen[Any], grace: float = STOP_SECONDS) -> None:
    """Stop one process we started, by its PID: SIGTERM, then SIGKILL after ``grace`` seconds (bounded waits)."""
    if proc.poll() is not None:
        return
    with contextlib.suppress(ProcessLookupError):
        os.kill(proc.pid, signal.SIGTERM)
    try:
        proc.wait(grace)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.kill(proc.pid, signal.SIGKILL)
        proc.wait(STOP_SECONDS)


def _dask_cli() -> list[str]:
    """The ``dask`` command of this Python (its console script, else the module behind it)."""
    script = Path(sys.executable).parent / "dask"
    return [str(script)] if script.is_file() else [sys.executable, "-m", "dask"]


@dataclass
class LocalDask:
    """A Dask scheduler and workers on 127.0.0.1, each a process of ours. Workers run without a nanny, so a
    worker's PID is the process that runs its tasks: killing it is a lost host, not a restart by its nanny."""

    folder: Path
    env: dict[str, str]
    resources: str | None = None
    scheduler: subprocess.Popen[bytes] | None = None
    workers: list[subprocess.Popen[bytes]] = field(default_factory=list)
    address: str = ""
    _logs: list[IO[bytes]] = field(default_factory=list)

    def _start(self, name: str, argv: list[str]) -> subprocess.Popen[bytes]:
        log = open(self.folder / f"{name}.log", "wb")  # noqa: SIM115 - closed in stop()
        self._logs.append(log)
        return subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log, stderr=log, env=self.env)

    def start_scheduler(self) -> str:
        info = self.folder / "scheduler.json"
        argv = [*_dask_cli(), "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard"]
        self.scheduler = self._start("scheduler", [*argv, "--scheduler-file", str(info)])
        deadline = time.monotonic() + START_SECONDS
        while time.monotonic() < deadline:
            if self.scheduler.poll() is not None:
                raise RuntimeError(f"dask scheduler exited with {self.scheduler.returncode}: see {self.folder}")
            with contextlib.suppress(OSError, ValueError):
                self.address = str(json.loads(info.read_text())["address"])
                return self.address
            time.sleep(0.1)
        raise RuntimeError(f"dask scheduler wrote no address in {START_SECONDS:.0f} s: see {self.folder}")

    def add_worker(self) -> subprocess.Popen[bytes]:
        """Start one more worker (one task at a time) and return its process."""
        name = f"worker{len(self.workers)}"
        argv = [*_dask_cli(), "worker", self.address, "--host", "127.0.0.1", "--nthreads", "1", "--no-nanny"]
        argv += ["--no-dashboard", "--name", name, "--local-directory", str(self.folder / name)]
        if self.resources:
            argv += ["--resources", self.resources]
        proc = self._start(name, argv)
        self.workers.append(proc)
        return proc

    def wait_for_workers(self, count: int) -> None:
        """Block until ``count`` workers are connected (bounded)."""
        from distributed import Client

        with Client(self.address, timeout=START_SECONDS, set_as_default=False) as client:
            client.wait_for_workers(count, timeout=START_SECONDS)

    def stop(self) -> None:
        """Stop every process started here by its PID (workers first), each with bounded waits."""
        for proc in [*self.workers, *([self.scheduler] if self.scheduler else [])]:
            stop_process(proc)
        for log in self._logs:
            log.close()


@contextlib.contextmanager
def local_dask(
    folder: Path, workers: int, resources: str | None = None, env: dict[str, str] | None = None
) -> Iterator[LocalDask]:
    """A scheduler and ``workers`` workers on 127.0.0.1 for the ``with`` block; all stopped at its end."""
    folder.mkdir(parents=True, exist_ok=True)
    base = dict(os.environ if env is None else env)
    root = str(Path(__file__).resolve().parents[1])  # the workers unpickle engine's task function
    base["PYTHONPATH"] = os.pathsep.join([root, *[p for p in base.get("PYTHONPATH", "").split(os.pathsep) if p]])
    cluster = LocalDask(folder, base, resources)
    try:
        cluster.start_scheduler()
        for _ in range(workers):
            cluster.add_worker()
        cluster.wait_for_workers(workers)
        yield cluster
    finally:
        cluster.stop()


def machine() -> dict[str, Any]:
    """The CPU model and core count the measurement ran on."""
    model = platform.processor() or platform.machine()
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    return {"cpu": model, "cores": os.cpu_count() or 1, "python": platform.python_version()}


def write_shots_file(
    path: Path, clips: list[BenchClip], runs: Path, preset: str, overrides: list[str], export_chunk: int | None
) -> Path:
    """A shots file (contract SHOTS_*) for ``clips``, whose run folders go under ``runs``."""
    defaults: dict[str, Any] = {"preset": preset, "set": list(overrides), "preview": False}
    if export_chunk:
        defaults["export_chunk"] = export_chunk
    shots = [
        {"name": c.name, "plate": str(c.frames), "masks": [str(m) for m in c.masks], "run": str(runs / c.name)}
        for c in clips
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({C.SHOTS_TAG: C.SHOTS_VERSION, C.SHOTS_DEFAULTS_KEY: defaults, "shots": shots}))
    return path


def _threads_env(threads: int) -> dict[str, str]:
    env = dict(os.environ)
    env["OMP_NUM_THREADS"] = env["MKL_NUM_THREADS"] = str(threads)
    env["PYTHONPATH"] = os.pathsep.join(
        [str(Path(__file__).resolve().parents[1]), *[p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]]
    )
    return env


def run_sequential(shots_file: Path, threads: int, log: Path) -> float:
    """Every task of the shots file's plan, one after another in plan order; the wall seconds."""
    from engine.farm.plan import load_plan

    plan = load_plan(shots_file)
    env = _threads_env(threads)
    start = time.monotonic()
    with open(log, "wb") as out:
        for task in plan.tasks:
            rc = subprocess.run(engine_argv(task.args), stdin=subprocess.DEVNULL, stdout=out, stderr=out, env=env)
            if rc.returncode != C.EXIT_OK:
                raise RuntimeError(f"{task.id}: exit {rc.returncode}: see {log}")
    return time.monotonic() - start


def run_dask_route(shots_file: Path, workers: int, threads: int, folder: Path) -> float:
    """The shots file's plan through ``run_plan`` on ``workers`` local workers; the wall seconds (workers up)."""
    from engine.farm.plan import load_plan

    plan = load_plan(shots_file)
    with local_dask(folder / "cluster", workers) as cluster, open(folder / "progress.jsonl", "w") as progress:
        result = run_plan(plan, cluster.address, threads=threads, stream=progress)
    if not result.ok:
        first = (result.failed or [r for r in result.results.values() if r["state"] != "done"])[0]
        raise RuntimeError(f"{first['id']}: {first.get('error')}: see {folder}")
    return result.seconds


def export_files(run: Path) -> dict[str, bytes]:
    """Every file of a run folder's exports, by path relative to the run folder (to compare two routes)."""
    root = run / C.EXPORTS_DIR
    return {p.relative_to(run).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


#: Manifest fields that say when or how fast, not what: they differ between any two runs.
VOLATILE_KEYS = frozenset({"created", "train_seconds", "seconds_per_step"})


def _json_diff(a: Any, b: Any, key: str = "") -> float:
    """The largest difference between two JSON values' numbers (inf: a different shape, text or key)."""
    if key in VOLATILE_KEYS:
        return 0.0
    if isinstance(a, dict) and isinstance(b, dict):
        if a.keys() != b.keys():
            return math.inf
        return max([_json_diff(a[k], b[k], k) for k in a], default=0.0)
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return math.inf
        return max([_json_diff(x, y, key) for x, y in zip(a, b, strict=True)], default=0.0)
    numbers = (int, float)
    if isinstance(a, numbers) and isinstance(b, numbers) and not isinstance(a, bool) and not isinstance(b, bool):
        return abs(float(a) - float(b))
    return 0.0 if a == b else math.inf


def _file_diff(name: str, a: bytes, b: bytes, folders: tuple[Path, Path]) -> float:
    """How far two files of the same name differ: 0 for the same bytes, else by their content (pixels, JSON)."""
    if a == b:
        return 0.0
    import numpy as np

    from engine.io.images import read_exr, read_image

    if name.endswith(".exr"):
        ca, cb = (read_exr(folder / name) for folder in folders)
        if ca.keys() != cb.keys() or any(ca[k].shape != cb[k].shape for k in ca):
            return math.inf
        return max(float(np.abs(ca[k] - cb[k]).max()) for k in ca)
    if name.endswith(".png"):
        (pa, _), (pb, _) = (read_image(folder / name) for folder in folders)
        return math.inf if pa.shape != pb.shape else float(np.abs(pa - pb).max())
    if name.endswith(".json"):
        return _json_diff(json.loads(a), json.loads(b))
    return math.inf


def _psnr(run: Path) -> float | None:
    try:
        return float(json.loads((run / C.RUN_METRICS).read_text())["psnr"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def compare_exports(run_a: Path, run_b: Path) -> dict[str, Any]:
    """Two run folders' exports compared: the same files, how many have the same bytes, the largest difference
    of their floats (EXR pixels, manifest numbers) and of their PNGs (None: a file differs in shape or text), and
    each fit's PSNR. With the same torch thread count the routes give the same bytes; with different counts float
    sums round differently, training amplifies that, and the PSNRs say whether the fits are equally good."""
    fa, fb = export_files(run_a), export_files(run_b)
    diffs = {name: _file_diff(name, fa[name], fb[name], (run_a, run_b)) for name in fa if name in fb}
    floats = [d for n, d in diffs.items() if not n.endswith(".png")]
    pngs = [d for n, d in diffs.items() if n.endswith(".png")]

    def largest(values: list[float]) -> float | None:
        worst = max(values, default=0.0)
        return None if math.isinf(worst) else worst

    return {
        "files": len(fa),
        "same_files": sorted(fa) == sorted(fb),
        "identical_files": sum(fa[n] == fb[n] for n in diffs),
        "max_float_diff": largest(floats),
        "max_png_diff": largest(pngs),
        "psnr": [_psnr(run_a), _psnr(run_b)],
    }


def run_farm_bench(
    clips: list[BenchClip],
    out: Path,
    command: list[str],
    preset: str = "draft",
    overrides: list[str] | None = None,
    workers: int = 2,
    cores: int | None = None,
    export_chunk: int | None = None,
) -> dict[str, Any]:
    """Time both routes on ``clips`` and write OUT/farm_bench.json; returns the record."""
    if len(clips) < 1:
        raise InputError(None, "no clips given", "pass two or more clip folders (frames/ and masks/ inside)")
    names = [c.name for c in clips]
    if len(set(names)) != len(names):
        raise InputError(None, f"two clips share a name ({names})", "pass clip folders with different names")
    if workers < 1 or (cores is not None and cores < 1):
        raise InputError(None, "--workers and --cores must be at least 1", "pass e.g. --workers 2")
    cores = cores or os.cpu_count() or 1
    per_worker = max(1, cores // workers)
    out = out.resolve()
    ours = {ROUTE_SEQUENTIAL, ROUTE_DASK, FARM_BENCH_JSON}
    if out.is_dir() and not set(os.listdir(out)) <= ours:
        raise InputError(out, "holds files other than an earlier farm bench's", "pass a new or empty --out folder")
    for name in ours:  # an earlier measurement's runs: fitted again from scratch
        shutil.rmtree(out / name, ignore_errors=True)
        with contextlib.suppress(FileNotFoundError, IsADirectoryError):
            (out / name).unlink()
    out.mkdir(parents=True, exist_ok=True)
    sets = list(overrides or [])
    record: dict[str, Any] = {
        "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "machine": {**machine(), "cores_used": cores},
        "command": command,
        "shots": [{"name": c.name, "plate": str(c.frames), "masks": [str(m) for m in c.masks]} for c in clips],
        "preset": preset,
        "set": sets,
        "routes": {},
    }
    seq_shots = write_shots_file(
        out / ROUTE_SEQUENTIAL / "shots.json", clips, out / ROUTE_SEQUENTIAL / "runs", preset, sets, export_chunk
    )
    seconds = run_sequential(seq_shots, cores, out / ROUTE_SEQUENTIAL / "engine.log")
    record["routes"][ROUTE_SEQUENTIAL] = {"workers": 1, "threads_per_engine": cores, "seconds": round(seconds, 2)}
    dask_shots = write_shots_file(
        out / ROUTE_DASK / "shots.json", clips, out / ROUTE_DASK / "runs", preset, sets, export_chunk
    )
    seconds = run_dask_route(dask_shots, workers, per_worker, out / ROUTE_DASK)
    record["routes"][ROUTE_DASK] = {"workers": workers, "threads_per_engine": per_worker, "seconds": round(seconds, 2)}
    record["ratio"] = round(record["routes"][ROUTE_SEQUENTIAL]["seconds"] / max(seconds, 1e-9), 3)
    runs = {route: out / route / "runs" for route in (ROUTE_SEQUENTIAL, ROUTE_DASK)}
    record["exports"] = {
        c.name: compare_exports(runs[ROUTE_SEQUENTIAL] / c.name, runs[ROUTE_DASK] / c.name) for c in clips
    }
    (out / FARM_BENCH_JSON).write_text(json.dumps(record, indent=2))
    return record


def _export_summary(name: str, e: dict[str, Any]) -> str:
    same = "the same files" if e["same_files"] else "different files"
    text = f"{name}: {same}, {e['identical_files']}/{e['files']} byte for byte"
    if e["max_float_diff"] is not None and e["max_png_diff"] is not None:
        text += f", values within {max(e['max_float_diff'], e['max_png_diff']):.2g}"
    psnr = e["psnr"]
    if None not in psnr:
        text += f", PSNR {psnr[0]:.2f} / {psnr[1]:.2f} dB"
    return text


def format_table(record: dict[str, Any]) -> str:
    """The measurement as markdown: when, where, how, then one row per route and the ratio."""
    m, routes = record["machine"], record["routes"]
    lines = [
        f"Measured {record['date']} on {m['cpu']} ({m['cores']} cores, {m['cores_used']} used), "
        f"{len(record['shots'])} shots ({', '.join(s['name'] for s in record['shots'])}), preset {record['preset']}.",
        "",
        "Command: `" + " ".join(record["command"]) + "`",
        "",
        "| route | engines at once | torch threads each | wall time (s) |",
        "|---|---:|---:|---:|",
        f"| one after another | 1 | {routes[ROUTE_SEQUENTIAL]['threads_per_engine']} | "
        f"{routes[ROUTE_SEQUENTIAL]['seconds']:.1f} |",
        f"| Dask, {routes[ROUTE_DASK]['workers']} workers | {routes[ROUTE_DASK]['workers']} | "
        f"{routes[ROUTE_DASK]['threads_per_engine']} | {routes[ROUTE_DASK]['seconds']:.1f} |",
        "",
        f"Ratio (one after another / Dask): **{record['ratio']:.2f}x**.",
        "",
        "Exports of the two routes (one after another / Dask): "
        + "; ".join(_export_summary(name, e) for name, e in record["exports"].items())
        + ".",
    ]
    return "\n".join(lines)


__all__ = [
    "FARM_BENCH_JSON",
    "LocalDask",
    "compare_exports",
    "export_files",
    "format_table",
    "local_dask",
    "machine",
    "run_farm_bench",
    "stop_process",
    "write_shots_file",
]
