"""Measurements read from a finished ``fit``'s run folder: the error of the ETA it reported, and its PSNR
recorded as its preset's expected PSNR (what ``estimate`` shows)."""

from __future__ import annotations

import json
from pathlib import Path

from engine import contract as C
from engine.errors import InputError
from engine.fit.run_folder import RunFolder
from engine.io.atomic import atomic_write_text


def fit_eta_errors(run_dir: str | Path) -> list[dict]:
    """The ETA error of a finished ``fit``: for each progress line of its ``fit.log`` (the ETA it reported,
    see ``engine.fit.eta``), the predicted remaining training time against the actual
    one (``metrics.json``'s ``train_seconds`` minus the line's ``elapsed``). ``error`` = predicted / actual - 1.
    Training seconds exclude the live evaluation and checkpoints; a resumed fit is not supported."""
    run = RunFolder(run_dir)
    metrics = run.read_metrics()
    if metrics is None:
        raise InputError(run.metrics, "the fit has not finished", "let it finish (or resume it) first")
    total = metrics["train_seconds"]
    rows = []
    for line in run.log.read_text(encoding="utf-8").splitlines():
        msg = C.parse_progress_line(line)
        if not msg or msg["event"] != C.EVENT_PROGRESS or msg.get("eta") is None:
            continue
        actual = total - msg["elapsed"]
        if actual <= 0:
            continue
        rows.append(
            {
                "step": msg["step"],
                "fraction": round(msg["step"] / msg["total"], 4),
                "elapsed": msg["elapsed"],
                "eta_seconds": msg["eta"],
                "actual_seconds": round(actual, 2),
                "error": round(msg["eta"] / actual - 1.0, 4),
            }
        )
    return rows


def record_expected_psnr(preset: str, run_dir: str | Path, clip: str, note: str, path: Path | None = None) -> dict:
    """Write a finished fit's full-frame PSNR into ``engine/fit/expected_psnr.json`` as ``preset``'s expected PSNR
    (what ``estimate`` shows): the run must be a fit of that preset. Returns the row written."""
    from engine.fit.estimate import EXPECTED_PSNR_FILE

    run = RunFolder(run_dir)
    metrics = run.read_metrics()
    if metrics is None:
        raise InputError(run.metrics, "the fit has not finished", "let it finish (or resume it) first")
    if metrics["preset"] != preset:
        raise InputError(run.metrics, f"this is a {metrics['preset']} fit, not {preset}", "pass the right run")
    path = path or EXPECTED_PSNR_FILE
    data = json.loads(path.read_text(encoding="utf-8"))
    row = {"psnr": round(float(metrics["psnr"]), 2), "clip": clip, "note": note}
    data["presets"][preset] = row
    atomic_write_text(path, json.dumps(data, indent=2) + "\n")
    return row
