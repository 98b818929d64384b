"""``bench export-size EXPORT``: what each choice of pass channels and compression costs on disk, per frame, on an
export's own passes, and what half floats lose.

Why: an export with every bit (``--pass-precision full``) and the STMap copy of the UV for Nuke (``--stmap``) writes
every layer's UV (u, v, coverage) and alpha as float32 twice over, ZIP-compressed: ~7 MB a frame at 854x480, so tens
of MB at 2K and more at 4K. The choices a studio weighs are
measured here on real passes rather than guessed: the STMap copy left out, the alpha and coverage (values in 0..1 that
no reader needs to the last float32 bit) in half float, and the compression. UVs stay float32 in every variant: on a
1000-texel atlas half floats move u, v by up to a quarter texel.

The rows are meant for such an export (``export RUN --pass-precision full --stmap``): a row that keeps the copy
finds none in an export without it. Each variant rewrites a sample of the export's pass files into a scratch folder
(the export is only read) and reports the mean bytes per frame, the seconds to write one, and the largest error half
floats put in any value.
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenEXR

from engine import contract as C
from engine.errors import InputError
from engine.terms.export_names import PASSES_DIR, alpha_pass, stmap_pass, uv_pass

#: (name, compression, alpha and coverage in half float (1: half channels; 2: rounded to half's precision, kept in
#: float32 channels), the STMap copy kept, u and v rounded to multiples of this (0: not rounded; float32 either way))
VARIANTS: tuple[tuple[str, str, int, bool, float], ...] = (
    ("as exported: float32, STMap copy, ZIP", "zip", False, True, 0.0),
    ("STMap copy left out", "zip", False, False, 0.0),
    ("alpha and coverage in half float, STMap copy left out", "zip", True, False, 0.0),
    ("the same, u and v rounded to 2^-17 (float32)", "zip", True, False, 2.0**-17),
    ("the same, the STMap copy kept (its values as the UV pass's)", "zip", True, True, 2.0**-17),
    (
        "every channel float32, the STMap copy kept; alpha and coverage rounded to half's precision, u and v to 2^-17",
        "zip",
        2,
        True,
        2.0**-17,
    ),
    (
        "every channel float32, no STMap copy; alpha and coverage rounded to half's precision, u and v to 2^-17 "
        "(what export writes by default)",
        "zip",
        2,
        False,
        2.0**-17,
    ),
    ("the same, u and v rounded to 2^-14 (float32)", "zip", True, False, 2.0**-14),
    ("as exported, PIZ", "piz", False, True, 0.0),
    ("alpha and coverage in half float, STMap copy left out, PIZ", "piz", True, False, 0.0),
)
#: The row of what ``export`` writes by default (``--pass-precision compact``, no ``--stmap``).
DEFAULT_VARIANT = VARIANTS[6][0]
COMPRESSIONS = {"zip": OpenEXR.ZIP_COMPRESSION, "piz": OpenEXR.PIZ_COMPRESSION}


@dataclass(frozen=True)
class SizeRow:
    variant: str
    channels: int
    mb_per_frame: float
    write_seconds: float
    max_half_error: float
    max_uv_error: float


def _read(path: Path) -> dict[str, np.ndarray]:
    with OpenEXR.File(str(path)) as f:
        return {name: np.asarray(ch.pixels) for name, ch in f.channels().items()}


def _is_alpha_or_coverage(name: str) -> bool:
    """An alpha pass (``Atlas.Alpha<Layer>.V``) or a UV pass's coverage (``Atlas.UV<Layer>.A``)."""
    return name.startswith(f"Atlas.{alpha_pass('')}") or (
        name.startswith(f"Atlas.{uv_pass('')}") and name.endswith(".A")
    )


def _is_u_or_v(name: str) -> bool:
    """A UV pass's u or v (``Atlas.UV<Layer>.U`` / ``.V``)."""
    return name.startswith(f"Atlas.{uv_pass('')}") and name.endswith((".U", ".V"))


def measure_export_size(export: Path, frames: int = 10) -> list[SizeRow]:
    """Every ``VARIANTS`` row on ``frames`` pass files of ``export`` (an export folder or its manifest), spread over
    the clip."""
    folder = export.parent if export.name == C.MANIFEST_NAME else export
    passes = folder / PASSES_DIR
    files = sorted(passes.glob("*.exr")) if passes.is_dir() else []
    if not files:
        raise InputError(folder, "holds no pass files", "pass an export folder (RUN/exports/vNNN) or its manifest")
    picked = files[:: max(1, len(files) // max(1, frames))][:frames]
    rows = []
    with tempfile.TemporaryDirectory(prefix="export_size_") as scratch:
        for name, compression, half, stmap, grid in VARIANTS:
            sizes, seconds, worst, uv_worst, count = [], 0.0, 0.0, 0.0, 0
            for path in picked:
                chans = {k: v for k, v in _read(path).items() if stmap or not k.startswith(stmap_pass(""))}
                data = {}
                for key, values in chans.items():
                    if half and _is_alpha_or_coverage(key):
                        halved = values.astype(np.float16)
                        data[key] = halved if half == 1 else halved.astype(np.float32)
                        worst = max(worst, float(np.abs(halved.astype(np.float32) - values).max()))
                    elif grid and _is_u_or_v(key):
                        data[key] = (np.round(values / grid) * grid).astype(np.float32)
                        uv_worst = max(uv_worst, float(np.abs(data[key] - values).max()))
                    elif values.ndim == 3 and (half or grid):  # an STMap copy (R, G, B, A): as its UV pass is kept
                        copy = np.array(values, dtype=np.float32)
                        if grid:
                            copy[..., :2] = np.round(copy[..., :2] / grid) * grid
                        if half:
                            copy[..., 3] = copy[..., 3].astype(np.float16).astype(np.float32)
                        data[key] = copy
                    else:
                        data[key] = np.ascontiguousarray(values, dtype=np.float32)
                count = sum(1 if v.ndim == 2 else v.shape[2] for v in data.values())  # (OpenEXR takes the dict over)
                out = Path(scratch) / path.name
                start = time.perf_counter()
                header = {"compression": COMPRESSIONS[compression], "type": OpenEXR.scanlineimage}
                with OpenEXR.File(header, data) as f:
                    f.write(str(out))
                seconds += time.perf_counter() - start
                sizes.append(os.path.getsize(out))
            rows.append(SizeRow(name, count, float(np.mean(sizes)) / 1e6, seconds / len(picked), worst, uv_worst))
    return rows


def format_sizes(export: Path, rows: list[SizeRow], resolution: tuple[int, int] | None) -> str:
    """The table, with each size scaled to 1920x1080 and 4096x2160 by pixel count (a guide: compression varies)."""
    pixels = resolution[0] * resolution[1] if resolution else None
    lines = [
        f"export-size {export}" + (f" ({resolution[0]}x{resolution[1]})" if resolution else ""),
        "| channels | count | MB/frame | at 1080p | at 4K | write s/frame | max error: alpha, coverage "
        "| max error: u, v |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        hd = f"{r.mb_per_frame * 1920 * 1080 / pixels:.1f}" if pixels else "–"
        uhd = f"{r.mb_per_frame * 4096 * 2160 / pixels:.1f}" if pixels else "–"
        err = f"{r.max_half_error:.1e}" if r.max_half_error else "0"
        uv = f"{r.max_uv_error:.1e}" if r.max_uv_error else "0"
        size = f"{r.mb_per_frame:.2f} | {hd} | {uhd}"
        lines.append(f"| {r.variant} | {r.channels} | {size} | {r.write_seconds:.2f} | {err} | {uv} |")
    return "\n".join(lines)


__all__ = ["DEFAULT_VARIANT", "VARIANTS", "SizeRow", "format_sizes", "measure_export_size"]
