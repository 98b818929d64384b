"""`bench paint-table`: one preset fitted on every clip of a folder the way a user fits it (``fit``, then
``export``), judged only on what the user gets, the export.

Per clip (a folder with ``frames/``, ``masks/`` and maybe ``tracks_tapvid.npz``; a synthetic scene of
``bench motion-scenes`` also has ``gt_uv.npz`` and ``texture.png``), with its masks degraded by a named recipe
(``bench.degrade``: ``exact`` or a rough roto):

* **paint**: where a dot painted on the exported atlases shows in every frame (``paint_tracking``), TAP-Vid
  delta_avg in native pixels;
* **flow**: the baseline, chained DIS flow on the native plate (``flow_tracks``), and ``ratio`` = paint / flow;
* **IoU**: the exported foreground alpha (> 0.5, layers after the background together) against the clip's own
  precise ``masks/``, pooled over every frame: the decomposition, whatever masks the fit was given;
* **sharpness**: the plate re-rendered from the discretized atlases through the passes, PSNR inside the precise
  masks (``sharpness``); on a scene also **true sharpness**, the same for the scene's true texture through its
  true surface coordinates, the most an atlas can reach;
* **PSNR** and **train s**: the fit's ``metrics.json``.

Every step keeps what it made (``OUT/runs/CLIP`` is an ordinary run folder, exported into ``exports/v001``;
the flow baseline is cached in ``OUT/flow/CLIP.json``), so the command run again after a stop continues where it
was and costs nothing once done. Writes ``OUT/paint.json`` and ``OUT/paint.md`` (one table), and with
``--pictures`` ``OUT/pictures/CLIP.png`` (``paint_picture``).
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import subprocess
import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from bench.all_clips import find_clips
from bench.bench_clip import TRACKS_FILE
from bench.degrade import DEFAULT_SEED, masks_iou, recipe, write_degraded
from bench.flow_tracks import score_clip
from bench.motion_scenes import GT_UV_NPZ, PART_MASKS, TEXTURE_PNG
from bench.paint_slip import export_slip
from bench.paint_tracking import score_export
from bench.report_file import read_tracks
from bench.sharpness import MSE_FLOOR, atlas_sharpness
from bench.tracking import Tracks
from engine import contract as C
from engine.errors import InputError
from engine.export.manifest import Manifest
from engine.fit.auto_parts import SAID_PREFIX
from engine.io.atomic import atomic_write_text
from engine.io.clip import iter_frames, open_clip, read_masks
from engine.io.images import read_image
from engine.terms.cli import EXPORT_FOLLOW_FLOW_FLAG, EXPORT_INTO_ARG, FIT_RESUME_IF_STARTED_FLAG
from engine.terms.run_folder import AUTO_PARTS_DIR, FIT_AUTO_PARTS_FLAG

PAINT_JSON = "paint.json"
PAINT_MD = "paint.md"
PAINT_TAG = "neural_atlas_paint_table"
PAINT_VERSION = 1
#: The export every clip is scored on (``export --into``): run again, it is reused when it holds the same frames.
EXPORT_VERSION = "v001"
#: The recipe that leaves the masks as they are.
EXACT = "exact"
#: A pixel is the object in the exported passes where the foreground layers' alpha together exceeds this.
FG_ALPHA = 0.5
#: The table's columns: header and the row key each shows, and the decimals.
COLUMNS: tuple[tuple[str, str, int], ...] = (
    ("clip", "clip", 0),
    ("paint", "paint", 3),
    ("flow", "flow", 3),
    ("paint / flow", "ratio", 2),
    ("object: paint", "paint_object", 3),
    ("object: flow", "flow_object", 3),
    ("object: paint / flow", "ratio_object", 2),
    ("background: paint", "paint_background", 3),
    ("background: flow", "flow_background", 3),
    ("slip px", "slip", 2),
    ("fg IoU", "fg_iou", 3),
    ("sharpness dB", "sharpness", 2),
    ("true texture dB", "true_sharpness", 2),
    ("PSNR dB", "psnr", 2),
    ("train s", "train_seconds", 0),
)

Log = Callable[[str], None]
#: The ways a table's clips are split (``TableFit.split``): one layer per part mask where a clip has
#: ``masks_parts/`` (``parts``), its one mask split by strokes drawn from those (``scribbles``), by the strokes the
#: fit draws from the motion (``auto``: ``fit --auto-parts``), or one layer per mask (``one``: ``--no-auto-parts``).
#: None: the fit's default (its own search, wherever it applies).
SPLITS: tuple[str, ...] = ("parts", "scribbles", "auto", "one")


@dataclass(frozen=True)
class TableFit:
    """How every clip of a table is fitted and exported: one value from the command line to each clip's fit.
    ``scribble_frames``: with ``split="scribbles"``, the frames with strokes, spread evenly from the first to the
    last; ``follow_flow``: None, exported as ``export`` does by default (each layer follows the flow where it slips,
    the parts of one split object stay as fitted), True ``--follow-flow`` (every layer), False ``--no-follow-flow``."""

    preset: str = "draft"
    degrade: str = EXACT
    seed: int = DEFAULT_SEED
    sets: tuple[str, ...] = ()
    threads: int | None = None
    split: str | None = None
    scribble_frames: int = 3
    follow_flow: bool | None = None

    def __post_init__(self) -> None:
        recipe(self.degrade)  # an unknown name is refused before anything runs
        if self.split is not None and self.split not in SPLITS:
            raise ValueError(f"unknown split {self.split!r}; expected one of {SPLITS} or None")
        object.__setattr__(self, "sets", tuple(self.sets))

    @classmethod
    def of_flags(
        cls, *, parts: bool = False, scribbles: bool = False, auto_parts: bool = False, one_layer: bool = False,
        **fields: Any,
    ) -> TableFit:  # fmt: skip
        """The value of the command line's flags: at most one way to split a clip."""
        chosen = [name for name, on in zip(SPLITS, (parts, scribbles, auto_parts, one_layer), strict=True) if on]
        if len(chosen) > 1:
            raise ValueError("parts, scribbles, auto_parts and one_layer are ways to split a clip: choose one")
        return cls(split=chosen[0] if chosen else None, **fields)

    @property
    def auto_parts(self) -> bool | None:
        """The fit's parts flag: True ``--auto-parts``, False ``--no-auto-parts``, None neither (its default)."""
        return {"auto": True, "one": False}.get(self.split or "")


def _engine(args: list[str], log_path: Path, threads: int | None) -> str:
    """Run ``python -m engine ARGS`` (the product's own command, as a user runs it) with its stderr appended to
    ``log_path``; returns its stdout. A failure is one line naming the log."""
    env = dict(os.environ)
    if threads is not None:
        env["OMP_NUM_THREADS"] = str(threads)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with log_path.open("a", encoding="utf-8") as err:
        done = subprocess.run(
            [sys.executable, "-m", "engine", *args], stdout=subprocess.PIPE, stderr=err, text=True, env=env
        )
    if done.returncode != 0:
        tail = log_path.read_text(encoding="utf-8", errors="replace").strip().splitlines()[-1:] or ["no output"]
        raise InputError(
            log_path, f"engine {args[0]} failed (exit {done.returncode}): {tail[0]}", "fix what the log says, run again"
        )
    return done.stdout


def fit_and_export(
    frames: Path, masks: list[Path], run: Path, how: TableFit, log_path: Path, scribbles: Path | None = None
) -> Path:
    """Fit (or continue, or leave a finished fit: ``--resume-if-started``) ``how.preset`` with one layer per mask
    folder (or the one mask split by ``scribbles``, or by the parts the fit finds: ``how.auto_parts``) and export
    into ``EXPORT_VERSION`` (``how.follow_flow``); returns the manifest's path."""
    set_args = [a for kv in how.sets for a in ("--set", kv)]
    mask_args = [a for m in masks for a in ("--mask", str(m))]
    split_args = [C.SCRIBBLE_ARG, str(scribbles)] if scribbles is not None else []
    if how.auto_parts is not None:
        split_args += [FIT_AUTO_PARTS_FLAG if how.auto_parts else C.FIT_NO_AUTO_PARTS_FLAG]
    _engine(
        [C.VERB_FIT, str(frames), *mask_args, *split_args, "--out", str(run), "--preset", how.preset,
         FIT_RESUME_IF_STARTED_FLAG, "--no-bar", *set_args],
        log_path, how.threads,
    )  # fmt: skip
    follow = (
        []
        if how.follow_flow is None
        else [EXPORT_FOLLOW_FLOW_FLAG if how.follow_flow else C.EXPORT_NO_FOLLOW_FLOW_FLAG]
    )
    out = _engine(
        [C.VERB_EXPORT, str(run), EXPORT_INTO_ARG, EXPORT_VERSION, "--no-bar", *follow], log_path, how.threads
    )
    with log_path.open("a", encoding="utf-8") as log:  # the export's messages: each layer's reach and why
        log.write(out)
    lines = [line for line in out.strip().splitlines() if line.strip()]
    if not lines:
        raise InputError(log_path, "engine export printed no manifest path", "read the log, run again")
    return Path(lines[-1].strip())


def _auto_parts_line(log_path: Path) -> str | None:
    """The last thing ``fit --auto-parts`` said in the clip's log about its parts (None: nothing)."""
    lines = log_path.read_text(encoding="utf-8", errors="replace").splitlines() if log_path.is_file() else []
    said = [line[len(SAID_PREFIX) :] for line in lines if line.startswith(SAID_PREFIX)]
    return said[-1].strip() if said else None


def export_fg_iou(manifest_path: str | Path, plate: str | Path, masks: str | Path) -> float | None:
    """IoU of the exported foreground (the alpha of every layer after the background, summed, >= FG_ALPHA) against
    the precise masks, intersection and union pooled over the exported frames; None without foreground layers or
    mask pixels. ``>=`` because compact passes round alpha towards zero onto a grid that holds FG_ALPHA itself: a
    fitted alpha just above it is exported as exactly FG_ALPHA, and still counts as foreground, as in the fit."""
    manifest = Manifest(manifest_path)
    if len(manifest.layers) < 2:
        return None
    info = open_clip(plate)
    gt = read_masks(masks, info, manifest.resolution)
    numbers = list(info.frame_numbers)
    inter = union = 0
    for frame in manifest.frames:
        fg = sum(p.alpha for p in manifest.read_passes(frame)[1:]) >= FG_ALPHA
        m = gt[numbers.index(frame)]
        inter += int((fg & m).sum())
        union += int((fg | m).sum())
    return inter / union if union else None


def true_sharpness(folder: str | Path) -> float | None:
    """A synthetic scene's own ceiling for ``sharpness``: its true texture sampled (bilinear) at its true surface
    coordinates, PSNR against the plate over the pixels where the coordinate is known, pooled over frames; None
    for a clip without ``gt_uv.npz`` and ``texture.png``."""
    base = Path(folder)
    if not (base / GT_UV_NPZ).is_file() or not (base / TEXTURE_PNG).is_file():
        return None
    texture, _ = read_image(base / TEXTURE_PNG)
    with np.load(base / GT_UV_NPZ) as f:
        uv = f["uv"]
    info = open_clip(base / "frames")
    sq, count = 0.0, 0
    for t, rgb in enumerate(iter_frames(info)):
        known = np.isfinite(uv[t]).all(-1)
        if not known.any():
            continue
        field = np.nan_to_num(uv[t]).astype(np.float32)
        # texel [j, i] holds the colour at surface point (i, j): remap's pixel centres are at integer coordinates
        sampled = cv2.remap(texture[..., :3], field[..., 0], field[..., 1], cv2.INTER_LINEAR, cv2.BORDER_REPLICATE)
        plate = np.clip(rgb[..., :3], 0.0, 1.0)  # both 8-bit codes read as 0..1: compared as the frames are written
        diff = sampled[known].astype(np.float64) - plate[known]
        sq += float((diff * diff).sum())
        count += diff.size
    return None if count == 0 else 10.0 * math.log10(1.0 / max(sq / count, MSE_FLOOR))


def flow_baseline(frames: Path, tracks_path: Path, cache: Path) -> dict:
    """The clip's chained-DIS report (``flow_tracks``), cached in ``cache``: it depends on the plate alone."""
    if cache.is_file():
        return json.loads(cache.read_text(encoding="utf-8"))
    report = score_clip(frames, read_tracks(tracks_path))
    cache.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(cache, json.dumps(report))
    return report


def part_folders(folder: Path) -> list[Path]:
    """The clip's part mask folders, ``masks_parts/PART/`` in name order ([] for a clip without parts)."""
    parts = folder / PART_MASKS
    return sorted(p for p in parts.iterdir() if p.is_dir()) if parts.is_dir() else []


def part_queries(folder: Path, tracks: Tracks) -> dict[str, np.ndarray]:
    """bool [N] per part of ``masks_parts/PART/``: the tracks whose query pixel lies on that part's mask at the query
    frame ({} for a clip without parts)."""
    parts = part_folders(folder)
    t = np.rint(tracks.query_txy[:, 0]).astype(np.int64)
    x = np.clip(np.rint(tracks.query_txy[:, 1]).astype(np.int64), 0, tracks.image_size[0] - 1)
    y = np.clip(np.rint(tracks.query_txy[:, 2]).astype(np.int64), 0, tracks.image_size[1] - 1)
    found = {}
    for part in parts:
        files = sorted(f for f in part.iterdir() if not f.name.startswith("."))
        keep = np.zeros(len(t), dtype=bool)
        for i in np.unique(t):
            mask = cv2.imread(str(files[i]), cv2.IMREAD_GRAYSCALE)
            keep[t == i] = mask[y[t == i], x[t == i]] > 127
        found[part.name] = keep
    return found


def _region_score(report: dict, key: str) -> float | None:
    """A tracking report's delta_avg over the points whose query lies on (``on_mask``) or off (``off_mask``) the
    clip's mask; None where the tracks do not say, or hold no such point."""
    return ((report.get("by_query_mask") or {}).get(key) or {}).get("delta_avg")


def score_clip_export(folder: Path, manifest: Path, out: Path) -> dict:
    """Every export score of one clip (the row's numbers but PSNR and train s)."""
    frames, precise = folder / "frames", folder / "masks"
    row: dict[str, Any] = {"paint": None, "paint_256": None, "flow": None, "flow_256": None, "ratio": None,
                           "ratio_object": None}  # fmt: skip
    if (folder / TRACKS_FILE).is_file():
        tracks = read_tracks(folder / TRACKS_FILE)
        paint = score_export(manifest, tracks)
        flow = flow_baseline(frames, folder / TRACKS_FILE, out / "flow" / f"{folder.name}.json")
        row.update(
            paint=paint["delta_avg"],
            paint_256=paint["delta_avg_256"],
            paint_by_gap=paint.get("by_gap"),
            paint_misses=paint["misses"],
            flow=flow["delta_avg"],
            flow_256=flow["delta_avg_256"],
            flow_by_gap=flow.get("by_gap"),
        )
        by_part = {name: score_export(manifest, tracks.subset(keep, tracks.num_frames))["delta_avg"]
                   for name, keep in part_queries(folder, tracks).items() if keep.any()}  # fmt: skip
        if by_part:
            row["paint_by_part"] = by_part
        if row["flow"]:
            row["ratio"] = row["paint"] / row["flow"]
        # the points on the object (the mask at the query) apart from the rest: a crowd's or a second animal's
        # tracks move against the background layer, which chained flow follows and no atlas of the object can
        for region, key in (("object", "on_mask"), ("background", "off_mask")):
            row[f"paint_{region}"] = _region_score(paint, key)
            row[f"flow_{region}"] = _region_score(flow, key)
        if row["paint_object"] is not None and row["flow_object"]:
            row["ratio_object"] = row["paint_object"] / row["flow_object"]
    sharp = atlas_sharpness(manifest, frames, [precise])
    row.update(
        slip=export_slip(manifest, frames)["foreground"]["median_px"],
        fg_iou=export_fg_iou(manifest, frames, precise),
        sharpness=sharp["psnr_pooled"],
        true_sharpness=true_sharpness(folder),
    )
    return row


def run_paint_table(
    root: str | Path,
    out_dir: str | Path,
    how: TableFit | None = None,
    only: list[str] | None = None,
    pictures: bool = False,
    command: list[str] | None = None,
    log: Log | None = None,
) -> dict:
    """Fit, export and score every clip under ``root`` (or the ``only`` ones) as ``how`` says (default: ``draft``,
    the clips' own masks, the fit's and the export's defaults); returns the table record, also written to
    ``out_dir/paint.json`` and ``out_dir/paint.md``. A split clip's scores are the same (the foreground is every
    layer after the background): ``parts`` fits a clip with ``masks_parts/`` (``motion_scenes.part_masks``) with
    one layer per part; ``scribbles`` the product's way instead, its one mask split by strokes drawn from the part
    masks on ``how.scribble_frames`` frames (3: first, middle, last; ``part_scribbles``); ``auto`` with ``fit
    --auto-parts``, its one (degraded) mask split by the strokes the fit draws from the motion where it splits it
    (the row's ``auto_parts``: what the fit said it found; ``scribbles``: the strokes it wrote, ``RUN/parts``);
    ``one`` with ``fit --no-auto-parts``, one layer per mask."""
    how = how or TableFit()
    say = log or (lambda line: print(line, file=sys.stderr, flush=True))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for folder in _selected_clips(root, only):
        row = _clip_row(folder, out, how, say)
        if pictures and (folder / "masks").is_dir():
            from bench.paint_picture import paint_picture

            row["picture"] = str(paint_picture(Path(row["manifest"]), folder / "frames", folder / "masks",
                                               out / "pictures" / f"{folder.name}.png"))  # fmt: skip
        rows.append(row)
        say(f"paint-table: {folder.name}: " + ", ".join(f"{key} {_cell(row, key, d)}" for _, key, d in COLUMNS[1:]))
    table = {
        PAINT_TAG: PAINT_VERSION,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "command": command if command is not None else list(sys.argv),
        "preset": how.preset,
        "degrade": how.degrade,
        "degradation": asdict(recipe(how.degrade)),
        "seed": how.seed,
        "sets": list(how.sets),
        "parts": how.split == "parts",
        "scribbles": how.split == "scribbles",
        "scribble_frames": how.scribble_frames if how.split == "scribbles" else None,
        "auto_parts": how.split == "auto",
        "one_layer": how.split == "one",
        "follow_flow": how.follow_flow,
        "rows": rows,
        "mean": mean_row(rows),
    }
    atomic_write_text(out / PAINT_JSON, json.dumps(table, indent=1))
    atomic_write_text(out / PAINT_MD, format_table(table) + "\n")
    return table


def _selected_clips(root: str | Path, only: list[str] | None) -> list[Path]:
    """The clip folders under ``root``, or the ``only`` ones; a name that is not there is refused up front."""
    folders = find_clips(root)
    if only:
        unknown = sorted(set(only) - {f.name for f in folders})
        if unknown:
            raise InputError(Path(root), f"holds no clip {unknown[0]}", "name clip folders that are under it")
        folders = [f for f in folders if f.name in only]
    return folders


def _clip_row(folder: Path, out: Path, how: TableFit, say: Log) -> dict:
    """One clip fitted and exported as ``how`` says, and its export scored: the table's row."""
    given = [folder / "masks"]
    split = part_folders(folder)
    if how.split == "parts" and split:
        given = split
    masks = given  # exact: the clip's own masks, as a user passes them
    if recipe(how.degrade) != recipe(EXACT):
        masks = [
            write_degraded(m, out / "masks" / how.degrade / folder.name / m.name, how.degrade, how.seed) for m in given
        ]
    strokes = None
    found = None
    layers = len(masks) + 1
    if how.split == "scribbles" and split:
        from bench.part_scribbles import write_part_scribbles

        at = tuple(float(a) for a in np.linspace(0.0, 1.0, max(2, how.scribble_frames)))
        strokes, _ = write_part_scribbles(split, out / "scribbles" / folder.name, at)
        layers = len(split) + 1
    run = out / "runs" / folder.name
    log_path = out / "logs" / f"{folder.name}.log"
    say(f"paint-table: {folder.name}: fit {how.preset} + export -> {run}")
    manifest = fit_and_export(folder / "frames", masks, run, how, log_path, strokes)
    if (
        strokes is None and len(masks) == 1 and how.auto_parts is not False
    ):  # the fit's own search (asked, or its default):
        # what it said it found, and the strokes it wrote
        found = _auto_parts_line(log_path)
        if found is not None:
            say(f"paint-table: {folder.name}: parts: {found}")
        if (run / AUTO_PARTS_DIR).is_dir():
            strokes = run / AUTO_PARTS_DIR
        layers = len(Manifest(manifest).layers)
    say(f"paint-table: {folder.name}: scoring the export")
    metrics = json.loads((run / C.RUN_METRICS).read_text(encoding="utf-8"))
    row = {
        "clip": folder.name,
        "layers": layers,
        "scribbles": str(strokes) if strokes is not None else None,
        "auto_parts": found,
        "given_masks_iou": masks_iou(masks[0], folder / "masks") if len(masks) == 1 else None,
        **score_clip_export(folder, manifest, out),
        "psnr": metrics.get("psnr"),
        "train_seconds": metrics.get("train_seconds"),
        "steps": metrics.get("steps"),
        "manifest": str(manifest),
    }
    return row


def mean_row(rows: list[dict]) -> dict:
    """The mean of each numeric column over the rows that have it (None where none has)."""
    mean: dict[str, Any] = {"clip": "mean"}
    for _, key, _ in COLUMNS[1:]:
        vals = [r[key] for r in rows if r.get(key) is not None]
        mean[key] = float(np.mean(vals)) if vals else None
    return mean


def _cell(row: dict, key: str, decimals: int) -> str:
    v = row.get(key)
    if key == "clip":
        return str(v)
    return "–" if v is None else f"{v:.{decimals}f}"


def format_table(table: dict) -> str:
    """The markdown table of a ``paint.json`` record: a line naming the preset and masks, then rows and mean."""
    sets = "".join(f" `--set {kv}`" for kv in table.get("sets") or [])
    parts = ", one layer per part where a clip has `masks_parts/`" if table.get("parts") else ""
    if table.get("scribbles"):
        parts = ", one mask split by strokes drawn from `masks_parts/` where a clip has it"
    if table.get("auto_parts"):
        parts = ", one mask split by the strokes `fit --auto-parts` draws from the motion where it splits the object"
    if table.get("one_layer"):
        parts = ", one layer per mask (`fit --no-auto-parts`)"
    head = f"preset `{table['preset']}`{sets}, masks `{table['degrade']}` (seed {table['seed']}){parts}"
    lines = [head, "", "| " + " | ".join(h for h, _, _ in COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for row in [*table["rows"], table["mean"]]:
        lines.append("| " + " | ".join(_cell(row, key, d) for _, key, d in COLUMNS) + " |")
    return "\n".join(lines)


__all__ = [
    "COLUMNS",
    "EXPORT_VERSION",
    "PAINT_JSON",
    "PAINT_MD",
    "SPLITS",
    "TableFit",
    "export_fg_iou",
    "fit_and_export",
    "flow_baseline",
    "format_table",
    "mean_row",
    "run_paint_table",
    "score_clip_export",
    "true_sharpness",
]
