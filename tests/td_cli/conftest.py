"""One tiny fit of an untagged float EXR plate, and its export, through the command line as a pipeline runs it."""

from __future__ import annotations

import contextlib
import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from engine import cli
from engine.io import colour
from engine.io.images import write_rgba_exr
from tests.farm.farm_helpers import TINY_SET, write_clip


@dataclass(frozen=True)
class Ran:
    """A command's exit code, stdout and stderr."""

    code: int
    out: str
    err: str


def run_main(*args: str | os.PathLike[str]) -> Ran:
    """``python -m engine ARGS`` in this process, stdout and stderr captured."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main([os.fspath(a) for a in args])
    return Ran(code, out.getvalue(), err.getvalue())


@dataclass(frozen=True)
class AssumedRun:
    plate: Path
    run: Path
    fit_out: str
    fit_err: str
    manifest: Path


def exr_plate(pngs: Path, folder: Path) -> Path:
    """The synthetic clip's sRGB PNG frames as untagged float EXRs (scene-linear values, no chromaticities)."""
    folder.mkdir(parents=True)
    for i, png in enumerate(sorted(pngs.glob("*.png"))):
        rgb = oiio.ImageBuf(str(png)).get_pixels(oiio.FLOAT)[:, :, :3]
        write_rgba_exr(folder / f"plate.{1001 + i}.exr", colour.srgb_to_linear(np.ascontiguousarray(rgb)))
    return folder


@pytest.fixture(scope="package")
def assumed_run(tmp_path_factory) -> AssumedRun:
    tmp = tmp_path_factory.mktemp("assumed")
    frames, masks = write_clip(tmp / "clip")
    plate = exr_plate(frames, tmp / "exr")
    run = tmp / "run"
    sets = [x for s in TINY_SET for x in ("--set", s)]
    fit = run_main("fit", plate, "--mask", masks, "--out", run, "--preset", "draft", *sets, "--no-bar")
    assert fit.code == 0, fit.err
    export = run_main("export", run, "--no-bar", "--atlas-size", "64")
    assert export.code == 0, export.err
    return AssumedRun(plate, run, fit.out, fit.err, Path(export.out.splitlines()[-1]))
