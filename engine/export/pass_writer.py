"""An export's pass files: each frame's UV + alpha channels evaluated at every native pixel, with the bits the
export keeps, written one file per frame while the next frame is evaluated.

Why a module of its own: this is where an export spends its time and memory at 2K-4K (the networks at every native
pixel, then OpenEXR's compression), and where both are bounded: one frame evaluated (in chunks, ``sampling``) while
at most ``PASS_WRITE_AHEAD`` frames are written (``io.write_ahead``).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .. import contract as C
from ..fit.fitted_run import FittedRun
from ..fit.progress import Reporter
from ..fit.run_folder import ClipRecord
from ..io.colour import RAW
from ..io.images import exr_timing, write_exr
from ..io.write_ahead import FRAMES_AHEAD, WriteAhead
from ..terms import export_names as E
from ..terms.colour import EXR_COLORSPACE_ATTRIBUTE
from ..terms.export_names import ALPHA_CHANNELS, STMAP_CHANNELS, stmap_channel_name
from .pass_files import kept_precision, pass_file, stmap_values
from .plan import Plan
from .sampling import eval_pixels, pixel_grid

#: Pass files written by a second thread while the next frame is evaluated (OpenEXR compresses and writes without
#: Python's lock): at most this many frames wait to be written, so memory holds at most one more frame of channels.
#: 0: every frame written before the next is evaluated (``bench export-cost --compare write-ahead`` measures both).
PASS_WRITE_AHEAD = FRAMES_AHEAD


def write_passes(
    reporter: Reporter,
    fitted: FittedRun,
    plan: Plan,
    todo: list[int],
    dest: Path,
    bar: Any,
    written: Any = None,
    corrections: dict[int, np.ndarray] | None = None,
) -> None:
    """The UV + alpha passes of the run frames ``todo`` at native resolution into ``dest/passes``, each file
    atomic (a frame's pass exists whole or not at all); ``written(path)`` is told of each, and the progress, once
    its file is complete. ``corrections`` (``_flow_corrections``) are added, upsampled, to their layers' UV. A frame
    is written while the next is evaluated (``PASS_WRITE_AHEAD``, ``io.write_ahead``)."""
    corrections = corrections or {}
    clip = fitted.clip
    reporter.emit(C.EVENT_STAGE, stage="passes", message=f"{len(todo)} frames of UV + alpha passes")
    frame_numbers = list(clip.frame_numbers)
    grid = pixel_grid(clip.native_size, _native_scale(clip), next(fitted.model.parameters()).device)
    started = time.perf_counter()

    def finish(k: int, path: Path) -> None:
        if written is not None:
            written(path)
        bar.update(1)
        reporter.emit(C.EVENT_PROGRESS, step=k + 1, total=len(todo), psnr=None, elapsed=None, eta=None)
        # the export's own whole job (a fit's reader places it after the fit's share): its frames, at their rate
        left = (time.perf_counter() - started) / (k + 1) * (len(todo) - k - 1)
        fraction = round((k + 1) / len(todo), 4)
        reporter.emit(
            C.EVENT_JOB,
            stage="export",
            done=k + 1,
            total=len(todo),
            stage_eta=round(left, 1),
            job_fraction=fraction,
            job_eta=round(left, 1),
        )

    with WriteAhead[Path](PASS_WRITE_AHEAD, finish, "passes") as writer:
        for k, t in enumerate(todo):
            chans = _frame_channels(fitted, plan, grid, t, corrections)
            timing = exr_timing(clip.rate, clip.pixel_aspect, clip.timecode, frame_numbers[t] - frame_numbers[0])
            tags = {EXR_COLORSPACE_ATTRIBUTE: RAW, **timing}  # data, with the plate's timing
            writer.submit(k, write_exr, pass_file(dest, frame_numbers[t], clip), chans, attributes=tags)
            del chans  # the writer holds the frame's channels until its file is written


def _native_scale(clip: ClipRecord) -> tuple[float, float]:
    """Working pixels per native pixel, per axis: native pixel centres in the networks' coordinates."""
    (nw, nh), (ww, wh) = clip.native_size, clip.working_size
    return ww / nw, wh / nh


def _frame_channels(
    fitted: FittedRun, plan: Plan, grid: Any, t: int, corrections: dict[int, np.ndarray]
) -> dict[str, np.ndarray]:
    """Run frame ``t``'s pass channels at native resolution (``grid``: its pixel centres, ``pixel_grid``), with the
    bits ``plan.precision`` keeps and, where ``plan.stmap`` says so, each layer's STMap copy."""
    nw, nh = fitted.clip.native_size
    uvs, wts = eval_pixels(fitted.model, grid, t)
    chans: dict[str, np.ndarray] = {}
    for i, name in enumerate(plan.names):
        uv = uvs[i]
        if i in corrections:  # working size -> native, pixel centres on pixel centres
            uv = uv + cv2.resize(corrections[i][t], (nw, nh), interpolation=cv2.INTER_LINEAR).reshape(-1, 2)
        tex_uv, inside = plan.frames_by_layer[i].to_texture_uv(uv)
        a = wts[:, i]
        uv_pass, alpha_pass = E.uv_pass(name), E.alpha_pass(name)
        u_name, v_name, coverage_name = (C.channel_name(uv_pass, c) for c in C.UV_CHANNELS)
        kept = kept_precision(tex_uv[:, 0], tex_uv[:, 1], a * inside, a, plan.precision)
        chans[u_name], chans[v_name], chans[coverage_name] = (x.reshape(nh, nw) for x in kept[:3])
        chans[C.channel_name(alpha_pass, ALPHA_CHANNELS[0])] = kept[3].reshape(nh, nw)
        if plan.stmap:
            for channel, values in zip(STMAP_CHANNELS, stmap_values(chans, uv_pass), strict=True):
                chans[stmap_channel_name(name, channel)] = values
    return chans


__all__ = ["PASS_WRITE_AHEAD", "write_passes"]
