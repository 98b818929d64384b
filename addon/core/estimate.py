"""How long a fit takes: the documented estimate per preset, which the panel shows until the engine's own
(``engine estimate``) has timed this clip on this machine, and the engine's, once it has. No bpy here.

The documented estimate: each preset's step budget (``contract.PRESET_STEPS``) times its seconds per step, plus
flow and evaluation, which scale with the frames and the working pixels (steps cost about the same at any
resolution: a fixed pixel batch, grown with a clip longer than the preset's ``contract.PRESET_CLIP_FRAMES``). The
per-step and overhead figures are the 2-core CPU bench of docs/accuracy-vs-time.md (its data:
docs/bench/blackswan-60min.json).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

from ...engine import contract as C  # type: ignore[import-not-found]
from .progress import format_seconds

#: preset -> seconds per training step on the documented 2-core CPU
SECONDS_PER_STEP: dict[str, float] = {"draft": 0.132, "balanced": 0.151, "final": 0.154, "paper": 4.54}
#: The documented flow + evaluation time: OVERHEAD_SECONDS for OVERHEAD_FRAMES frames at OVERHEAD_SIZE.
OVERHEAD_SECONDS = 70.0
OVERHEAD_FRAMES = 50
OVERHEAD_SIZE = (768, 432)
PIXELS_PER_MEGAPIXEL = 1e6
#: seconds of flow + evaluation per frame per working megapixel
OVERHEAD_SECONDS_PER_FRAME_MPX = (
    OVERHEAD_SECONDS / OVERHEAD_FRAMES / (OVERHEAD_SIZE[0] * OVERHEAD_SIZE[1] / PIXELS_PER_MEGAPIXEL)
)
#: The preset the estimate falls back to for a name it does not know.
FALLBACK_PRESET = "balanced"
#: The engine's estimate, preset -> {"seconds": float | None, "psnr": float | None} and, for a preset that cannot
#: fit this clip (the engine's row carries ``unavailable``), "unavailable": the engine's one-line reason.
EngineRows = dict[str, dict[str, Any]]


def preset_items() -> list[tuple[str, str, str]]:
    """The preset menu: (name, title, description with its steps and seconds per step), in the contract's order."""
    return [
        (name, name.title(), f"{steps} steps, about {SECONDS_PER_STEP[name]:.2f} s per step on a 2-core CPU")
        for name, steps in C.PRESET_STEPS.items()
    ]


def estimate_seconds(
    preset: str, frames: int, width: int, height: int, long_edge: int = C.DEFAULT_LONG_EDGE, steps: int | None = None
) -> float:
    """The documented fit time of ``frames`` frames of a ``width`` x ``height`` clip (``steps``: the artist's
    ``steps=`` override; None: the preset's budget)."""
    name = preset if preset in C.PRESET_STEPS else FALLBACK_PRESET
    w, h = C.working_size(width, height, long_edge)
    training = (C.PRESET_STEPS[name] if steps is None else steps) * SECONDS_PER_STEP[name] * batch_scale(name, frames)
    return training + OVERHEAD_SECONDS_PER_FRAME_MPX * frames * (w * h / PIXELS_PER_MEGAPIXEL)


def batch_scale(preset: str, frames: int) -> float:
    """How much more a step of a ``frames``-frame clip costs than the documented one: a preset's batch grows with a
    clip longer than the length it is for (``contract.PRESET_CLIP_FRAMES``), and a step's time with its batch."""
    per = C.PRESET_CLIP_FRAMES.get(preset, 0)
    return max(1.0, frames / per) if per > 0 else 1.0


def overridden_int(items: Sequence[str], key: str) -> int | None:
    """The last ``KEY=N`` among the fit's ``--set`` items (``farm.set_items``) as a positive whole number, as the
    engine reads it (the last one given wins); None when there is none or it is not one (the engine refuses that
    with its own line)."""
    value = next((item.partition("=")[2] for item in reversed(items) if item.partition("=")[0].strip() == key), None)
    if value is None:
        return None
    try:
        number = int(value)
    except ValueError:
        return None
    return number if number > 0 else None


def _engine_row(row: dict[str, Any]) -> dict[str, Any]:
    """One preset of the engine's JSON as the panel keeps it: its time and PSNR, or why it does not apply."""
    if row.get("unavailable"):
        return {"seconds": None, "psnr": None, "unavailable": str(row["unavailable"])}
    return {"seconds": float(row["total_seconds"]), "psnr": row.get("expected_psnr")}


def parse_engine_estimate(text: str, tag: str) -> EngineRows:
    """``engine estimate --json`` output (the line carrying ``tag``) -> {preset: {seconds, psnr}}, or
    {preset: {seconds: None, psnr: None, unavailable: why}} for a preset the engine says cannot fit this clip."""
    for line in reversed(text.strip().splitlines()):
        line = line.strip()
        if not line.startswith("{"):
            continue
        try:
            data = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(data, dict) and tag in data:
            return {p["preset"]: _engine_row(p) for p in data.get("presets", [])}
    return {}


def estimate_text(preset: str, engine: EngineRows, fallback_seconds: float) -> str:
    """The panel's line: the engine's estimate for this clip when it has one, why the preset cannot fit this clip
    when the engine says so, else the documented estimate."""
    row = engine.get(preset)
    if row is None:
        return f"about {format_seconds(fallback_seconds)} on a 2-core CPU (documented)"
    if row.get("unavailable"):
        return f"{preset} cannot fit this clip: {row['unavailable']}"
    text = f"about {format_seconds(row['seconds'] or 0.0)} here (engine estimate)"
    psnr = row.get("psnr")
    return text + (f", ~{psnr:.1f} dB" if psnr else "")
