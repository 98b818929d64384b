"""A hand-made export (plate, passes, manifest) with known UVs: tests of render/project without a fit."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from engine import contract as C
from engine.export.manifest_writer import layer_record
from engine.export.pass_files import stmap_values
from engine.io.images import write_exr, write_png
from engine.terms.export_names import (
    ATLASES_DIR,
    EDITS_DIR,
    PASSES_DIR,
    STMAP_CHANNELS,
    alpha_pass,
    layer_name,
    pass_file_name,
    stmap_channel_name,
    uv_pass,
)
from engine.terms.manifest import MANIFEST_TAG, MANIFEST_VERSION, validate_manifest
from engine.terms.versions import ENGINE_VERSION

UVFn = Callable[[int, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]


def make_fake_export(
    folder: Path,
    plate: np.ndarray,
    layers: list[tuple[UVFn, tuple[int, int]]],
) -> Path:
    """``plate`` float [T, H, W, 3] in [0, 1] (written as 8-bit sRGB PNG frames); ``layers`` = per layer a
    function (t, xs, ys) -> (u, v, alpha) over pixel-centre grids, and its atlas size. Returns the manifest."""
    t_count, h, w, _ = plate.shape
    frames_dir = folder / "clip"
    frames_dir.mkdir(parents=True, exist_ok=True)
    files = []
    for t in range(t_count):
        path = frames_dir / f"{t:05d}.png"
        write_png(path, plate[t], 8)
        files.append(str(path))
    export = folder / "run" / C.EXPORTS_DIR / "v001"
    edits = folder / "run" / EDITS_DIR
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64) + 0.5
    names = [layer_name(i, len(layers)) for i in range(len(layers))]
    for t in range(t_count):
        chans = {}
        for name, (fn, _) in zip(names, layers, strict=True):
            u, v, a = fn(t, xs, ys)
            inside = (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
            u_name, v_name, coverage_name = (C.channel_name(uv_pass(name), c) for c in C.UV_CHANNELS)
            chans[u_name] = np.clip(u, 0, 1)
            chans[v_name] = np.clip(v, 0, 1)
            chans[coverage_name] = a * inside
            chans[C.channel_name(alpha_pass(name), "V")] = a
            for channel, values in zip(STMAP_CHANNELS, stmap_values(chans, uv_pass(name)), strict=True):
                chans[stmap_channel_name(name, channel)] = values
        write_exr(export / PASSES_DIR / pass_file_name(t), chans)
    layer_recs = []
    for i, (name, (_, (aw, ah))) in enumerate(zip(names, layers, strict=True)):
        write_png(edits / f"{name}.png", np.zeros((ah, aw, 4), np.float32), 8)
        write_png(export / ATLASES_DIR / f"{name}.png", np.ones((ah, aw, 4), np.float32) * 0.5, 16)
        layer_recs.append(layer_record(name, i, (aw, ah), (-1.0, -1.0, 1.0, 1.0), f"../../edits/{name}.png"))
    manifest = {
        MANIFEST_TAG: MANIFEST_VERSION,
        "engine_version": ENGINE_VERSION,
        "run_dir": str(folder / "run"),
        "created": "2026-01-01T00:00:00+00:00",
        "clip": {
            "source": str(frames_dir),
            "kind": "sequence",
            "frame_files": files,
            "frame_numbers": list(range(t_count)),
            "first_frame": 0,
            "last_frame": t_count - 1,
            "fps": None,
            "resolution": [w, h],
            "working_resolution": [w, h],
            "colorspace": "sRGB",
        },
        "passes": {
            "dir": "passes",
            "pattern": "atlas.{frame:05d}.exr",
            "blender_pattern": "atlas.#####.exr",
            "frames": list(range(t_count)),
            "exr_layer": "Atlas",
            "resolution": [w, h],
        },
        "layers": layer_recs,
        "fit": {"preset": "fake", "model": "fake", "steps": 0, "train_seconds": 0.0, "psnr": None, "alpha_iou": None},
    }
    path = export / C.MANIFEST_NAME
    path.write_text(json.dumps(validate_manifest(manifest)))
    return path
