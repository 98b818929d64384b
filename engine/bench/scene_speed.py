"""What the scene analysis saves: the same clip fitted with ``components=auto`` and ``components=all``.

    python -m engine.bench.scene_speed CLIP [--mask FOLDER] [--frames A:B] [--preset draft] [--steps N]
                                 [--long-edge PX] [--out DIR]

Both fits use the same config, seed and steps; only ``components`` differs. Prints one line per fit
(seconds per step, full-frame PSNR, background mapping class, terms evaluated) and the ratio of seconds
per step, then a JSON summary as the last line. Training time only (the flow is computed once per run and
cached; it is not part of ``train_seconds``). The numbers in docs/engine.md come from this command.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

from engine.config import apply_overrides, preset_config
from engine.data.scene_analysis import read_scene_file
from engine.fit.trainer import fit


def compare_components(
    clip: str | Path,
    masks: list[str | Path],
    out: Path,
    preset: str = "draft",
    steps: int = 300,
    long_edge: int = 384,
    frame_range: tuple[int, int] | None = None,
    overrides: dict[str, str] | None = None,
) -> dict[str, Any]:
    """Fit ``clip`` twice (components auto, then all) into ``out/auto`` and ``out/all``; returns both
    fits' seconds per step, PSNR and scene decisions, and the seconds-per-step ratio all/auto."""
    rows: dict[str, Any] = {}
    for comp in ("auto", "all"):
        cfg = apply_overrides(
            preset_config(preset),
            {
                "steps": str(steps),
                "long_edge": str(long_edge),
                "eval_every": str(max(steps, 1)),
                "checkpoint_seconds": "1e9",
                "components": comp,
                **(overrides or {}),
            },
        )
        run = Path(out) / comp
        metrics = fit(
            clip,
            list(masks),
            run,
            cfg,
            device_name="cpu",
            frame_range=frame_range,
            progress_bar=False,
            stream=io.StringIO(),
        )
        scene = read_scene_file(run)
        rows[comp] = {
            "seconds_per_step": metrics["seconds_per_step"],
            "psnr": metrics["psnr"],
            "alpha_iou": metrics["alpha_iou"],
            "background_motion": scene.background_motion if scene else None,
            "active_terms": scene.active_terms if scene else None,
            "working_size": metrics["working_size"],
            "frames": metrics["frames"],
        }
    auto_sps = max(rows["auto"]["seconds_per_step"], 1e-9)  # guard: a zero-step fit has 0 s/step
    return {
        "clip": str(clip),
        "steps": steps,
        "preset": preset,
        **rows,
        "speedup": rows["all"]["seconds_per_step"] / auto_sps,
    }


def _frames(text: str) -> tuple[int, int]:
    a, _, b = text.partition(":")
    return int(a), int(b)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m engine.bench.scene_speed", description=__doc__.split("\n\n")[0])
    p.add_argument("clip")
    p.add_argument("--mask", action="append", default=[])
    p.add_argument("--frames", type=_frames, default=None, metavar="A:B")
    p.add_argument("--preset", default="draft")
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--long-edge", type=int, default=384)
    p.add_argument("--out", default=None, help="folder for the two runs (default: a temporary folder)")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out) if args.out else Path(tmp)
        res = compare_components(args.clip, args.mask, out, args.preset, args.steps, args.long_edge, args.frames)
    for comp in ("auto", "all"):
        r = res[comp]
        print(
            f"components={comp}: {r['seconds_per_step'] * 1000:.1f} ms/step, PSNR {r['psnr']:.2f} dB, "
            f"background {r['background_motion']}, {len(r['active_terms'] or [])} terms",
            file=sys.stderr,
        )
    print(f"speed-up (all / auto seconds per step): {res['speedup']:.2f}x", file=sys.stderr)
    print(json.dumps(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
