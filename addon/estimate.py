"""A documented fit-time estimate per preset, until the engine's own calibration lands. No bpy here.

Measured on a 2-core CPU (docs/engine.md: blackswan, 50 frames fitted at 768x432): seconds per training
step per preset, and the per-frame cost of optical flow and evaluation (wall time minus train time:
draft 204 s - 134 s = 70 s for 50 frames at 0.33 Mpx). Steps cost about the same at any resolution
(a fixed pixel batch); flow and evaluation scale with the working pixels.
"""

from __future__ import annotations

#: preset -> (steps, seconds per step) from docs/engine.md (session 4: blackswan draft 97 s / 800 steps,
#: balanced 692 s / 6000 steps; final's steps at balanced's rate)
PRESET_STEPS: dict[str, tuple[int, float]] = {
    "draft": (800, 0.121),
    "balanced": (6000, 0.115),
    "final": (28000, 0.115),
    "paper": (400000, 4.43),
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
