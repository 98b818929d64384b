"""A fit that diverges stops in one line, and plates that would make it diverge or make its PSNR meaningless are
repaired and reported.

Every step checks its loss before the backward pass (NaN/Inf coordinates crash grid_sample's CPU backward: the
process used to die with a segfault, exit 139, no message), its gradients before the optimiser steps and its
parameters after; a checkpoint holding NaN/Inf is never written. A divergence is ``FitDiverged``: exit 4, one line
naming the step, what went non-finite, the likely cause and the command that continues from the last good
checkpoint with a lower rate, which then finishes.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from engine import cli
from engine import contract as C
from engine.config import apply_overrides, preset_config
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.errors import FitDiverged
from engine.fit import trainer
from engine.fit.checkpoint import nonfinite_entries
from engine.fit.fit_inputs import FitInputs
from engine.fit.prepare import PLATE_VALUE_LIMIT, prepare_clip, to_fitting_values
from engine.fit.run_folder import RunFolder
from engine.io.colour import BUILTIN_CONFIG, SCENE_LINEAR, legacy_linear_to_srgb, to_working
from engine.terms.cli import EXIT_DIVERGED
from tests.engine.fit_helpers import quiet_fit
from tests.paths import ROOT
from tests.stability.fitcheck import write_masks, write_sequence

SPEC = SceneSpec(width=48, height=32, frames=4, fg_size=(16, 12), fg_start=(10.0, 8.0))
STEPS = 40
SETS = [f"steps={STEPS}", "batch=256", "eval_pixels=500", "bootstrap_steps=10", "global_rigidity_steps=5"]
#: Seconds a child may take (it takes a few).
TIMEOUT_S = 600
CPU = torch.device("cpu")


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> tuple[Path, Path]:
    return write_scene(make_scene(SPEC), tmp_path_factory.mktemp("divergence") / "clip")


def _engine(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "engine", *argv], cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT_S
    )


@pytest.mark.slow
def test_a_huge_learning_rate_exits_4_in_one_line_and_resume_with_a_lower_one_finishes(tmp_path, clip):
    frames, masks = clip
    run = tmp_path / "run"
    sets = [a for s in [*SETS, "lr=1e8"] for a in ("--set", s)]
    out = _engine("fit", str(frames), "--mask", str(masks), "--out", str(run), "--preset", "draft", "--no-bar", *sets)
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert out.returncode == EXIT_DIVERGED, (out.returncode, out.stderr)  # not 139 / -11: no segfault
    assert len(lines) == 1 and lines[0].startswith(f"error: {run}: the fit diverged at step "), out.stderr
    for needle in ("became NaN/Inf", "lr=1e+08", "extreme values in the plate", "the last good one"):
        assert needle in lines[0], (needle, lines[0])
    command = lines[0].split("with a lower rate: ", 1)[1]
    assert command == f"python -m engine fit --resume --out {run} --set lr=0.001", command
    errors = [m for m in map(C.parse_progress_line, out.stdout.splitlines()) if m and m["event"] == C.EVENT_ERROR]
    assert len(errors) == 1 and errors[0]["message"] == lines[0][len("error: ") :]

    # the checkpoint is the last good one: finite, before the step that diverged; no metrics
    state = RunFolder(run).load_checkpoint(CPU)
    diverged_at = int(lines[0].split("diverged at step ", 1)[1].split(":", 1)[0])
    assert state["step"] < diverged_at and not nonfinite_entries(state)
    assert f"keeps step {state['step']}," in lines[0]
    assert not (run / C.RUN_METRICS).exists()

    resumed = _engine(*command.split()[3:], "--no-bar")  # the command the message gives, as it is
    assert resumed.returncode == C.EXIT_OK, resumed.stderr
    metrics = json.loads((run / C.RUN_METRICS).read_text())
    assert metrics["steps"] == STEPS and math.isfinite(metrics["psnr"])
    assert RunFolder(run).read_config().lr == 1e-3


def _trainer(clip: tuple[Path, Path], tmp_path: Path, **overrides: str) -> trainer.Trainer:
    frames, masks = clip
    cfg = apply_overrides(preset_config("draft"), {"batch": "256", **overrides})
    prepared = prepare_clip(FitInputs(frames, [masks]), cfg, tmp_path / "run")
    return trainer.Trainer(cfg, prepared, prepared.analyse(cfg), CPU)


def _weights(model: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


def _same(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


class _NoBackward(torch.autograd.Function):
    """NaN forward; a backward that fails the test if it is ever reached."""

    @staticmethod
    def forward(ctx, x):  # type: ignore[no-untyped-def]
        return x * float("nan")

    @staticmethod
    def backward(ctx, grad):  # type: ignore[no-untyped-def]
        raise AssertionError("backward ran on a non-finite loss")


def test_a_non_finite_loss_stops_before_its_backward_pass(tmp_path, clip, monkeypatch):
    tr = _trainer(clip, tmp_path)
    tr.optimise(0)
    before = _weights(tr.model)
    real = trainer.compute_losses

    def losses(*args):  # type: ignore[no-untyped-def]
        loss, terms = real(*args)
        return _NoBackward.apply(loss), {**terms, "flow": terms["flow"] * float("inf")}

    monkeypatch.setattr(trainer, "compute_losses", losses)
    with pytest.raises(trainer.NonFinite) as err:
        tr.optimise(1)
    assert (err.value.step, err.value.quantity) == (2, "loss") and "flow" in err.value.where
    assert _same(before, _weights(tr.model))


def test_non_finite_gradients_never_reach_the_optimiser(tmp_path, clip):
    tr = _trainer(clip, tmp_path)
    tr.optimise(0)
    before, adam = _weights(tr.model), [s["step"].clone() for s in tr.optim.state.values()]
    grid = tr.optim.param_groups[0]["params"][0]
    grid.register_hook(lambda g: torch.full_like(g, float("nan")))
    with pytest.raises(trainer.NonFinite) as err:
        tr.optimise(1)
    assert (err.value.quantity, err.value.where) == ("gradients", [tr.optim.param_groups[0]["name"]])
    assert _same(before, _weights(tr.model))  # no step was taken
    assert all(torch.equal(a, s["step"]) for a, s in zip(adam, tr.optim.state.values(), strict=True))


def test_non_finite_parameters_after_a_step_are_caught_at_that_step(tmp_path, clip):
    tr = _trainer(clip, tmp_path)
    mappings = next(g for g in tr.optim.param_groups if g["name"] == "mappings")
    tr.optim.register_step_post_hook(lambda opt, a, k: mappings["params"][0].data.fill_(float("inf")))
    with pytest.raises(trainer.NonFinite) as err:
        tr.optimise(0)
    assert (err.value.step, err.value.quantity, err.value.where) == (1, "parameters", ["mappings"])


def test_a_checkpoint_holding_nan_is_never_written(tmp_path, clip, monkeypatch):
    """A fit that checkpoints every step and whose parameters go NaN at step 6: FitDiverged naming step 6, and
    the checkpoint on disk is step 5's, finite."""
    frames, masks = clip
    real_optimizer = trainer.make_optimizer

    def optimizer(model, cfg, device):  # type: ignore[no-untyped-def]
        opt = real_optimizer(model, cfg, device)
        steps = [0]

        def poison(o, args, kwargs):  # type: ignore[no-untyped-def]
            steps[0] += 1
            if steps[0] == 6:
                o.param_groups[0]["params"][0].data[0] = float("nan")

        opt.register_step_post_hook(poison)
        return opt

    monkeypatch.setattr(trainer, "make_optimizer", optimizer)
    cfg = apply_overrides(preset_config("draft"), {"steps": "10", "batch": "128", "checkpoint_seconds": "0"})
    run = tmp_path / "run"
    stream = io.StringIO()
    with pytest.raises(FitDiverged, match="diverged at step 6: the parameters") as err:
        quiet_fit(run, cfg, FitInputs(frames, [masks]), stream)
    assert "keeps step 5, the last good one" in str(err.value) and "\n" not in str(err.value)
    state = RunFolder(run).load_checkpoint(CPU)  # loads: nothing non-finite in it
    assert state["step"] == 5 and not nonfinite_entries(state)

    tr = _trainer(clip, tmp_path)
    tr.model.state_dict()[next(iter(tr.model.state_dict()))].fill_(float("nan"))
    before = (run / C.RUN_CHECKPOINT).read_bytes()
    with pytest.raises(trainer.NonFinite, match="checkpoint's values"):
        tr.save(RunFolder(run), trainer.Reporter.null())
    assert (run / C.RUN_CHECKPOINT).read_bytes() == before


def test_the_finite_checks_do_not_change_the_maths(tmp_path, clip, monkeypatch):
    """The same fit with the checks and with them switched off: identical weights and PSNR (they only read)."""
    frames, masks = clip
    cfg = apply_overrides(preset_config("draft"), {"steps": "12", "batch": "256", "eval_pixels": "500"})

    def run_fit(name: str) -> tuple[float, dict[str, torch.Tensor]]:
        run = tmp_path / name
        metrics = quiet_fit(run, cfg, FitInputs(frames, [masks]))
        return metrics["psnr"], RunFolder(run).load_checkpoint(CPU)["model"]

    checked = run_fit("checked")
    monkeypatch.setattr(trainer, "require_finite", lambda ok, step, quantity, where: None)
    unchecked = run_fit("unchecked")
    assert checked[0] == unchecked[0] and _same(checked[1], unchecked[1])


# --- plates the fit must not take silently ---------------------------------------------------------------------


def _exr_clip(folder: Path, poke: float | None) -> tuple[Path, Path]:
    """The test scene as float EXR (linear) frames; ``poke``: one pixel of frame 1 set to it."""
    scene = make_scene(SPEC)
    pixels = scene.frames.copy()
    if poke is not None:
        pixels[1, 5, 7, 0] = poke
    return write_sequence(folder / "exr", pixels, ext="exr", dtype=np.float32), write_masks(folder / "m", scene.masks)


def _fit_cli(frames: Path, masks: Path, run: Path) -> tuple[dict, list[str]]:
    err = io.StringIO()
    sets = [a for s in SETS for a in ("--set", s)]
    argv = ["fit", str(frames), "--mask", str(masks), "--out", str(run), "--preset", "draft", "--no-bar", *sets]
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        assert cli.main(argv) == C.EXIT_OK, err.getvalue()
    return json.loads((run / C.RUN_METRICS).read_text()), err.getvalue().splitlines()


def test_one_absurd_pixel_is_clamped_reported_and_cannot_decide_the_psnr(tmp_path):
    """One pixel of 1e30 in a float EXR used to drag the full-frame PSNR to about -212 dB: it is clamped to
    PLATE_VALUE_LIMIT, named in one warning line, and the PSNR (against the objective's target range) stays within
    a fraction of a dB of the same plate without it."""
    clean, _ = _fit_cli(*_exr_clip(tmp_path / "clean", None), tmp_path / "run_clean")
    poked, lines = _fit_cli(*_exr_clip(tmp_path / "poked", 1e30), tmp_path / "run_poked")
    warnings = [ln for ln in lines if ln.startswith("warning:")]
    assert warnings == [
        f"warning: values beyond +-{PLATE_VALUE_LIMIT:g} clamped in frames [1] of {tmp_path / 'poked' / 'exr'}"
    ]
    print(f"\nPSNR clean {clean['psnr']:.3f} dB, with one 1e30 pixel {poked['psnr']:.3f} dB")
    assert abs(poked["psnr"] - clean["psnr"]) < 0.5, (poked["psnr"], clean["psnr"])


def test_plate_values_within_the_limit_are_unchanged_bit_for_bit():
    """8-bit plates (and HDR values up to the limit) are what they were before the clamp existed: the values
    the fit sees are those of ``nan_to_num`` and the sRGB encoding alone."""
    rng = np.random.default_rng(0)
    eight_bit = (rng.integers(0, 256, (3, 6, 8, 3)) / 255.0).astype(np.float32)
    out, faults = to_fitting_values(eight_bit, "sRGB")
    assert out.tobytes() == eight_bit.tobytes() and faults.nonfinite == faults.absurd == []
    hdr = np.float32(rng.uniform(0.0, 5000.0, (2, 4, 4, 3)))
    hdr[0, 0, 0] = PLATE_VALUE_LIMIT
    out, faults = to_fitting_values(hdr, "linear")  # a run recorded before colour management: its own curve
    assert out.tobytes() == legacy_linear_to_srgb(hdr).astype(np.float32).tobytes() and faults.absurd == []
    out, faults = to_fitting_values(hdr, SCENE_LINEAR, colour_config=BUILTIN_CONFIG)  # the OCIO encoding alone
    want = np.clip(to_working(hdr, SCENE_LINEAR, BUILTIN_CONFIG), 0.0, None).astype(np.float32)
    assert out.tobytes() == want.tobytes() and faults.absurd == []
    hdr[1, 2, 2, 1] = -1e31
    _, faults = to_fitting_values(hdr, "linear")
    assert faults.absurd == [1]


def test_a_clip_longer_than_its_batch_is_for_draws_a_larger_batch_every_step(clip, tmp_path, monkeypatch):
    """A long tiny clip: with ``batch_frames`` shorter than the clip, the trainer's step (and the ETA's cost probe)
    samples ``step_batch(frames)`` pixels, grown in proportion; at the clip's own length, the batch as given."""
    drawn: list[int] = []
    real = trainer.sample_batch

    def counting(video, n, *args):  # type: ignore[no-untyped-def]
        drawn.append(n)
        return real(video, n, *args)

    monkeypatch.setattr(trainer, "sample_batch", counting)
    frames = SPEC.frames
    for batch_frames, expected in ((frames // 4, 256 * 4), (frames, 256)):
        drawn.clear()
        tr = _trainer(clip, tmp_path / str(batch_frames), batch_frames=str(batch_frames))
        tr.optimise(0)
        assert drawn == [expected] and tr.cfg.step_batch(frames) == expected
