"""The embedded demo: a generated plate with a moving object, fitted, exported, edited and rendered.

README command 1 runs this. It needs nothing outside the repository (no ``../shared``, no downloads),
and is idempotent: a second run reuses the clip, a finished fit (an interrupted one resumes), the newest
complete export, and a render that is newer than its inputs.

The example edit stands in for an artist's paint: a logo on the foreground atlas and a stylised
background atlas. It is written to ``example_edits/`` and passed to ``render`` as an override, so the
run's own edit layers (the artist's) stay untouched.
"""

from __future__ import annotations

import io
import json
import sys
from pathlib import Path

import cv2
import numpy as np
import torch

from engine import contract as C
from engine.compositing import load_edit
from engine.config import apply_overrides, preset_config
from engine.export import export_run
from engine.fit_preview import write_contact_sheet
from engine.image_io import read_image, write_png
from engine.manifest import Manifest
from engine.preview import checker_edits, grid, label, tile, write_png_u8, write_previews
from engine.render import plate_frames, render_frames, render_manifest, to_display_u8
from engine.synthetic import demo_spec, make_scene, write_scene
from engine.trainer import FitCancelled, fit, load_run

DEMO_ATLAS_SIZE = 512


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


def _newest_export(run: Path) -> Path | None:
    """The newest complete export made after the fit's last checkpoint (else None: export again)."""
    ckpt = (run / C.RUN_CHECKPOINT).stat().st_mtime
    found = sorted((run / C.EXPORTS_DIR).glob(f"v*/{C.MANIFEST_NAME}")) if (run / C.EXPORTS_DIR).exists() else []
    for manifest in reversed(found):
        if manifest.stat().st_mtime >= ckpt:
            return manifest
    return None


def _up_to_date(outputs: list[Path], inputs: list[Path]) -> bool:
    if not all(p.exists() for p in outputs):
        return False
    return min(p.stat().st_mtime for p in outputs) >= max(p.stat().st_mtime for p in inputs)


def demo_contact_sheet(manifest: Manifest, edits: list[np.ndarray | None], path: Path) -> Path:
    """Rows: original | checkerboard on the foreground | edited, for a few frames; then atlases and edits."""
    frames = manifest.frames
    picks = sorted({frames[round(i * (len(frames) - 1) / 3)] for i in range(4)})
    checker = checker_edits(manifest)
    rows = [
        [label(tile(to_display_u8(p)), f"original {n}") for n, p in plate_frames(manifest, picks)],
        [label(tile(to_display_u8(f)), f"checkerboard {n}") for n, f in render_frames(manifest, checker, picks)],
        [label(tile(to_display_u8(f)), f"edited {n}") for n, f in render_frames(manifest, edits, picks)],
    ]
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
    out = Path(out)
    _say(f"demo clip -> {out / 'clip'}")
    frames_dir, masks_dir = write_scene(make_scene(demo_spec()), out / "clip")
    run = out / "run"
    cfg = apply_overrides(preset_config(preset), overrides or {})
    if (run / C.RUN_METRICS).exists():
        _say(f"1/5 fit already done in {run} (delete it to refit)")
    else:
        resume = (run / C.RUN_CHECKPOINT).exists()
        _say(f"1/5 {'resuming' if resume else 'fitting'} ({preset}) -> {run}")
        try:
            # the bar on stderr is for people; the JSON progress lines go to the run's fit.log only
            fit(frames_dir, [masks_dir], run, cfg, resume=resume, stream=io.StringIO())
        except FitCancelled:
            _say(f"cancelled; run the same command again to resume {run}")
            raise
    metrics = json.loads((run / C.RUN_METRICS).read_text())
    model, prepared, _ = load_run(run)
    fit_sheet = write_contact_sheet(model, prepared.frames, prepared.size, torch.device("cpu"), out / "fit_sheet.png")

    manifest_path = _newest_export(run)
    if manifest_path is None:
        _say(f"2/5 export (UV + alpha EXR passes, atlases) -> {run / C.EXPORTS_DIR}")
        manifest_path = export_run(run, atlas_size=DEMO_ATLAS_SIZE, stream=io.StringIO())
    else:
        _say(f"2/5 export already done: {manifest_path.parent}")
    manifest = Manifest(manifest_path)
    preview_dir = manifest.folder / "preview"
    if not (preview_dir / "frames.png").exists():
        _say(f"3/5 preview (atlases, checkerboard, label propagation) -> {preview_dir}")
        write_previews(manifest_path, preview_dir)
    else:
        _say(f"3/5 preview already done: {preview_dir}")

    edits_dir = out / "example_edits"
    fg_edit, bg_edit = edits_dir / "Foreground.png", edits_dir / "Background.png"
    if not _up_to_date([fg_edit, bg_edit], [manifest_path]):
        _say(f"4/5 example edit: a logo on the foreground atlas, a stylised background -> {edits_dir}")
        fg = manifest.layer("Foreground")
        write_png(fg_edit, logo_edit(tuple(fg["atlas_size"])), 8)
        write_png(bg_edit, stylised_background(manifest.resolve(manifest.layer("Background")["atlas_png"])), 8)
    else:
        _say(f"4/5 example edit already made: {edits_dir}")
    edited, movie = out / "edited", out / "edited.mp4"
    overrides_edit = {"Foreground": str(fg_edit), "Background": str(bg_edit)}
    last_frame = edited / f"edit.{manifest.frames[-1]:05d}.png"
    if not _up_to_date([last_frame, movie], [fg_edit, bg_edit, manifest_path]):
        _say(f"5/5 render the edited clip -> {edited}, {movie}")
        render_manifest(manifest_path, edited, overrides_edit, fmt="png", movie=movie)
    else:
        _say(f"5/5 edited clip already rendered: {edited}")
    sheet = demo_contact_sheet(manifest, [load_edit(bg_edit), load_edit(fg_edit)], out / "contact_sheet.png")
    print(
        f"== done: PSNR {metrics['psnr']:.2f} dB, foreground alpha IoU {metrics['alpha_iou'][0]:.3f}, "
        f"{metrics['steps']} steps in {metrics['train_seconds']:.0f} s\n"
        f"   clip:    {out / 'clip'}\n"
        f"   fit:     {run} (config.json, metrics.json, checkpoint.pt, fit.log; {fit_sheet.name})\n"
        f"   export:  {manifest_path}\n"
        f"   preview: {preview_dir}\n"
        f"   edited:  {edited} and {movie} (example edits in {edits_dir})\n"
        f"   look: {sheet}",
        file=sys.stderr,
    )
    return metrics
