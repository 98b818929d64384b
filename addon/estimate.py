"""The documented fit-time estimate per preset: what the panel shows before the engine's own calibration
(``engine estimate``) has measured this clip on this machine. No bpy here.

Step budgets are the engine's (``contract.PRESET_STEPS``); seconds per step are the 60-minute side-by-side
bench on blackswan (docs/accuracy-vs-time.md, 2-core AMD EPYC: draft 106 s / 800 steps, balanced 907 s / 6000,
final 0.154 s/step, paper 4.54 s/step). Flow and evaluation cost per frame and working pixel (docs/engine.md:
draft 204 s wall - 134 s training = 70 s for 50 frames at 0.33 Mpx). Steps cost about the same at any
resolution (a fixed pixel batch); flow and evaluation scale with the working pixels.
"""

from __future__ import annotations

from ..engine import contract as C

#: preset -> seconds per training step on a 2-core CPU (docs/bench/blackswan-60min.json)
SECONDS_PER_STEP: dict[str, float] = {"draft": 0.132, "balanced": 0.151, "final": 0.154, "paper": 4.54}
#: preset -> (steps, seconds per step): the preset menu and the documented estimate
PRESET_STEPS: dict[str, tuple[int, float]] = {
    name: (steps, SECONDS_PER_STEP[name]) for name, steps in C.PRESET_STEPS.items()
}
#: seconds of flow + evaluation per frame per working megapixel (70 s / 50 frames / 0.332 Mpx)
OVERHEAD_SECONDS_PER_FRAME_MPX = 70.0 / 50 / (768 * 432 / 1e6)


def working_size(width: int, height: int, long_edge: int) -> tuple[int, int]:
    """The engine's working resolution: long edge ``long_edge`` (never upscaled), aspect kept."""
    scale = min(1.0, long_edge / max(width, height))
    return max(1, round(width * scale)), max(1, round(height * scale))


def estimate_seconds(preset: str, frames: int, width: int, height: int, long_edge: int = 768) -> float:
    steps, per_step = PRESET_STEPS.get(preset, PRESET_STEPS["balanced"])
    w, h = working_size(width, height, long_edge)
    return steps * per_step + OVERHEAD_SECONDS_PER_FRAME_MPX * frames * (w * h / 1e6)


def parse_engine_estimate(text: str, tag: str) -> dict[str, dict[str, float | None]]:
    """``engine estimate --json`` output (the line carrying ``tag``) -> {preset: {seconds, psnr}}."""
    import json

    for line in reversed(text.strip().splitlines()):
        line = line.strip()
        if not line.startswith("{"):
            continue
        try:
            data = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(data, dict) and tag in data:
            return {
                p["preset"]: {"seconds": float(p["total_seconds"]), "psnr": p.get("expected_psnr")}
                for p in data.get("presets", [])
            }
    return {}


def estimate_text(preset: str, engine: dict[str, dict[str, float | None]], fallback_seconds: float) -> str:
    """The panel's line: the engine's calibration for this clip when measured, else the documented estimate."""
    from .engine_process import format_seconds

    row = engine.get(preset)
    if row is None:
        return f"about {format_seconds(fallback_seconds)} on a 2-core CPU (documented)"
    text = f"about {format_seconds(row['seconds'] or 0.0)} here (engine estimate)"
    return text + (f", ~{row['psnr']:.1f} dB" if row.get("psnr") else "")
