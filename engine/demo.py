"""The embedded demo: a generated plate with a moving object, fitted, exported, edited and rendered.

README command 1 runs this. It needs nothing outside the repository (no clips, no downloads),
and is idempotent: a second run reuses the clip, a finished fit (an interrupted one resumes), the newest
complete export, and a render that is newer than its inputs.

The example edit stands in for an artist's paint: a logo on the foreground atlas and a stylised
background atlas. It is written to ``example_edits/`` and passed to ``render`` as an override, so the
run's own edit layers (the artist's) stay untouched.

Step 6 does what an artist would do in Blender, headless: ``addon/headless.py`` (run by a Python that has
``bpy``, or a ``blender`` binary; the engine itself never imports bpy) builds ``demo.blend`` with the add-on's
compositor tree and the same example edits as edit layers, and renders the edited clip through the
compositor. The demo compares that render with the engine's and prints the max abs error. Without Blender
the step is skipped with a message saying how to enable it.
"""

from __future__ import annotations

import importlib.util
import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

from . import contract as C
from .config import apply_overrides, preset_config
from .data.synthetic import demo_spec, make_scene, write_scene
from .edit.equations import load_edit
from .edit.preview import checker_edits, grid, label, tile, write_png_u8, write_previews
from .edit.render import RenderSettings, plate_frames, render_frames, render_manifest, to_display_u8
from .export.exporter import export_run
from .export.manifest import Manifest
from .fit.contact_sheet import write_contact_sheet
from .fit.fit_inputs import FitInputs
from .fit.fitted_run import load_run
from .fit.run_folder import RunFolder
from .fit.run_plan import PLAN_RESUME, PLAN_START, FitPlan
from .fit.trainer import FitCancelled, fit
from .io.atomic import atomic_write_text
from .io.images import read_image, write_png
from .terms import cli as cli_terms

DEMO_ATLAS_SIZE = 512
ROOT = Path(__file__).resolve().parents[1]
HEADLESS_SCRIPT = ROOT / cli_terms.HEADLESS_SCRIPT
#: Blender's own render step for 24 small frames takes seconds; this only stops a hung Blender.
BLENDER_TIMEOUT_S = 600
#: Where `NEURAL_ATLAS_BLENDER` can point: a `blender` binary, or a Python 3.11 with the `bpy` module.
BLENDER_ENV = "NEURAL_ATLAS_BLENDER"


def _say(text: str) -> None:
    print(f"== {text}", file=sys.stderr, flush=True)


def logo_edit(size: tuple[int, int]) -> np.ndarray:
    """A ring and two letters, sRGB straight-alpha RGBA [H, W, 4], centred on the atlas."""
    w, h = size
    img = np.zeros((h, w, 4), np.uint8)
    c, r = (w // 2, h // 2), int(min(w, h) * 0.28)
    thick = max(2, min(w, h) // 40)
    cv2.circle(img, c, r, (20, 20, 20, 255), thick * 3, cv2.LINE_AA)
    cv2.circle(img, c, r, (255, 255, 255, 255), thick, cv2.LINE_AA)
    scale = min(w, h) / 220.0
    (tw, th), _ = cv2.getTextSize("NA", cv2.FONT_HERSHEY_DUPLEX, scale, thick)
    org = (c[0] - tw // 2, c[1] + th // 2)
    cv2.putText(img, "NA", org, cv2.FONT_HERSHEY_DUPLEX, scale, (20, 20, 20, 255), thick * 3, cv2.LINE_AA)
    cv2.putText(img, "NA", org, cv2.FONT_HERSHEY_DUPLEX, scale, (255, 235, 60, 255), thick, cv2.LINE_AA)
    return img.astype(np.float32) / 255.0


def stylised_background(atlas_png: Path) -> np.ndarray:
    """The background atlas as a painting (OpenCV's edge-preserving stylisation), opaque where it is seen."""
    pixels, _ = read_image(atlas_png)
    rgb8 = np.rint(np.clip(pixels[..., :3], 0, 1) * 255).astype(np.uint8)
    styl = cv2.stylization(rgb8[..., ::-1].copy(), sigma_s=40, sigma_r=0.35)[..., ::-1]
    warm = np.clip(styl.astype(np.float32) / 255.0 * np.float32([1.08, 0.98, 0.85]), 0, 1)
    alpha = (pixels[..., 3:4] > 0.5).astype(np.float32)
    return np.concatenate((warm, alpha), -1)


def _newest_export(run: RunFolder) -> Path | None:
    """The newest complete export made after the fit's last checkpoint (else None: export again)."""
    ckpt = run.checkpoint.stat().st_mtime
    found = sorted(run.exports.glob(f"v*/{C.MANIFEST_NAME}")) if run.exports.exists() else []
    for manifest in reversed(found):
        if manifest.stat().st_mtime >= ckpt:
            return manifest
    return None


def _up_to_date(outputs: list[Path], inputs: list[Path]) -> bool:
    if not all(p.exists() for p in outputs):
        return False
    return min(p.stat().st_mtime for p in outputs) >= max(p.stat().st_mtime for p in inputs)


def blender_command() -> tuple[list[str], str] | None:
    """(argv prefix that runs ``addon/headless.py`` with Blender, description), or None when there is none.

    In order: ``NEURAL_ATLAS_BLENDER`` (a ``blender`` binary or a Python with bpy), this Python if it has the
    ``bpy`` module (the checkout's .venv does: bpy 4.5), ``blender`` on PATH. ``find_spec`` only looks:
    the engine process never imports bpy."""
    script = str(HEADLESS_SCRIPT)
    blender_args = ["-b", "--factory-startup", "--python-exit-code", "1", "-P", script, "--"]
    env = os.environ.get(BLENDER_ENV)
    if env:
        exe = shutil.which(env) or env
        if "blender" in Path(exe).name.lower():
            return [exe, *blender_args], f"{exe} (${BLENDER_ENV})"
        return [exe, script, "--"], f"{exe} (${BLENDER_ENV})"
    if importlib.util.find_spec("bpy") is not None:
        return [sys.executable, script, "--"], f"{sys.executable} (bpy module)"
    exe = shutil.which("blender")
    if exe:
        return [exe, *blender_args], exe
    return None


def blender_render(
    manifest_path: Path, edits: dict[str, str], blend: Path, render_dir: Path, report: Path
) -> dict | None:
    """Run ``addon/headless.py``: the .blend and the compositor's render (exact filter); its JSON report."""
    found = blender_command()
    if found is None:
        _say(
            "6/6 Blender render skipped: no Python with the bpy module and no `blender` on PATH "
            f"(set {BLENDER_ENV}=/path/to/blender to enable it)"
        )
        return None
    argv, what = found
    argv = [*argv, str(manifest_path), "--blend", str(blend), "--render", str(render_dir), "--filter", "exact"]
    for name, path in edits.items():
        argv += ["--edit", f"{name}={path}"]
    argv += ["--report", str(report)]
    _say(f"6/6 Blender: {blend.name} with the add-on's tree and the example edits, render -> {render_dir} ({what})")
    if render_dir.exists():
        shutil.rmtree(render_dir)  # a fresh render: no stale frame from an earlier run is compared
    try:
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=BLENDER_TIMEOUT_S, cwd=ROOT)
    except subprocess.TimeoutExpired:
        _say(f"6/6 Blender render did not finish in {BLENDER_TIMEOUT_S} s: skipped (the engine render is complete)")
        return None
    if proc.returncode != 0 or not report.exists():
        tail = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        _say(f"6/6 Blender render failed (exit {proc.returncode}): {tail}")
        return None
    return json.loads(report.read_text())


def compare_with_engine(manifest: Manifest, edits: list[np.ndarray | None], info: dict) -> dict:
    """Max abs error (linear) between Blender's EXR frames and the engine's render with the matching filter."""
    errors = []
    for number, frame in render_frames(manifest, edits, filter=info["engine_filter"]):
        pixels, _ = read_image(Path(info["render_dir"]) / f"edit.{number:05d}.exr")
        errors.append(float(np.abs(pixels[..., :3] - frame).max()))
    return {"max_abs_error": max(errors), "frames": len(errors), "engine_filter": info["engine_filter"]}


def demo_contact_sheet(
    manifest: Manifest, edits: list[np.ndarray | None], path: Path, blender_dir: Path | None = None
) -> Path:
    """Rows: original | checkerboard on the foreground | edited (engine) | edited (Blender's compositor, when
    it ran), for a few frames; then atlases and edits."""
    frames = manifest.frames
    picks = sorted({frames[round(i * (len(frames) - 1) / 3)] for i in range(4)})
    checker = checker_edits(manifest)
    rows = [
        [label(tile(to_display_u8(p)), f"original {n}") for n, p in plate_frames(manifest, picks)],
        [label(tile(to_display_u8(f)), f"checkerboard {n}") for n, f in render_frames(manifest, checker, picks)],
        [label(tile(to_display_u8(f)), f"edited {n}") for n, f in render_frames(manifest, edits, picks)],
    ]
    if blender_dir is not None:
        shots = [(n, read_image(blender_dir / f"edit.{n:05d}.exr")[0][..., :3]) for n in picks]
        rows.append([label(tile(to_display_u8(f)), f"Blender {n}") for n, f in shots])
    atlas_row = []
    for layer, edit in zip(manifest.layers, edits, strict=True):
        pixels, _ = read_image(manifest.resolve(layer["atlas_png"]))
        atlas = pixels[..., :3] * pixels[..., 3:4]
        atlas_row.append(label(tile((np.clip(atlas, 0, 1) * 255).astype(np.uint8), 240), f"{layer['name']} atlas"))
        if edit is not None:
            shown = np.clip(edit[..., :3] + (1 - edit[..., 3:4]) * 0.5, 0, 1)  # premultiplied over grey, linear
            atlas_row.append(label(tile(to_display_u8(shown), 240), f"{layer['name']} edit"))
    rows.append(atlas_row)
    return write_png_u8(path, grid(rows))


def run_demo(out: Path, preset: str = "draft", overrides: dict[str, str] | None = None) -> dict:
    """README command 1: the six steps, each skipped when its output is already there and up to date (so a second
    run costs seconds); the fit's metrics."""
    out = Path(out)
    _say(f"demo clip -> {out / 'clip'}")  # steps 1-5: the engine; 6: Blender
    frames_dir, masks_dir = write_scene(make_scene(demo_spec()), out / "clip")
    run = out / "run"
    folder = RunFolder(run)
    metrics = _fit_step(folder, frames_dir, masks_dir, preset, overrides)
    model, prepared, _ = load_run(run)
    fit_sheet = write_contact_sheet(model, prepared.frames, prepared.size, torch.device("cpu"), out / "fit_sheet.png")

    manifest_path, manifest, preview_dir = _export_step(folder)
    edits_dir = out / "example_edits"
    fg_edit, bg_edit = edits_dir / "Foreground.png", edits_dir / "Background.png"
    _example_edit_step(manifest, manifest_path, fg_edit, bg_edit)
    edited, movie = out / "edited", out / "edited.mp4"
    overrides_edit = {"Foreground": str(fg_edit), "Background": str(bg_edit)}
    _render_step(manifest, manifest_path, [fg_edit, bg_edit], overrides_edit, edited, movie)
    edit_arrays: list[np.ndarray | None] = [load_edit(bg_edit), load_edit(fg_edit)]

    blend, blender_dir = out / "demo.blend", out / "blender"
    compare = _blender_step(out, manifest, manifest_path, [fg_edit, bg_edit], overrides_edit, edit_arrays)
    sheet = demo_contact_sheet(
        manifest, edit_arrays, out / "contact_sheet.png", blender_dir if compare is not None else None
    )
    blender_line = (
        f"   blender: {blend} (open it in Blender 4.2+), its render {blender_dir}\n"
        if compare is not None
        else "   blender: skipped (no bpy / blender found)\n"
    )
    print(
        f"== done: PSNR {metrics['psnr']:.2f} dB, foreground alpha IoU {metrics['alpha_iou'][0]:.3f}, "
        f"{metrics['steps']} steps in {metrics['train_seconds']:.0f} s\n"
        f"   clip:    {out / 'clip'}\n"
        f"   fit:     {run} (config.json, metrics.json, checkpoint.pt, fit.log; {fit_sheet.name})\n"
        f"   export:  {manifest_path}\n"
        f"   preview: {preview_dir}\n"
        f"   edited:  {edited} and {movie} (example edits in {edits_dir})\n"
        f"{blender_line}"
        f"   look: {sheet}",
        file=sys.stderr,
    )
    return metrics


def _fit_step(
    folder: RunFolder, frames_dir: Path, masks_dir: Path, preset: str, overrides: dict[str, str] | None
) -> dict:
    """Step 1: fit the demo clip (a finished fit is kept, a stopped one resumes); its metrics."""
    run = folder.path
    cfg = apply_overrides(preset_config(preset), overrides or {})
    if folder.metrics.exists():
        _say(f"1/6 fit already done in {run} (delete it to refit)")
    else:
        resume = folder.checkpoint.exists()  # a demo fit that was stopped continues where it was
        _say(f"1/6 {'resuming' if resume else 'fitting'} ({preset}) -> {run}")
        try:
            # the bar on stderr is for people; the JSON progress lines go to the run's fit.log only
            plan = FitPlan(PLAN_RESUME if resume else PLAN_START, cfg, FitInputs(frames_dir, (masks_dir,)))
            fit(run, plan, stream=io.StringIO())
        except FitCancelled:
            _say(f"cancelled; run the same command again to resume {run}")
            raise
    metrics = folder.read_metrics()
    assert metrics is not None  # the fit above finished
    return metrics


def _export_step(folder: RunFolder) -> tuple[Path, Manifest, Path]:
    """Steps 2 and 3: the newest complete export (made when there is none) and its preview; (its manifest's path,
    the manifest, the preview folder)."""
    manifest_path = _newest_export(folder)
    if manifest_path is None:
        _say(f"2/6 export (UV + alpha EXR passes, atlases) -> {folder.exports}")
        manifest_path = export_run(folder.path, atlas_size=DEMO_ATLAS_SIZE, stream=io.StringIO())
    else:
        _say(f"2/6 export already done: {manifest_path.parent}")
    manifest = Manifest(manifest_path)
    preview_dir = manifest.folder / "preview"
    if not (preview_dir / "frames.png").exists():
        _say(f"3/6 preview (atlases, checkerboard, label propagation) -> {preview_dir}")
        write_previews(manifest_path, preview_dir)
    else:
        _say(f"3/6 preview already done: {preview_dir}")
    return manifest_path, manifest, preview_dir


def _example_edit_step(manifest: Manifest, manifest_path: Path, fg_edit: Path, bg_edit: Path) -> None:
    """Step 4: the artist's paint stood in for, a logo on the foreground atlas and a stylised background."""
    edits_dir = fg_edit.parent
    if not _up_to_date([fg_edit, bg_edit], [manifest_path]):
        _say(f"4/6 example edit: a logo on the foreground atlas, a stylised background -> {edits_dir}")
        fg = manifest.layer("Foreground")
        write_png(fg_edit, logo_edit(tuple(fg["atlas_size"])), 8)
        write_png(bg_edit, stylised_background(manifest.resolve(manifest.layer("Background")["atlas_png"])), 8)
    else:
        _say(f"4/6 example edit already made: {edits_dir}")


def _render_step(
    manifest: Manifest,
    manifest_path: Path,
    edits: list[Path],
    overrides_edit: dict[str, str],
    edited: Path,
    movie: Path,
) -> None:
    """Step 5: the edited clip rendered by the engine (the example ``edits`` as ``overrides_edit``), as PNG frames
    and a movie."""
    last_frame = edited / f"edit.{manifest.frames[-1]:05d}.png"
    if not _up_to_date([last_frame, movie], [*edits, manifest_path]):
        _say(f"5/6 render the edited clip -> {edited}, {movie}")
        render_manifest(manifest_path, edited, overrides_edit, RenderSettings("png"), movie=movie)
    else:
        _say(f"5/6 edited clip already rendered: {edited}")


def _blender_step(
    out: Path,
    manifest: Manifest,
    manifest_path: Path,
    edits: list[Path],
    overrides_edit: dict[str, str],
    edit_arrays: list[np.ndarray | None],
) -> dict | None:
    """Step 6: the same edit rendered by Blender's compositor, headless, and compared with the engine's render;
    the comparison, or None without Blender."""
    blend, blender_dir = out / "demo.blend", out / "blender"
    report, compare_path = out / "blender_render.json", out / "blender_compare.json"
    blender_outputs = [blend, report, compare_path] + [blender_dir / f"edit.{n:05d}.exr" for n in manifest.frames]
    compare = None
    if _up_to_date(blender_outputs, [*edits, manifest_path]):
        compare = json.loads(compare_path.read_text())
        _say(f"6/6 Blender render already done: {blender_dir}")
    else:
        info = blender_render(manifest_path, overrides_edit, blend, blender_dir, report)
        if info is not None:
            info["render_dir"] = str(blender_dir)
            compare = {**compare_with_engine(manifest, edit_arrays, info), "blender": info["blender"]}
            compare["filter"], compare["exact"] = info["filter"], info["exact"]
            atomic_write_text(compare_path, json.dumps(compare, indent=2))
    if compare is not None:
        why = "8-bit sRGB plate and edits: Blender decodes them with OCIO, the engine with the exact formula"
        _say(
            f"   Blender {compare['blender']} ({compare['filter']}) vs engine render ({compare['engine_filter']}): "
            f"max abs error {compare['max_abs_error']:.1e} over {compare['frames']} frames ({why})"
        )
    return compare
