"""Paint against chained flow by frame gap, read from paint tables (``bench paint-gaps``).

One number per clip hides where paint fails: an atlas whose UVs drift loses at long gaps what it wins at short ones,
and a turning body's new side enters only after many frames. Each table row keeps ``paint_by_gap`` and
``flow_by_gap`` (TAP-Vid delta_avg of the points whose frame lies in a gap bin of its query frame); this draws them,
one panel per clip, one line per table (exact masks against a rough roto, one change against another) and chained
flow dashed, so the note of a change can show its curves beside its table.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from engine.errors import InputError

#: The fix of a file that is not a paint table.
FIX_TABLE = "give paint-table's paint.json"


@dataclass(frozen=True)
class GapSeries:
    """One clip's delta_avg by gap bin in one table: ``bins`` ("1-3", "3-8", ..., "32+"), ``paint`` and ``flow``
    (NaN where the bin holds no scored point)."""

    label: str
    bins: tuple[str, ...]
    paint: tuple[float, ...]
    flow: tuple[float, ...]


def _bin_name(gap: list) -> str:
    low, high = gap
    return f"{low}+" if high is None else f"{low}-{high}"


def _values(curve: list[dict]) -> tuple[float, ...]:
    return tuple(math.nan if b.get("delta_avg") is None else float(b["delta_avg"]) for b in curve)


def table_label(table: dict) -> str:
    """What tells one table from another in a legend: its preset, masks, split and overrides."""
    parts = [table.get("preset", "?"), f"masks {table.get('degrade', '?')}"]
    if table.get("parts"):
        parts.append("part masks")
    if table.get("scribbles"):
        parts.append(f"scribbles on {table.get('scribble_frames') or 3} frames")
    parts += list(table.get("sets") or [])
    return ", ".join(parts)


def gap_series(table: dict, label: str | None = None) -> dict[str, GapSeries]:
    """Each row's by-gap curves of a paint-table record (``paint.json``), by clip; rows without them are left out."""
    out: dict[str, GapSeries] = {}
    for row in table.get("rows", []):
        paint, flow = row.get("paint_by_gap"), row.get("flow_by_gap")
        if not paint or not flow:
            continue
        bins = tuple(_bin_name(b["gap"]) for b in paint)
        if bins != tuple(_bin_name(b["gap"]) for b in flow):
            raise ValueError(f"{row.get('clip')}: paint and flow are binned differently")
        out[row["clip"]] = GapSeries(label or table_label(table), bins, _values(paint), _values(flow))
    return out


def read_table(path: str | Path) -> dict:
    """A ``paint.json``; a file that is not one is a one-line input error."""
    p = Path(path)
    try:
        table = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(p, f"is not a readable paint table ({type(exc).__name__})", FIX_TABLE) from None
    if not isinstance(table, dict) or "rows" not in table:
        raise InputError(p, "is not a paint table (no rows)", FIX_TABLE)
    return table


def plot_paint_gaps(
    tables: list[dict], path: str | Path, only: list[str] | None = None, labels: list[str] | None = None
) -> list[str]:
    """Draw every clip's paint by gap, one line per table, chained flow (the first table's) dashed; one panel per
    clip in the order they first appear (``only``: those clips). Returns the clips drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = [gap_series(t, labels[i] if labels else None) for i, t in enumerate(tables)]
    clips: list[str] = []
    for s in series:
        clips += [c for c in s if c not in clips and (not only or c in only)]
    if not clips:
        raise InputError(None, "no clip of these tables has paint_by_gap and flow_by_gap", "give paint-table records")
    cols = min(3, len(clips))
    rows = math.ceil(len(clips) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 3.6 * rows), squeeze=False)
    for ax, clip in zip(axes.flat, clips, strict=False):
        flow_drawn = False
        for s in series:
            if clip not in s:
                continue
            g = s[clip]
            x = range(len(g.bins))
            ax.plot(x, g.paint, marker="o", label=f"paint: {g.label}")
            if not flow_drawn:
                ax.plot(x, g.flow, color="k", linestyle="--", marker="x", label="chained flow")
                flow_drawn = True
            ax.set_xticks(list(x), g.bins)
        ax.set(title=clip, xlabel="frames from the query frame", ylabel="delta_avg", ylim=(0, 1))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="lower left")
    for ax in list(axes.flat)[len(clips) :]:
        ax.axis("off")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return clips


__all__ = ["GapSeries", "gap_series", "plot_paint_gaps", "read_table", "table_label"]
