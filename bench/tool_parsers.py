"""The measurement tools for developing the engine, run as ``python -m bench TOOL ...``. They are not
part of the product (its CLI is ``python -m engine``) and not in the extension zip.

    bench        accuracy against training time of several presets, in one process (docs/accuracy-vs-time.md)
    clips        one preset on every clip of a folder, fitted with degraded masks, scored against the precise ones
    speed        seconds per step of presets, side by side on one clip
    scene-speed  what the scene analysis saves: one clip fitted with components=auto and components=all
    expected-psnr  a finished fit's PSNR as its preset's expected PSNR (engine/fit/expected_psnr.json)
    farm         shots one after another against the same shots through `farm dask` with local workers
    motion-scenes  synthetic clip folders with ground-truth tracks (turning, deforming, small_fast, thin,
                   turning_depth, limbs_jump)
    long-plate   a real clip upscaled and played forward and back to a production size and length, with its
                 masks and tracks
    masks        the mask snap alone on every clip of a folder: degraded masks' IoU before and after
    paint-tracks where paint on the exported atlases shows in each frame, scored against TAP-Vid tracks
    flow-tracks  the baseline: chained DIS optical flow on the native plate, scored the same way
    sharpness    the plate re-rendered from the exported atlas textures and passes: PSNR inside the mask
    paint-slip   how far paint on an export moves from the plate's own motion between neighbouring frames
    paint-table  one preset fitted and exported on every clip of a folder, scored on the export: paint, flow,
                 IoU, sharpness, PSNR, training seconds; with a picture per clip
    paint-gaps   paint against chained flow by frame gap, one panel per clip, one line per paint table
    export-cost  two kinds of export in turn (following the flow or not; passes written ahead or not): time, memory
    export-size  an export's pass files rewritten with other channels, precision and compression: MB a frame

The tools' command-line parser: each tool's options; the options several tools share are defined once and given to
them as argparse parents, so their help cannot drift apart. ``bench.__main__`` runs the tool.
"""

from __future__ import annotations

import argparse

from bench.export_cost import COMPARISONS
from engine.cli_options import add_device, add_follow_flow, add_preset, add_set, add_threads, frame_range

BENCH = "bench"
CLIPS = "clips"
SPEED = "speed"
SCENE_SPEED = "scene-speed"
EXPECTED_PSNR = "expected-psnr"
FARM = "farm"
MOTION_SCENES = "motion-scenes"
LONG_PLATE = "long-plate"
MASKS = "masks"
PAINT_TRACKS = "paint-tracks"
FLOW_TRACKS = "flow-tracks"
SHARPNESS = "sharpness"
PAINT_SLIP = "paint-slip"
PAINT_TABLE = "paint-table"
PAINT_GAPS = "paint-gaps"
EXPORT_COST = "export-cost"
EXPORT_SIZE = "export-size"
PROG = "python -m bench"

BENCH_EPILOG = """\
clips: a folder holding frames/ and masks/ (and tracks_tapvid.npz: then atlas tracking is scored), or a frame
  folder with --mask (one clip only).
--set KEY=VALUE applies to every preset, --set PRESET.KEY=VALUE to one (e.g. paper.batch=2000).
writes OUT/bench.json (curves, machine, versions, command) and OUT/bench.png; see docs/accuracy-vs-time.md.
"""
#: The degraded masks of clips and masks by default: as rough as a quick roto (bench.degrade).
CLIPS_RECIPE = "dilated10_dropped10"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=PROG, description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = p.add_subparsers(dest="tool", metavar="TOOL")
    _add_bench_parser(sub)
    _add_speed_parsers(sub)
    _add_expected_psnr_parser(sub)
    _add_farm_parser(sub)
    _add_clips_parser(sub)
    _add_masks_parser(sub)
    _add_scoring_parsers(sub)
    _add_paint_table_parser(sub)
    _add_paint_gaps_parser(sub)
    _add_export_cost_parser(sub)
    _add_export_size_parser(sub)
    _add_motion_scenes_parser(sub)
    _add_long_plate_parser(sub)
    return p


# --- options several tools share: one definition each, given to the tools as argparse parents ---------------
# argparse puts a parent's options before the tool's own, so a tool whose shared options come last in its help
# (bench, clips: --device, --threads) takes its own options from a parent too.


def _parent() -> argparse.ArgumentParser:
    return argparse.ArgumentParser(add_help=False)


def _fit_device_parent() -> argparse.ArgumentParser:
    """Where the fits of bench and clips run: the device and torch's CPU threads."""
    p = _parent()
    add_device(p, "auto")
    add_threads(p)
    return p


def _preset_parent() -> argparse.ArgumentParser:
    """The one fit preset of clips and paint-table."""
    p = _parent()
    add_preset(p, "draft", "fit preset (default: draft)")
    return p


def _mask_recipe_parent(default: str) -> argparse.ArgumentParser:
    """The degraded masks of clips, masks and paint-table: a recipe of bench.degrade and its seed."""
    from bench.degrade import DEFAULT_SEED, RECIPES

    p = _parent()
    p.add_argument("--degrade", default=default, choices=list(RECIPES), help="mask recipe (default: %(default)s)")
    p.add_argument("--seed", type=int, default=DEFAULT_SEED, help="seed of the dropped frames (default: 0)")
    return p


def _manifest_parent() -> argparse.ArgumentParser:
    """The export that paint-tracks and sharpness score."""
    p = _parent()
    p.add_argument("manifest", metavar="EXPORT_MANIFEST", help="an export's manifest.json (or its folder)")
    return p


def _tracks_parent() -> argparse.ArgumentParser:
    """The tracking scorers' options: the clip's tracks and the report file."""
    p = _parent()
    p.add_argument("--tracks", required=True, metavar="NPZ", help="tracks_tapvid.npz of the clip")
    _add_json(p)
    return p


def _clip_names(text: str) -> list[str]:
    """``--only a,b`` -> ["a", "b"] (empty entries dropped; none: every clip)."""
    return [name for name in text.split(",") if name]


def _add_only(parser: argparse.ArgumentParser) -> None:
    """``--only CLIP,CLIP`` of the tools that read a folder of clips or tables of them: a list of clip names."""
    parser.add_argument(
        "--only", type=_clip_names, default=None, metavar="CLIP,CLIP", help="these clips only (default: every clip)"
    )


def _add_json(parser: argparse.ArgumentParser) -> None:
    """The scorers' report file (sharpness lists it after its own options, so it cannot take it as a parent)."""
    parser.add_argument("--json", default=None, metavar="OUT", help="also write the full scores to this file")


# --- each tool's parser ----------------------------------------------------------------------------------------


def _add_bench_parser(sub: argparse._SubParsersAction) -> None:
    sub.add_parser(
        BENCH,
        parents=[_bench_options(), _fit_device_parent()],
        help="accuracy against training time of several presets, in one process",
        epilog=BENCH_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Fit presets side by side for a training-time budget each; record PSNR, mapping "
        "consistency and point-tracking accuracy against training seconds (evaluation excluded).",
    )


def _bench_options() -> argparse.ArgumentParser:
    b = _parent()
    b.add_argument("clips", nargs="+", metavar="CLIP", help="clip folder (frames/, masks/) or a frame folder")
    b.add_argument("--mask", action="append", default=[], metavar="FOLDER", help="mask folder (single clip only)")
    b.add_argument("--tracks", default=None, metavar="NPZ", help="tracks_tapvid.npz (single clip only)")
    b.add_argument(
        "--score-masks",
        action="append",
        default=[],
        metavar="FOLDER",
        help="precise masks to score the foreground alpha against (single clip only; default: a clip folder's masks/)",
    )
    b.add_argument("--presets", default="draft,balanced,paper", help="comma-separated (default: draft,balanced,paper)")
    b.add_argument("--budget-seconds", type=float, required=True, help="training seconds per run")
    b.add_argument("--out", default="bench_out", help="output folder (default: bench_out)")
    b.add_argument("--evals", type=int, default=6, help="evaluations per run, geometric in time (default: 6)")
    b.add_argument("--eval-frames", type=int, default=5, help="frames evaluated (default: 5; 0 = all)")
    b.add_argument("--slice-seconds", type=float, default=5.0, help="interleaving slice (default: 5)")
    b.add_argument("--sequential", action="store_true", help="run presets one after another, not interleaved")
    b.add_argument(
        "--eval-at", default="", metavar="S,S,...", help="also evaluate at these training seconds (e.g. 180,600,1200)"
    )
    b.add_argument("--eval-at-start", action="store_true", help="also evaluate each model before its first step")
    b.add_argument("--stride", type=int, default=4, help="pixel grid of the consistency and tracking search")
    b.add_argument("--set", action="append", default=[], metavar="[PRESET.]KEY=VALUE", help="config override")
    return b


def _add_speed_parsers(sub: argparse._SubParsersAction) -> None:
    sp = sub.add_parser(
        SPEED,
        help="seconds per step of presets, side by side on one clip",
        description="Interleaves short blocks of training steps of each preset in one process.",
    )
    sp.add_argument("clip")
    sp.add_argument("--mask", action="append", default=[], metavar="FOLDER")
    sp.add_argument(
        "--presets",
        default="draft,balanced,paper",
        help="comma-separated, each PRESET or PRESET:KEY=VALUE[:KEY=VALUE] (default: draft,balanced,paper)",
    )
    sp.add_argument(
        "--at-step",
        type=int,
        default=0,
        help="time the steps with the loss weights of this step (default 0: every bootstrap term on)",
    )
    sp.add_argument("--steps", type=int, default=10, help="steps per block (default: 10)")
    sp.add_argument("--rounds", type=int, default=3, help="interleaved rounds (default: 3)")
    add_device(sp, "auto")
    sp.add_argument("--work", default=None, help="folder for the flow cache (default: a temp folder)")
    ss = sub.add_parser(
        SCENE_SPEED,
        help="one clip fitted with components=auto and =all: seconds per step, PSNR",
        description="Both fits use the same config, seed and steps; only `components` differs. Prints one line "
        "per fit and the ratio of seconds per step, then a JSON summary as the last line.",
    )
    ss.add_argument("clip")
    ss.add_argument("--mask", action="append", default=[])
    ss.add_argument("--frames", type=frame_range, default=None, metavar="A:B")
    add_preset(ss, "draft", "fit preset (default: draft)")
    ss.add_argument("--steps", type=int, default=300)
    ss.add_argument("--long-edge", type=int, default=384)
    ss.add_argument("--out", default=None, help="folder for the two runs (default: a temporary folder)")


def _add_expected_psnr_parser(sub: argparse._SubParsersAction) -> None:
    ep = sub.add_parser(
        EXPECTED_PSNR,
        help="record a finished fit's PSNR as what `estimate` expects of its preset",
        description="Writes RUN_DIR's full-frame PSNR (metrics.json) into engine/fit/expected_psnr.json.",
    )
    ep.add_argument("preset")
    ep.add_argument("run", metavar="RUN_DIR", help="a finished fit of PRESET")
    ep.add_argument("--clip", required=True, help="the clip's name, e.g. blackswan")
    ep.add_argument("--note", required=True, help="one line: where the measurement is documented")


def _add_frame_size(parser: argparse.ArgumentParser, width: int, height: int) -> None:
    """--width and --height of the frames a tool writes, with their defaults."""
    parser.add_argument("--width", type=int, default=width, help=f"frame width (default: {width})")
    parser.add_argument("--height", type=int, default=height, help=f"frame height (default: {height})")


def _add_motion_scenes_parser(sub: argparse._SubParsersAction) -> None:
    ms = sub.add_parser(
        MOTION_SCENES,
        help="synthetic clip folders with ground-truth tracks (turning, deforming, small_fast, thin, turning_depth, "
        "limbs_jump)",
        description="Write OUT/KIND/ for each scene: frames/, masks/, tracks_tapvid.npz and gt_uv.npz (the surface "
        "coordinate of every pixel), ready for `clips OUT`; see docs/accuracy-vs-time.md.",
    )
    ms.add_argument("out", metavar="OUT", help="folder for the clip folders")
    _add_frame_size(ms, 480, 272)
    ms.add_argument("--frames", type=int, default=36, help="frames per clip (default: 36)")
    ms.add_argument("--seed", type=int, default=0, help="texture seed (default: 0)")
    ms.add_argument("--kinds", default=None, metavar="K,K,...", help="scenes to write (default: all six)")


def _add_long_plate_parser(sub: argparse._SubParsersAction) -> None:
    lp = sub.add_parser(
        LONG_PLATE,
        help="a real clip upscaled and played forward and back to a production size and length, with its masks "
        "and tracks",
        description="Write OUT/frames, OUT/masks and OUT/tracks_tapvid.npz: CLIP's frames resized to WIDTHxHEIGHT "
        "(bicubic; masks nearest) and played forward and back to FRAMES frames, the tracks scaled to the new size. "
        "Its first frames are the clip's own, so a fit of them alone is the long fit's reference; see "
        "docs/accuracy-vs-time.md, *A long shot at 1080p*.",
    )
    lp.add_argument("clip", metavar="CLIP", help="clip folder holding frames/ and masks/ (and tracks_tapvid.npz)")
    lp.add_argument("out", metavar="OUT", help="folder to write")
    _add_frame_size(lp, 1920, 1080)
    lp.add_argument("--frames", type=int, default=300, help="frames to write (default: 300)")


def _add_clips_parser(sub: argparse._SubParsersAction) -> None:
    sub.add_parser(
        CLIPS,
        parents=[_preset_parent(), _mask_recipe_parent(CLIPS_RECIPE), _clips_options(), _fit_device_parent()],
        help="one preset on every clip of a folder, fitted with degraded masks, scored against the precise ones",
        description="Degrade each clip's masks/ by a named recipe into OUT/masks/RECIPE/CLIP, fit the preset on "
        "every clip with them (one after another, each to its steps) and score the last model against the "
        "clip's own masks/: PSNR, foreground alpha IoU, atlas and chained-flow TAP-Vid delta_avg, training "
        "seconds. Writes OUT/clips.md, OUT/clips.json and OUT/runs/CLIP/bench.json; see docs/accuracy-vs-time.md.",
    )


def _clips_options() -> argparse.ArgumentParser:
    c = _parent()
    c.add_argument("root", metavar="CLIPS_ROOT", help="folder of clip folders (frames/, masks/, tracks_tapvid.npz)")
    c.add_argument("--out", default="clips_out", help="output folder (default: clips_out)")
    c.add_argument("--budget-seconds", type=float, default=None, help="training seconds per clip (default: its steps)")
    c.add_argument("--eval-frames", type=int, default=0, help="frames evaluated (default: 0 = all)")
    c.add_argument("--stride", type=int, default=4, help="pixel grid of the consistency and tracking search")
    add_set(c, "config override")
    return c


def _add_masks_parser(sub: argparse._SubParsersAction) -> None:
    m = sub.add_parser(
        MASKS,
        parents=[_mask_recipe_parent(CLIPS_RECIPE)],
        help="the mask snap alone on every clip: degraded masks' IoU against the precise ones, before and after",
        description="Degrade each clip's masks/ by a named recipe into OUT/masks/RECIPE/CLIP, read them at the "
        "fit's working size, snap them as fit does (engine/data/mask_snap.py) and print their IoU against the "
        "precise masks before and after, the offset and the snap's seconds. Nothing is fitted.",
    )
    m.add_argument("root", metavar="CLIPS_ROOT", help="folder of clip folders (frames/, masks/)")
    m.add_argument("--reach", type=int, default=16, help="the snap's search in working pixels (default: 16)")
    m.add_argument("--out", default="masks_out", help="output folder (default: masks_out)")


def _add_scoring_parsers(sub: argparse._SubParsersAction) -> None:
    sub.add_parser(
        PAINT_TRACKS,
        parents=[_manifest_parent(), _tracks_parent()],
        help="where paint on the exported atlases shows in each frame, scored against TAP-Vid tracks",
        description="Read an export's native UV + alpha passes; each query takes the UV of the layer most opaque at "
        "it, and in every other frame the pixel that layer covers (Z > 0.5) whose UV is nearest (sub-pixel). Prints "
        "TAP-Vid delta_avg (native pixels and at 256x256); a frame where the layer covers nothing is a miss.",
    )
    ft = sub.add_parser(
        FLOW_TRACKS,
        parents=[_tracks_parent()],
        help="the baseline: chained DIS optical flow on the native plate, scored against TAP-Vid tracks",
        description="Chain OpenCV DIS flow (preset MEDIUM) on the native greyscale frames, forward and backward "
        "from each query; prints TAP-Vid delta_avg as paint-tracks does.",
    )
    ft.add_argument("frames", metavar="FRAMES_DIR", help="the plate (its frames in order are the tracks' frames)")
    sh = sub.add_parser(
        SHARPNESS,
        parents=[_manifest_parent()],
        help="the plate re-rendered from the exported atlas textures and passes: PSNR inside the mask",
        description="Sample each exported atlas texture at the exported UVs (bilinear, as Map UV does), sum the "
        "layers by their coverage and compare with the plate inside the mask: PSNR per frame, mean and pooled.",
    )
    sh.add_argument("--plate", required=True, metavar="FRAMES", help="the plate the export was made from")
    sh.add_argument("--masks", action="append", required=True, metavar="FOLDER", help="the object's masks")
    sh.add_argument(
        "--run",
        default=None,
        metavar="RUN_DIR",
        help="also the ceiling: the fit's own networks' reconstruction inside the masks at its working size (the "
        "gap to the export's number is what the discretised textures lose)",
    )
    _add_json(sh)
    sl = sub.add_parser(
        PAINT_SLIP,
        parents=[_manifest_parent()],
        help="how far paint on an export moves from the plate's own motion between neighbouring frames",
        description="For pixels a foreground layer owns, where DIS flow to the next frame survives a round trip, "
        "find where paint at the pixel's UV shows in the next frame (the owned pixel with the nearest UV, "
        "sub-pixel) and measure its distance from where the flow carries the pixel: median, mean and 90th "
        "percentile in native pixels, per foreground layer and pooled. No tracks needed.",
    )
    sl.add_argument("--plate", required=True, metavar="FRAMES", help="the plate the export was made from")
    _add_json(sl)


def _add_paint_table_parser(sub: argparse._SubParsersAction) -> None:
    pt = sub.add_parser(
        PAINT_TABLE,
        parents=[_preset_parent(), _mask_recipe_parent("exact")],
        help="one preset fitted and exported on every clip of a folder, scored on the export (paint, flow, IoU, "
        "sharpness, PSNR, train s)",
        description="For each clip folder (frames/, masks/, tracks_tapvid.npz; a motion scene's gt_uv.npz and "
        "texture.png too): degrade its masks by RECIPE, `fit` the preset into OUT/runs/CLIP (a finished fit is "
        "kept), `export` it, and score the export: paint-tracks, flow-tracks, their ratio, the exported foreground "
        "alpha's IoU against masks/, sharpness (and a scene's true-texture sharpness), PSNR and training seconds. "
        "Writes OUT/paint.md and OUT/paint.json; --pictures also OUT/pictures/CLIP.png (a checkerboard painted once, "
        "first / middle / last frame, above the same colours carried by chained flow).",
    )
    pt.add_argument("root", metavar="CLIPS_ROOT", help="folder of clip folders")
    pt.add_argument("--out", default="paint_out", help="output folder (default: paint_out)")
    _add_only(pt)
    add_set(pt, "fit config override")
    add_threads(pt, "CPU threads of each fit (default: torch's choice)")
    pt.add_argument("--pictures", action="store_true", help="also write OUT/pictures/CLIP.png")
    split = pt.add_mutually_exclusive_group()
    split.add_argument(
        "--parts", action="store_true", help="fit a clip with masks_parts/PART/ folders with one layer per part"
    )
    split.add_argument(
        "--scribbles",
        action="store_true",
        help="fit a clip with masks_parts/PART/ folders with its one mask split by strokes drawn from the parts "
        "on --scribble-frames frames: the product's Split with Scribbles",
    )
    split.add_argument(
        "--auto-parts",
        action="store_true",
        help="fit each clip with `fit --auto-parts`: its (degraded) mask split by the strokes the fit draws from the "
        "motion into OUT/runs/CLIP/parts (a clip it does not split is fitted as without); the fit's default does "
        "the same wherever it applies",
    )
    split.add_argument(
        "--no-auto-parts",
        dest="one_layer",
        action="store_true",
        help="fit each clip with `fit --no-auto-parts`: one layer per mask, never split",
    )
    pt.add_argument(
        "--scribble-frames",
        type=int,
        default=3,
        metavar="N",
        help="with --scribbles: frames with strokes, spread evenly from the first to the last (default: 3)",
    )
    add_follow_flow(
        pt,
        None,
        "export with the engine's --follow-flow, which insists: every layer's UV averaged along optical flow "
        "where it slips against it, the parts of one split object too (default: export's own, which leaves those "
        "parts as fitted)",
        "export with --no-follow-flow (each layer's UV as fitted)",
    )


def _add_paint_gaps_parser(sub: argparse._SubParsersAction) -> None:
    pg = sub.add_parser(
        PAINT_GAPS,
        help="paint against chained flow by frame gap, one panel per clip, one line per paint table",
        description="Read paint-table records (paint.json) and draw each clip's TAP-Vid delta_avg by the frames "
        "between a point's frame and its query frame: one line per table (e.g. exact masks against a rough roto, "
        "or one change against another), chained flow dashed.",
    )
    pg.add_argument("tables", nargs="+", metavar="PAINT_JSON", help="paint-table records")
    pg.add_argument("--out", required=True, metavar="PNG", help="the picture to write")
    _add_only(pg)
    pg.add_argument(
        "--label",
        action="append",
        default=None,
        metavar="TEXT",
        help="a legend entry per table, in order (default: each table's preset, masks and overrides)",
    )


def _add_export_cost_parser(sub: argparse._SubParsersAction) -> None:
    ec = sub.add_parser(
        EXPORT_COST,
        help="two kinds of export of one run, in turn: wall time and peak memory, as ratios",
        description="Export a copy of RUN_DIR (its exports and edit layers are not touched) REPEATS times each way "
        "(--compare: following the flow and as fitted, or the pass files written ahead and in turn), in turn with "
        "the order swapped each round, each in its own process: the medians of wall seconds and of peak resident "
        "memory, and their ratios.",
    )
    ec.add_argument("run", metavar="RUN_DIR", help="the --out folder of a finished fit")
    ec.add_argument("--repeats", type=int, default=2, help="exports of each kind (default: 2)")
    add_threads(ec, "CPU threads of each export (default: torch's choice)")
    ec.add_argument("--work", default=None, metavar="DIR", help="where the copy goes (default: the temp folder)")
    ec.add_argument(
        "--compare",
        default="follow-flow",
        choices=tuple(COMPARISONS),
        help="follow-flow (default): following the flow against the UV as fitted (--no-follow-flow); write-ahead: "
        "each frame's pass file written while the next frame is evaluated against one after another; "
        "render-write-ahead: the same for `render` (EXR frames, paint on half of every atlas) of one export",
    )
    _add_json(ec)


def _add_export_size_parser(sub: argparse._SubParsersAction) -> None:
    es = sub.add_parser(
        EXPORT_SIZE,
        help="an export's pass files rewritten with other channels, precision and compression: MB a frame",
        description="Rewrite FRAMES of EXPORT's pass files (spread over the clip) into a scratch folder with each "
        "choice of channels (the STMap copy kept or left out), precision (alpha and coverage in half float; u and v "
        "rounded) and compression (ZIP, PIZ): the mean MB a frame, scaled to 1080p and 4K by pixel count, the "
        "seconds to write one, and the largest error each choice puts in a value. The export is only read.",
    )
    es.add_argument("export", metavar="EXPORT", help="an export folder (RUN/exports/vNNN) or its manifest.json")
    es.add_argument("--frames", type=int, default=10, help="pass files to rewrite (default: 10)")
    _add_json(es)


def _add_farm_parser(sub: argparse._SubParsersAction) -> None:
    fb = sub.add_parser(
        FARM,
        help="shots one after another vs through `farm dask` with local workers: wall times and their ratio",
        description="Plan the clips as a shots file and run the plan twice: every task one after another (all "
        "cores to each engine), then on a Dask scheduler and workers started on 127.0.0.1 (the cores split "
        "between them). Prints a markdown table (date, machine, this command) and writes OUT/farm_bench.json.",
    )
    fb.add_argument("clips", nargs="+", metavar="CLIP", help="clip folder holding frames/ and masks/")
    fb.add_argument("--out", default="farm_bench_out", help="output folder, replaced (default: farm_bench_out)")
    add_preset(fb, "draft", "fit preset of every shot (default: draft)")
    add_set(fb, "fit config override")
    fb.add_argument("--workers", type=int, default=2, help="Dask workers, one engine each (default: 2)")
    fb.add_argument("--cores", type=int, default=None, help="torch threads in all (default: the machine's cores)")
    fb.add_argument("--export-chunk", type=int, default=None, metavar="N", help="frames per export-passes task")
