"""Time the Live Preview of a large plate at full size and at proxy sizes (docs/addon.md, *Live preview*), headless.

A fake export (``fake_export.make_export``: a noise plate as 8-bit PNGs, two layers' passes as float EXRs) of
``--frames`` frames at ``--size`` is written once in ``--work``. Then, for each size of ``--proxies``, two Blenders
of their own (the bpy module; fresh processes, so nothing is cached from another size):

- **build**: Import Atlas with the panel's Preview Size set, the preview's files removed first, so the import writes
  them (what choosing a new size costs the first time): its time, and the process's peak resident set.
- **ticks**: Import Atlas again (the files are there now), then ``--ticks`` frame changes. A tick is what a frame
  change costs the viewport: ``scene.frame_set(F)`` then a Cycles render (CPU, 1 sample) of the preview through its
  camera at an eighth of the plate's size, as Rendered shading draws the new frame; each tick's images are freed
  first (``Image.buffers_free``), as for a frame not seen before. "render only" is the same render again at the
  same frame. Memory: Blender's own (the ``Mem``/``Peak`` of its render lines: its allocator, image buffers
  included; and Cycles' peak), and the process's resident set once the preview is built and its peak over the
  ticks (``/proc/self/status``). Below 100 %, the time Blender takes to load one UV file, as written (uncompressed)
  and ZIP compressed.

    .venv/bin/python tests/addon/bench_live_preview.py [--size 4096x2160] [--frames 4] [--proxies 100,50]
        [--ticks 8] [--work DIR] [--out docs/bench/live-preview-4k.json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path[:0] = [str(ROOT), str(HERE)]

#: The render of a tick: this fraction of the plate's sides (a viewport's share of the plate; the load is the same).
TICK_RENDER_FRACTION = 8
#: A render's status line: Blender's memory now and its peak, then Cycles' (MB).
RENDER_LINE = re.compile(r"Mem:([\d.]+)M \(Peak ([\d.]+)M\) \| Time:[^|]*\| Mem:([\d.]+)M, Peak:([\d.]+)M")


def _memory_mb() -> dict[str, float]:
    """The resident set now and its peak (MB), from /proc/self/status."""
    fields = dict(line.split(":", 1) for line in Path("/proc/self/status").read_text().splitlines() if ":" in line)
    return {k: int(fields[k].split()[0]) / 1024 for k in ("VmRSS", "VmHWM")}


def _reset_peak() -> bool:
    """Reset the peak resident set (Linux: clear_refs 5); False where it cannot be."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        return False
    return True


def _import(manifest: Path, percent: int) -> tuple[object, float]:
    """A factory-fresh scene with Preview Size ``percent`` and ``manifest`` imported: (scene, seconds)."""
    import bpy
    from neural_atlas import addon
    from neural_atlas.addon.core import preview_proxy as X

    addon.register()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.neural_atlas.preview_proxy = X.choice_id(percent)
    start = time.perf_counter()
    assert bpy.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest)) == {"FINISHED"}
    return scene, time.perf_counter() - start


def build(manifest: Path, percent: int) -> dict[str, object]:
    """The import that writes the preview's files."""
    _, seconds = _import(manifest, percent)
    return {"import_writing_preview_files_seconds": seconds, "rss_peak_mb_import": _memory_mb()["VmHWM"]}


def ticks(manifest: Path, percent: int, count: int) -> dict[str, object]:
    """The import with the files there, then ``count`` ticks."""
    import bpy
    from neural_atlas.addon.core import preview_plan as V
    from neural_atlas.addon.core import preview_proxy as X

    scene, import_s = _import(manifest, percent)
    folder = manifest.parent
    layers = scene.neural_atlas.imported_layers.split(", ")
    images = [bpy.data.images[n] for n in (V.PREVIEW_PLATE_IMAGE, *(V.uv_image_name(layer) for layer in layers))]
    sizes = {}
    for img in images:  # a sequence image's size is its files': the first one's, loaded on its own
        first = bpy.data.images.load(bpy.path.abspath(img.filepath), check_existing=False)
        sizes[img.name] = list(first.size)
        bpy.data.images.remove(first)
    w, h = scene.render.resolution_x, scene.render.resolution_y
    r, cycles = scene.render, scene.cycles
    r.engine, r.use_compositing, r.use_sequencer = "CYCLES", False, False
    r.resolution_x, r.resolution_y, r.resolution_percentage = w // TICK_RENDER_FRACTION, h // TICK_RENDER_FRACTION, 100
    cycles.device, cycles.samples, cycles.use_adaptive_sampling, cycles.use_denoising = "CPU", 1, False, False
    scene.camera = bpy.data.objects[V.PREVIEW_CAMERA]
    frames = list(range(scene.frame_start, scene.frame_end + 1))
    memory_built = _memory_mb()
    peak_reset = _reset_peak()
    tick_s, render_s = [], []
    for k in range(count):
        frame = frames[(k + 1) % len(frames)]
        for img in images:
            img.buffers_free()
        start = time.perf_counter()
        scene.frame_set(frame)
        bpy.ops.render.render(write_still=False)
        tick_s.append(time.perf_counter() - start)
        start = time.perf_counter()
        bpy.ops.render.render(write_still=False)  # the same frame again
        render_s.append(time.perf_counter() - start)
    memory_ticks = _memory_mb()
    loads = _uv_file_loads(bpy.path.abspath(images[-1].filepath)) if percent != X.FULL else {}
    on_disk = {
        d: sum(f.stat().st_size for f in (folder / d).rglob("*") if f.is_file())
        for d in (V.PREVIEW_UV_DIR, X.PROXY_DIR)
        if (folder / d).exists()
    }
    return {
        "percent": percent,
        "preview_size": list(X.proxy_size((w, h), percent)),
        "image_sizes": sizes,
        "import_with_preview_files_there_seconds": import_s,
        "tick_render_size": [r.resolution_x, r.resolution_y],
        "tick_seconds": tick_s,
        "tick_median_seconds": statistics.median(tick_s),
        "render_only_seconds": render_s,
        "render_only_median_seconds": statistics.median(render_s),
        "rss_mb_preview_built": memory_built["VmRSS"],
        "rss_mb_after_ticks": memory_ticks["VmRSS"],
        "rss_peak_mb_ticks" if peak_reset else "rss_peak_mb_process": memory_ticks["VmHWM"],
        "preview_files_bytes": on_disk,
        "frames": len(frames),
        "uv_file_load_seconds": loads,
    }


def _uv_file_loads(path: str, repeats: int = 5) -> dict[str, float]:
    """The median time Blender takes to load one UV file as written (uncompressed) and the same pixels ZIP
    compressed (``exr_passes``), the pixels taken in (``size`` reads them)."""
    import bpy
    from neural_atlas.addon.core import exr_passes

    zipped = f"{path}.zip.exr"
    ch = exr_passes.read_channels(path, ("R", "G", "B"))
    exr_passes.write_rgb(zipped, ch["R"], ch["G"], ch["B"])
    times: dict[str, list[float]] = {"none": [], "zip": []}
    try:
        for _ in range(repeats):
            for kind, file in (("none", path), ("zip", zipped)):
                start = time.perf_counter()
                img = bpy.data.images.load(file, check_existing=False)
                assert img.size[0] > 0
                times[kind].append(time.perf_counter() - start)
                bpy.data.images.remove(img)
    finally:
        os.remove(zipped)
    return {kind: statistics.median(t) for kind, t in times.items()}


def _blender_memory(stdout: str) -> dict[str, float]:
    """The largest of Blender's and Cycles' memory figures in a process's render lines (MB)."""
    found = [tuple(map(float, m.groups())) for m in RENDER_LINE.finditer(stdout)]
    if not found:
        return {}
    return {
        "blender_mem_mb_max": max(f[0] for f in found),
        "blender_peak_mb": max(f[1] for f in found),
        "cycles_peak_mb": max(f[3] for f in found),
    }


def _machine() -> dict[str, object]:
    lines = Path("/proc/cpuinfo").read_text().splitlines()
    cpu = next((line.split(":", 1)[1].strip() for line in lines if "model name" in line), platform.processor())
    return {"cpu": cpu, "cores": os.cpu_count(), "load_average": list(os.getloadavg()), "platform": platform.platform()}


def _run(mode: str, manifest: Path, percent: int, ticks_count: int, work: Path) -> tuple[dict[str, object], str]:
    result = work / f"{mode}_{percent}.json"
    result.unlink(missing_ok=True)
    cmd = [sys.executable, __file__, "--ticks", str(ticks_count), "--child", mode, str(manifest), str(percent)]
    done = subprocess.run([*cmd, str(result)], capture_output=True, text=True, timeout=7200)
    if done.returncode != 0 or not result.exists():
        sys.exit(f"the {percent}% {mode} failed:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}")
    return json.loads(result.read_text()), done.stdout


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="4096x2160", help="the plate's WIDTHxHEIGHT")
    ap.add_argument("--frames", type=int, default=4)
    ap.add_argument("--proxies", default="100,50", help="the Preview Sizes to time, percent, comma separated")
    ap.add_argument("--ticks", type=int, default=8)
    ap.add_argument("--work", type=Path, default=None, help="where the fake export is written (kept; default: a temp)")
    ap.add_argument("--out", type=Path, default=None, help="the JSON report (default: print only)")
    ap.add_argument("--child", nargs=4, metavar=("MODE", "MANIFEST", "PERCENT", "RESULT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        import conftest  # noqa: F401  (imports the checkout as the package neural_atlas)

        mode, manifest, percent, result = args.child
        got = (
            build(Path(manifest), int(percent)) if mode == "build" else ticks(Path(manifest), int(percent), args.ticks)
        )
        Path(result).write_text(json.dumps(got, indent=1))
        sys.stdout.flush()
        os._exit(0)  # bpy < 5 can hang at exit (docs/blender-compat.md)
    import fake_export as FX

    size = tuple(int(s) for s in args.size.lower().split("x"))
    work = args.work or Path(tempfile.mkdtemp(prefix="na_preview_bench_"))
    manifest = work / "run" / "exports" / "v001" / "manifest.json"
    start = time.perf_counter()
    if not manifest.exists():
        frames = tuple(range(1001, 1001 + args.frames))
        manifest = FX.make_export(work, frames=frames, size=(size[0], size[1]))
    print(f"fake export {size[0]}x{size[1]}, {args.frames} frames: {manifest} ({time.perf_counter() - start:.0f} s)")
    runs = []
    for percent in (int(p) for p in args.proxies.split(",")):
        for made in ("preview_uv", "preview_proxy"):
            shutil.rmtree(manifest.parent / made, ignore_errors=True)
        built, _ = _run("build", manifest, percent, args.ticks, work)
        ticked, stdout = _run("ticks", manifest, percent, args.ticks, work)
        run = {**ticked, **built, **_blender_memory(stdout)}
        runs.append(run)
        print(f"{percent}%: " + json.dumps({k: v for k, v in run.items() if not isinstance(v, list | dict)}))
    import bpy  # only its version: the runs were in their own processes

    report = {
        "tool": "tests/addon/bench_live_preview.py",
        "command": " ".join([".venv/bin/python", "tests/addon/bench_live_preview.py", *sys.argv[1:]]),
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "machine": _machine(),
        "bpy": bpy.app.version_string,
        "plate": {"size": list(size), "frames": args.frames, "kind": "8-bit PNG sequence (noise)", "layers": 2},
        "tick": f"frame_set + a 1-sample Cycles CPU render at 1/{TICK_RENDER_FRACTION} of the plate's size, the "
        "preview's images freed first",
        "runs": runs,
    }
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=1) + "\n")
        print(f"wrote {args.out}")
    sys.stdout.flush()
    os._exit(0)


if __name__ == "__main__":
    main()
