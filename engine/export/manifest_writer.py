"""The manifest an export writes, and the Nuke script beside it.

The schema is ``engine.contract``'s (``validate_manifest`` checks what is written here) and
``engine.export.manifest`` reads it back. The manifest records every path relative to itself
(``relative_path``): a run folder moved or mounted elsewhere with its plate keeps working. Torch-free: an export
made by hand (without a fit) writes its layers' entries with ``layer_record`` too.
"""

from __future__ import annotations

import datetime
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .. import contract as C
from ..errors import InputError
from ..io.atomic import DISK_ERRORS, atomic_write_text
from ..terms.export_names import (
    ALPHA_CHANNELS,
    ATLAS_EXR_EXT,
    ATLAS_PNG_EXT,
    ATLASES_DIR,
    EDIT_LAYER_EXT,
    EXR_LAYER,
    NUKE_SCRIPT_NAME,
    PASSES_DIR,
    ROLE_BACKGROUND,
    STMAP_CHANNELS,
    alpha_pass,
    blender_pattern,
    pass_pattern,
    stmap_channel_name,
    stmap_pass,
    uv_pass,
)
from ..terms.manifest import MANIFEST_TAG, MANIFEST_VERSION
from ..terms.versions import ENGINE_VERSION
from .pass_files import pass_padding

if TYPE_CHECKING:
    from ..fit.fitted_run import FittedRun
    from ..fit.run_folder import ClipRecord
    from .plan import Plan


def layer_record(
    name: str,
    index: int,
    atlas_size: tuple[int, int],
    box: tuple[float, ...],
    edit_layer: str,
    follows_flow: bool = False,
    stmap: bool = True,
) -> dict[str, Any]:
    """One layer's manifest entry (terms.manifest.MANIFEST_LAYER_KEYS); paths relative to the export folder.
    ``follows_flow``: its UV was averaged along optical flow (``engine.export.follow_flow``); ``stmap``: the pass
    files hold its STMap copy (``stmap_pass``, ``stmap_channels``; absent otherwise)."""
    stmap_channels = [stmap_channel_name(name, c) for c in STMAP_CHANNELS]
    stmap_keys = {"stmap_pass": stmap_pass(name), "stmap_channels": stmap_channels}
    return {
        "name": name,
        "index": index,
        "role": ROLE_BACKGROUND if index == 0 else C.ROLE_FOREGROUND,
        "uv_pass": uv_pass(name),
        "alpha_pass": alpha_pass(name),
        "uv_channels": list(C.UV_CHANNELS),
        "alpha_channels": list(ALPHA_CHANNELS),
        "channels": [C.channel_name(uv_pass(name), c) for c in C.UV_CHANNELS]
        + [C.channel_name(alpha_pass(name), c) for c in ALPHA_CHANNELS],
        **(stmap_keys if stmap else {}),
        "atlas_exr": f"{ATLASES_DIR}/{name}{ATLAS_EXR_EXT}",
        "atlas_png": f"{ATLASES_DIR}/{name}{ATLAS_PNG_EXT}",
        "atlas_size": list(atlas_size),
        "edit_layer": edit_layer,
        "atlas_box": [round(float(b), 7) for b in box],
        "follows_flow": follows_flow,
    }


def relative_path(path: str | Path, start: Path) -> str:
    """``path`` relative to the folder ``start`` ("/" separated), both with their symlinks resolved: what a manifest
    records, so a run folder moved or mounted elsewhere with its plate keeps working. The absolute path where no
    relative one exists (another Windows drive)."""
    real = os.path.realpath(path)
    try:
        return os.path.relpath(real, os.path.realpath(start)).replace(os.sep, "/")
    except ValueError:
        return real


def clip_timing(clip: ClipRecord) -> dict[str, Any]:
    """The manifest clip's timing fields (``terms.manifest.MANIFEST_OPTIONAL_FIELDS``): exact rate, pixel aspect ratio,
    timecode of the first frame, a movie's first frame number."""
    return {
        "rate": None if clip.rate is None else list(clip.rate),
        "pixel_aspect": clip.pixel_aspect,
        "timecode": clip.timecode,
        "start_frame": clip.start_frame,
    }


def build_manifest(
    run_dir: Path,
    final: Path,
    fitted: FittedRun,
    plan: Plan,
) -> dict[str, Any]:
    """The manifest of ``fitted``'s export into ``final`` by ``plan`` (its layers' atlas frames, the run frames
    selected, the layers whose UV follows the flow, the bits its passes keep): what Blender, Nuke and render read
    the passes, atlases and edit layers by. Paths are relative to ``final``; the plate's are also kept absolute, for
    a run folder moved without its plate."""
    clip, cfg, metrics = fitted.clip, fitted.cfg, fitted.metrics or {}
    numbers = list(clip.frame_numbers)
    rel_edits = relative_path(fitted.folder.edits, final)
    layers = [
        layer_record(name, i, fr.size, fr.box, f"{rel_edits}/{name}{EDIT_LAYER_EXT}", i in plan.follows, plan.stmap)
        for i, (name, fr) in enumerate(zip(plan.names, plan.frames_by_layer, strict=True))
    ]
    return {
        MANIFEST_TAG: MANIFEST_VERSION,
        "engine_version": ENGINE_VERSION,
        "run_dir": relative_path(run_dir, final),
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "clip": {
            "source": relative_path(clip.source, final),
            "kind": clip.kind,
            "frame_files": [relative_path(f, final) for f in clip.frame_files],
            # where the relative paths name nothing (the run folder moved alone), readers take these
            "source_absolute": os.path.abspath(clip.source),
            "frame_files_absolute": [os.path.abspath(f) for f in clip.frame_files],
            "frame_numbers": numbers,
            "first_frame": numbers[0],
            "last_frame": numbers[-1],
            "fps": clip.fps,
            "resolution": list(clip.native_size),
            "working_resolution": list(clip.working_size),
            "colorspace": clip.colorspace,
            **({"colour_config": clip.colour_config} if clip.colour_config is not None else {}),
            **({"colour_source": clip.colour_source} if clip.colour_source is not None else {}),
            "masks": [relative_path(m, final) for m in clip.masks],
            **clip_timing(clip),
        },
        "passes": {
            "dir": PASSES_DIR,
            "pattern": pass_pattern(pass_padding(clip)),
            "blender_pattern": blender_pattern(pass_padding(clip)),
            "frames": [numbers[t] for t in plan.selected],
            "exr_layer": EXR_LAYER,
            "resolution": list(clip.native_size),
            "precision": plan.precision,
        },
        "layers": layers,
        "fit": {
            "preset": cfg.preset,
            "model": cfg.model,
            "steps": int(metrics.get("steps", 0)),
            "train_seconds": float(metrics.get("train_seconds", 0.0)),
            "psnr": metrics.get("psnr"),
            "alpha_iou": metrics.get("alpha_iou"),
        },
        "scene": fitted.scene.to_dict(),
    }


def _write_nuke_script(staging: Path, manifest: dict[str, Any]) -> None:
    """The Nuke script of the edit beside the manifest (its paths are the manifest's, relative to the same folder);
    a plate Nuke cannot read as one sequence, or an OCIO config that is gone, gets a warning instead (`engine nuke`
    says the same)."""
    from .nuke import NukeScriptError, nuke_script

    try:
        atomic_write_text(staging / NUKE_SCRIPT_NAME, nuke_script(manifest, str(staging / C.MANIFEST_NAME)))
    except (NukeScriptError, InputError) as exc:
        if isinstance(exc, DISK_ERRORS):  # a full disk fails the export, as any other file it writes would
            raise
        print(f"warning: no {NUKE_SCRIPT_NAME}: {exc}", file=sys.stderr)


__all__ = [
    "build_manifest",
    "clip_timing",
    "layer_record",
    "relative_path",
]
