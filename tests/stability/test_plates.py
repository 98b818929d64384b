"""Plates in every encoding a compositor hands over: HDR linear EXR (values up to 50, negatives), EXR with
NaN/Inf pixels (sanitised with a warning naming the frames), 16-bit PNG, greyscale and RGBA.

Each is fitted on the short schedule with every loss term, gradient and parameter checked finite
(``monitored_fit``); each also checks the values the model fits (``prepared.frames``) are the plate's.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from engine import contract as C
from engine.config import apply_overrides, preset_config
from engine.data.synthetic import SceneSpec, make_scene
from engine.fit.evaluation import render_frame
from engine.fit.model_build import build_model
from engine.model.losses import psnr_from_mse
from engine.terms.colour import COLOUR_BUILTIN_CONFIG
from engine.terms.run_folder import RUN_CLIP
from tests.stability.fitcheck import QUICK, monitored_fit, write_masks, write_sequence

SPEC = SceneSpec(width=48, height=32, frames=3, fg_size=(16, 12), fg_start=(10.0, 8.0))
MIN_GAIN_DB = 0.2


def _srgb_to_linear(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _linear_to_srgb(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, None)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055).astype(np.float32)


def _reachable_psnr(model, prepared) -> float:
    target = np.clip(prepared.frames, 0.0, 1.0)
    sq = [(render_frame(model, t, prepared.size, torch.device("cpu"))[0] - target[t]) ** 2 for t in range(len(target))]
    return psnr_from_mse(float(np.mean(sq)))


def _initial_model(mon):  # type: ignore[no-untyped-def]
    cfg = apply_overrides(preset_config("draft"), QUICK)
    torch.manual_seed(cfg.seed)
    return build_model(cfg, mon.prepared)


@pytest.mark.parametrize("kind", ["png16", "greyscale", "rgba"])
def test_integer_plates_16bit_grey_rgba(tmp_path, monkeypatch, kind):
    """Values read back within one code value of what was written; grey replicated; RGBA's alpha (half
    transparent over the object) dropped without premultiplying the colour."""
    scene = make_scene(SPEC)
    if kind == "png16":
        frames = write_sequence(tmp_path / "frames", scene.frames, dtype=np.uint16)
        expected, tol = scene.frames, 1.0 / 65535
    elif kind == "greyscale":
        grey = scene.frames.mean(-1, keepdims=True)
        frames = write_sequence(tmp_path / "frames", grey)
        expected, tol = np.repeat(grey, 3, -1), 0.5 / 255 + 1e-6
    else:
        alpha = np.where(scene.masks, 0.5, 1.0)[..., None].astype(np.float32)
        frames = write_sequence(tmp_path / "frames", np.concatenate((scene.frames, alpha), -1))
        expected, tol = scene.frames, 0.5 / 255 + 1e-6
    masks = write_masks(tmp_path / "masks", scene.masks)
    _, mon = monitored_fit(monkeypatch, frames, [masks], tmp_path / "run")
    assert np.abs(mon.prepared.frames - expected).max() <= tol
    assert mon.psnr_gain > MIN_GAIN_DB


def test_hdr_linear_exr_plate_up_to_50_with_negatives(tmp_path, monkeypatch):
    """A float EXR plate is scene-linear: highlights up to 50 and negative pixels (a denoiser's undershoot).
    The model fits display-encoded values (negatives clipped to 0, sRGB curve, so 50 -> 5.33); the atlas
    colours are in [0, 1], so highlights above display white are reconstructed as white: every loss and
    gradient stays finite and the fit still improves."""
    scene = make_scene(SPEC)
    lin = _srgb_to_linear(scene.frames)
    lin[:, 2:6, 2:10] = 50.0  # a specular highlight
    lin[:, -6:-2, -10:-2] = -0.25  # undershoot
    frames = write_sequence(tmp_path / "frames", lin, ext="exr", dtype=np.float32)
    masks = write_masks(tmp_path / "masks", scene.masks)
    _, mon = monitored_fit(monkeypatch, frames, [masks], tmp_path / "run")
    record = json.loads((tmp_path / "run" / RUN_CLIP).read_text())
    assert (record["colorspace"], record["colour_config"]) == (C.COLOUR_SCENE_LINEAR, COLOUR_BUILTIN_CONFIG)
    fitted = mon.prepared.frames
    assert np.isfinite(fitted).all() and fitted.min() >= 0.0
    # encoded by OCIO's sRGB curve (float32 approximation of the IEC formula: relative 3e-5 at most)
    assert np.allclose(fitted, _linear_to_srgb(lin), rtol=3e-5, atol=1e-5)
    assert fitted.max() == pytest.approx(float(_linear_to_srgb(np.float32(50.0))), rel=3e-5)
    # the fit improves where it can (the plate clamped to [0, 1], the objective's TARGET_RANGE): compared
    # with the same model at initialisation (same seed), not with the plate's unreachable highlights
    assert _reachable_psnr(mon.model, mon.prepared) > _reachable_psnr(_initial_model(mon), mon.prepared) + MIN_GAIN_DB


def test_nan_and_inf_plate_is_sanitised_with_a_warning_naming_the_frames(tmp_path, monkeypatch, capsys):
    """NaN in frame 1, +Inf and -Inf in frame 2 of a linear EXR: one warning line names frames [1, 2] and the
    clip; NaN and -Inf become 0, +Inf becomes 1 (display white); the fit never sees a non-finite value."""
    scene = make_scene(SPEC)
    lin = _srgb_to_linear(scene.frames)
    lin[1, 5, 5] = np.nan
    lin[1, 10:12, 20:30] = np.nan
    lin[2, 3, 7] = np.inf
    lin[2, 4, 7] = -np.inf
    frames = write_sequence(tmp_path / "frames", lin, ext="exr", dtype=np.float32)
    masks = write_masks(tmp_path / "masks", scene.masks)
    _, mon = monitored_fit(monkeypatch, frames, [masks], tmp_path / "run")
    err = capsys.readouterr().err
    warnings = [ln for ln in err.splitlines() if ln.startswith("warning:")]
    assert len(warnings) == 1 and "frames [1, 2]" in warnings[0] and str(frames) in warnings[0], err
    fitted = mon.prepared.frames
    assert np.isfinite(fitted).all()
    assert fitted[1, 5, 5].tolist() == [0.0, 0.0, 0.0] and fitted[2, 4, 7].tolist() == [0.0, 0.0, 0.0]
    assert np.allclose(fitted[2, 3, 7], 1.0, atol=1e-6)  # display white (the sRGB curve's 1.0 in float32)
    assert mon.psnr_gain > MIN_GAIN_DB
