"""What a bench record shows a person: the plot of PSNR, tracking and consistency against training minutes
(``bench.png``) and the markdown table of each run's last point."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def plot_bench(record: dict, path: str | Path) -> None:
    """PSNR, tracking delta_avg and consistency against training minutes: one row per clip, one line per preset."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    clips = record["clips"]
    fig, axes = plt.subplots(len(clips), 3, figsize=(15, 4 * len(clips)), squeeze=False)
    for row, clip in zip(axes, clips, strict=True):
        for run in (r for r in record["runs"] if r["clip"] == clip["name"]):
            pts = run["curve"]
            if not pts:
                continue
            minutes = [p["train_seconds"] / 60.0 for p in pts]
            label = f"{run['preset']} ({run['model']})"
            row[0].plot(minutes, [p["psnr"] for p in pts], marker="o", label=label)
            trk = [p["tracking"]["delta_avg"] if p["tracking"] else None for p in pts]
            if any(v is not None for v in trk):
                row[1].plot(minutes, [np.nan if v is None else v for v in trk], marker="o", label=label)
            cons = [np.nan if p["consistency_texels"] is None else p["consistency_texels"] for p in pts]
            row[2].plot(minutes, cons, marker="o", label=label)
        base = clip.get("tracking_baseline")
        if base and base.get("delta_avg") is not None:
            row[1].axhline(base["delta_avg"], color="k", linestyle="--", label="chained optical flow")
        name = clip["name"]
        row[0].set(title=f"{name}: PSNR on {len(clip['eval_frames'])} full frames", ylabel="dB")
        row[1].set(title=f"{name}: TAP-Vid delta_avg (native px)", ylim=(0, 1))
        row[2].set(title=f"{name}: mapping consistency", ylabel="texels (lower is better)")
        for ax in row:
            ax.set_xlabel("training minutes (evaluation excluded)")
            ax.grid(alpha=0.3)
            if ax.lines:
                ax.legend(fontsize=8)
    m = record["machine"]
    fig.suptitle(f"accuracy vs time: {m['cpu']}, {m['cores']} cores, {record['created']}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def summary_table(record: dict) -> str:
    lines = [
        "| clip | preset | steps | train s | s/step | PSNR (last / best) | fg IoU | consistency (texels) "
        "| delta_avg | flow delta_avg |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    base = {c["name"]: c.get("tracking_baseline") for c in record["clips"]}
    for r in record["runs"]:
        last = r["curve"][-1] if r["curve"] else None
        b = base.get(r["clip"])

        def fmt(v: Any, spec: str = ".3f") -> str:
            return "–" if v is None else format(v, spec)

        trk = last["tracking"]["delta_avg"] if last and last["tracking"] else None
        lines.append(
            f"| {r['clip']} | {r['preset']} | {r['steps']} | {r['train_seconds']:.0f} | {r['seconds_per_step']:.3f} | "
            f"{fmt(last and last['psnr'], '.2f')} / {fmt(last and last['best_psnr'], '.2f')} | "
            f"{fmt(last and last.get('fg_iou'))} | "
            f"{fmt(last and last['consistency_texels'], '.2f')} | {fmt(trk)} | {fmt(b and b['delta_avg'])} |"
        )
    return "\n".join(lines)
