"""The mask snap alone, on every clip of a folder: how far it moves degraded masks and how close they come to
the precise ones, without fitting anything (seconds per clip instead of minutes).

Each clip's precise ``masks/`` are degraded by a named recipe (``bench.degrade``) into
``OUT/masks/RECIPE/CLIP``, read at the fit's working size exactly as ``fit`` reads them, snapped with the fit's
``engine.data.mask_snap.snap_masks``, and scored against the precise masks at that size (pooled over the frames the
degraded masks have). It also gives the share of the snapped masks the fit's mask prior holds, and whether the fit
will hold the masks for all its steps for that (``mask_hold_coverage``). ``python -m bench masks CLIPS
--degrade RECIPE`` prints the table.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from bench.all_clips import find_clips
from bench.degrade import DEFAULT_SEED, recipe, write_degraded
from engine import contract as C
from engine.config import FitConfig
from engine.data.mask_snap import snap_masks
from engine.data.video import mask_hold_layers, mask_prior, prior_coverage
from engine.fit.prepare import to_fitting_values
from engine.io.clip import open_clip, read_frames, read_masks, working_size


def pooled_iou(masks: np.ndarray, truth: np.ndarray) -> float | None:
    """IoU of bool [T, H, W] ``masks`` against ``truth`` over the frames ``masks`` has (an empty frame is "no
    mask"); None when it has none."""
    has = masks.reshape(masks.shape[0], -1).any(-1)
    union = int((masks[has] | truth[has]).sum())
    return int((masks[has] & truth[has]).sum()) / union if union else None


def check_clip(folder: Path, degraded: Path, reach_px: int, long_edge: int = C.DEFAULT_LONG_EDGE) -> dict:
    """One clip: the degraded masks' IoU against the precise ones before and after the snap, the offset, the share
    of the snapped masks the mask prior holds (with the default config's margin and hold threshold), and the snap's
    seconds."""
    info = open_clip(folder / "frames")
    size = working_size(info.width, info.height, long_edge)
    frames, _ = to_fitting_values(read_frames(info, size), info.colorspace, info.source, info.colour_config)
    given = read_masks(degraded, info, size)
    truth = read_masks(folder / "masks", info, size)
    start = time.perf_counter()
    snapped, snaps = snap_masks(frames, given[None], reach_px)
    seconds = time.perf_counter() - start
    cfg = FitConfig()
    coverage = prior_coverage(snapped, mask_prior(snapped, cfg.mask_prior_margin_px))[0]
    return {
        "clip": folder.name,
        "frames": int(given.shape[0]),
        "given_iou": pooled_iou(given, truth),
        "snap_px": snaps[0].offset_px,
        "snapped_iou": pooled_iou(snapped[0], truth),
        # the share of the snapped masks the fit's mask prior holds; under mask_hold_coverage they are held
        "prior_coverage": None if coverage is None else round(coverage, 3),
        "held": bool(mask_hold_layers([coverage], cfg.mask_hold_coverage)[0]),
        "seconds": round(seconds, 2),
    }


def check_all(
    root: str | Path, out: str | Path, degrade: str, seed: int = DEFAULT_SEED, reach_px: int = 16
) -> list[dict]:
    """``check_clip`` for every clip folder under ``root``, the degraded masks written under ``out``."""
    recipe(degrade)  # an unknown recipe is refused before anything is written
    rows = []
    for folder in find_clips(root):
        deg = write_degraded(folder / "masks", Path(out) / "masks" / degrade / folder.name, degrade, seed)
        rows.append(check_clip(folder, deg, reach_px))
    return rows


def format_rows(rows: list[dict], degrade: str) -> str:
    """A markdown table of ``check_all``'s rows."""

    def num(v: float | None) -> str:
        return "–" if v is None else f"{v:.3f}"

    lines = [
        f"masks degraded by `{degrade}`, snapped at working size",
        "",
        "| clip | frames | given masks IoU | snap px | snapped masks IoU | prior holds | snap s |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['clip']} | {r['frames']} | {num(r['given_iou'])} | {r['snap_px']} | {num(r['snapped_iou'])} | "
            f"{num(r['prior_coverage'])}{' (held)' if r['held'] else ''} | {r['seconds']:.2f} |"
        )
    return "\n".join(lines)


__all__ = ["check_all", "check_clip", "format_rows", "pooled_iou"]
