"""Every clip under one folder, fitted with degraded masks and judged against the precise ones: one table.

Each clip folder (``frames/`` and ``masks/``, maybe ``tracks_tapvid.npz``) gets its masks degraded by a named
recipe (``bench.degrade``) into ``OUT/masks/RECIPE/CLIP``; one preset is fitted on each clip with those
masks by ``run_bench`` (one clip after another, each to its preset's steps unless a budget ends it first) and
evaluated once at the end on every frame (by default): PSNR, the foreground alpha's IoU against the clip's own
precise ``masks/`` (``fg_iou``, next to the given masks' own IoU against them), TAP-Vid delta_avg of atlas
tracking and of chained optical flow (and, in each row of ``clips.json``, of DIS flow on the native plate:
``flow_tracks``). Writes
``OUT/runs/CLIP/bench.json`` (each clip's full record), ``OUT/clips.json`` (the table's rows) and
``OUT/clips.md`` (the table).
"""

from __future__ import annotations

import datetime as _dt
import json
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any

from bench.bench import BENCH_JSON, BenchPlan, run_bench
from bench.bench_clip import BenchClip, resolve_clip
from bench.degrade import DEFAULT_SEED, masks_iou, recipe, write_degraded
from bench.flow_tracks import score_clip
from bench.report_file import read_tracks
from engine.errors import InputError
from engine.io.atomic import atomic_write_text

CLIPS_JSON = "clips.json"
CLIPS_MD = "clips.md"
CLIPS_TAG = "neural_atlas_all_clips"
CLIPS_VERSION = 1
#: Training seconds per run when no budget is given: far beyond any preset, so the preset's steps end each run.
NO_BUDGET_SECONDS = 1e7
#: The table's columns: header and the row key each shows.
COLUMNS: tuple[tuple[str, str], ...] = (
    ("clip", "clip"),
    ("given masks IoU", "mask_iou"),
    ("snap px", "snap_px"),
    ("prior holds", "prior_coverage"),
    ("PSNR (dB)", "psnr"),
    ("fg IoU vs GT", "fg_iou"),
    ("atlas delta_avg", "atlas_delta_avg"),
    ("chained-flow delta_avg", "flow_delta_avg"),
    ("train s", "train_seconds"),
)
#: Decimals each number is shown with.
DECIMALS = {
    "mask_iou": 3,
    "snap_px": 0,
    "prior_coverage": 2,
    "psnr": 2,
    "fg_iou": 3,
    "atlas_delta_avg": 3,
    "flow_delta_avg": 3,
    "train_seconds": 0,
}


def find_clips(root: str | Path) -> list[Path]:
    """The clip folders directly under ``root`` (those holding ``frames/`` and ``masks/``), sorted by name."""
    base = Path(root).expanduser()
    if not base.is_dir():
        raise InputError(base, "is not a folder", "pass the folder that holds the clip folders")
    found = sorted(p for p in base.iterdir() if (p / "frames").is_dir() and (p / "masks").is_dir())
    if not found:
        raise InputError(base, "holds no clip folder (frames/ and masks/)", "pass the folder that holds the clips")
    return found


def degraded_clips(root: str | Path, out: Path, recipe_name: str, seed: int = DEFAULT_SEED) -> list[BenchClip]:
    """Every clip under ``root`` with its masks degraded into ``out/masks/RECIPE/CLIP``, scored against its own."""
    recipe(recipe_name)  # an unknown name is refused before anything is written
    clips = []
    for folder in find_clips(root):
        deg = write_degraded(folder / "masks", out / "masks" / recipe_name / folder.name, recipe_name, seed)
        clips.append(resolve_clip(folder, [deg], score_masks=[folder / "masks"]))
    return clips


def clip_rows(record: dict) -> list[dict]:
    """One row per run of a bench record: the masks it was given (their IoU against the precise ones, how far
    the fit's mask snap moved them, ``engine.data.mask_snap``, and the share of them its mask prior holds,
    ``video.prior_coverage``), its last evaluation's numbers and the clip's
    chained-flow baseline."""
    base = {c["name"]: c.get("tracking_baseline") for c in record["clips"]}
    given = {}
    for c in record["clips"]:
        iou = None
        if len(c.get("masks") or []) == 1 and len(c.get("score_masks") or []) == 1:
            iou = masks_iou(c["masks"][0], c["score_masks"][0])
        snaps = c.get("mask_snap_px") or []
        cover = c.get("prior_coverage") or []
        given[c["name"]] = {
            "mask_iou": iou,
            "snap_px": float(snaps[0]) if len(snaps) == 1 else None,
            "prior_coverage": cover[0] if len(cover) == 1 else None,
        }
    unknown = {"mask_iou": None, "snap_px": None, "prior_coverage": None}
    rows = []
    for run in record["runs"]:
        last = run["curve"][-1] if run["curve"] else {}
        flow = base.get(run["clip"])
        rows.append(
            {
                "clip": run["clip"],
                **given.get(run["clip"], unknown),
                "psnr": last.get("psnr"),
                "fg_iou": last.get("fg_iou"),
                "atlas_delta_avg": last["tracking"]["delta_avg"] if last.get("tracking") else None,
                "flow_delta_avg": flow["delta_avg"] if flow else None,
                "train_seconds": run["train_seconds"],
                "steps": run["steps"],
                "failed": run["failed"],
            }
        )
    return rows


def dis_flow_fields(clip: BenchClip) -> dict[str, float | None]:
    """The clip's DIS-flow baseline on its native plate (``flow_tracks``), a stronger one than the working-resolution
    chained flow of the table's column: row fields ``dis_flow_delta_avg`` (native px) and ``dis_flow_delta_avg_256``,
    None without tracks."""
    if clip.tracks is None:
        return {"dis_flow_delta_avg": None, "dis_flow_delta_avg_256": None}
    report = score_clip(clip.frames, read_tracks(clip.tracks))
    return {"dis_flow_delta_avg": report["delta_avg"], "dis_flow_delta_avg_256": report["delta_avg_256"]}


def mean_row(rows: list[dict]) -> dict:
    """The mean of each numeric column over the rows that have it (None where none has)."""
    out: dict[str, Any] = {"clip": "mean"}
    for _, key in COLUMNS[1:]:
        vals = [r[key] for r in rows if r[key] is not None]
        out[key] = round(sum(vals) / len(vals), 4) if vals else None
    return out


def _cell(row: dict, key: str) -> str:
    v = row[key]
    if key == "clip":
        return str(v)
    return "–" if v is None else f"{v:.{DECIMALS[key]}f}"


def format_table(table: dict) -> str:
    """The markdown table of a ``clips.json`` record: a line naming the preset, recipe and seed, then the rows
    and their mean."""
    head = f"preset `{table['preset']}`, masks degraded by `{table['degrade']}` (seed {table['seed']})"
    lines = [head, "", "| " + " | ".join(h for h, _ in COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for row in [*table["rows"], table["mean"]]:
        lines.append("| " + " | ".join(_cell(row, key) for _, key in COLUMNS) + " |")
    return "\n".join(lines)


def clips_plan(preset: str = "draft", budget_seconds: float | None = None, **fields: Any) -> BenchPlan:
    """The bench each clip of a table gets: ``preset`` alone, trained to its own steps (``budget_seconds`` None)
    or for that long, evaluated once at the end, ``fields`` as ``BenchPlan``'s (its overrides, evaluation frames,
    stride, device, threads)."""
    budget = NO_BUDGET_SECONDS if budget_seconds is None else budget_seconds
    return BenchPlan((preset,), budget, **{"eval_frames": 0, **fields, "evals": 1, "sequential": True})


def run_all_clips(
    root: str | Path,
    out_dir: str | Path,
    plan: BenchPlan | None = None,
    degrade: str = "dilated10_dropped10",
    seed: int = DEFAULT_SEED,
    command: list[str] | None = None,
    log: Any = None,
) -> dict:
    """Fit ``plan``'s preset (``clips_plan``; default ``draft``) on every clip under ``root`` with masks degraded by
    ``degrade`` and score it; returns the table record (also ``out_dir/clips.json`` and ``out_dir/clips.md``)."""
    plan = plan or clips_plan()
    if len(plan.presets) != 1:
        raise ValueError(f"a clips table fits one preset, not {list(plan.presets)}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    clips = degraded_clips(root, out, degrade, seed)
    rows, benches = [], []
    for clip in clips:  # one bench per clip: only one clip's frames, flow and model are in memory at a time
        record = run_bench([clip], plan, out / "runs" / clip.name, command=command, log=log, plot=False)
        rows += [{**row, **dis_flow_fields(clip)} for row in clip_rows(record)]
        benches.append(f"runs/{clip.name}/{BENCH_JSON}")
    table = {
        CLIPS_TAG: CLIPS_VERSION,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "command": command if command is not None else list(sys.argv),
        "preset": plan.presets[0],
        "degrade": degrade,
        "degradation": asdict(recipe(degrade)),
        "seed": seed,
        "eval_frames": plan.eval_frames,
        "benches": benches,
        "rows": rows,
        "mean": mean_row(rows),
    }
    atomic_write_text(out / CLIPS_JSON, json.dumps(table, indent=1))
    atomic_write_text(out / CLIPS_MD, format_table(table) + "\n")
    return table


__all__ = [
    "CLIPS_JSON",
    "CLIPS_MD",
    "clip_rows",
    "clips_plan",
    "degraded_clips",
    "dis_flow_fields",
    "find_clips",
    "format_table",
    "mean_row",
    "run_all_clips",
]
