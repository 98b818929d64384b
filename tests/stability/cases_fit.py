"""Bad input to ``fit`` beyond the reading of the clip (``bad_inputs.CASES`` has those): config values out of their
range, a resume that would not continue the same fit, run files edited by hand or taken from another run, a run
folder that holds the artist's work, a plate without a number. Each is one line, exit 2, and writes nothing.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from engine import contract as C
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.terms.run_folder import RUN_CLIP, RUN_CONFIG, SCENE_FILE
from tests.stability.bad_inputs import TINY_FIT, Case, _clip, _fit_args, _fitted, _good_clip_with, _resume
from tests.stability.fitcheck import write_sequence


def _set(item: str) -> Callable[[Path], list[str]]:
    return _good_clip_with("--set", item)


def _resume_with(*extra: str) -> Callable[[Path], list[str]]:
    """A finished tiny fit, resumed with ``extra`` (the change under test)."""

    def build(d: Path) -> list[str]:
        _fitted(d)
        return [*_resume(d), *extra]

    return build


def _resume_other_masks(d: Path) -> list[str]:
    _fitted(d)
    shutil.copytree(d / "clip" / "masks", d / "other_masks")
    return [*_resume(d), "--mask", str(d / "other_masks")]


def _resume_other_clip_path(d: Path) -> list[str]:
    _fitted(d)
    shutil.copytree(d / "clip" / "frames", d / "copy_of_frames")
    return [str(d / "copy_of_frames"), *_resume(d)]


def _edited(file: str, edit: Callable[[dict], object]) -> Callable[[Path], list[str]]:
    """A finished tiny fit whose ``file`` was edited by hand (``edit`` changes the decoded JSON), resumed."""

    def build(d: Path) -> list[str]:
        _fitted(d)
        path = d / "run" / file
        data = json.loads(path.read_text())
        replaced = edit(data)
        path.write_text(json.dumps(data if replaced is None else replaced))
        return _resume(d)

    return build


def _exported_without_checkpoint(d: Path) -> list[str]:
    """A fit that was exported (and maybe painted), then its checkpoint and metrics deleted: a plain fit into it
    would have refitted over the artist's exports."""
    frames, masks = _fitted(d)
    export = d / "run" / C.EXPORTS_DIR / "v001"
    export.mkdir(parents=True)
    (export / C.MANIFEST_NAME).write_text("{}")
    (d / "run" / C.RUN_CHECKPOINT).unlink()
    (d / "run" / C.RUN_METRICS).unlink()
    return _fit_args(frames, masks, d)


def _checkpoint_of_another_clip(d: Path) -> list[str]:
    """The checkpoint of another clip's fit copied over this run's."""
    _fitted(d)
    other = d / "other"
    other.mkdir()
    spec = SceneSpec(width=32, height=24, frames=3, fg_size=(12, 10), fg_start=(8.0, 6.0), seed=5)
    frames, masks = write_scene(make_scene(spec), other / "clip")
    _fitted_into(frames, masks, other / "run")
    shutil.copyfile(other / "run" / C.RUN_CHECKPOINT, d / "run" / C.RUN_CHECKPOINT)
    return _resume(d)


def _fitted_into(frames: Path, masks: Path, run: Path) -> None:
    import contextlib
    import io

    from engine import cli

    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        code = cli.main(["fit", str(frames), "--mask", str(masks), "--out", str(run), *TINY_FIT])
    assert code == C.EXIT_OK, code


def _checkpoint_edit(edit: Callable[[dict], None]) -> Callable[[Path], list[str]]:
    """A finished tiny fit whose checkpoint was changed by ``edit`` (a key removed, a tensor of another shape)."""

    def build(d: Path) -> list[str]:
        _fitted(d)
        path = d / "run" / C.RUN_CHECKPOINT
        state = torch.load(path, weights_only=True)
        edit(state)
        torch.save(state, path)
        return _resume(d)

    return build


def _drop_optimiser(state: dict) -> None:
    del state["optim"]


def _reshape_first_weight(state: dict) -> None:
    key = next(iter(state["model"]))
    state["model"][key] = torch.zeros(3, 5)


def _all_nan_clip(d: Path) -> list[str]:
    scene = make_scene(SceneSpec(width=32, height=24, frames=3, fg_size=(12, 10), fg_start=(8.0, 6.0)))
    frames = write_sequence(d / "nan_exr", np.full_like(scene.frames, np.nan), ext="exr", dtype=np.float32)
    return _fit_args(frames, None, d)


def _paper_without_mask(d: Path) -> list[str]:
    frames, _ = _clip(d)
    return [str(frames), "--out", str(d / "run"), *TINY_FIT, "--preset", "paper"]


def _no_out(d: Path) -> list[str]:
    frames, masks = _clip(d)
    return [str(frames), "--mask", str(masks), *TINY_FIT]


CASES: tuple[Case, ...] = (
    Case("set_long_edge_zero", "--set long_edge=0", _set("long_edge=0"), ("long_edge=0", "an int in 16..16384")),
    Case("set_eval_every_zero", "--set eval_every=0", _set("eval_every=0"), ("eval_every=0", "an int >= 1")),
    Case("set_batch_zero", "--set batch=0", _set("batch=0"), ("batch=0", "an int in 1..10000000")),
    Case("set_negative_steps", "--set steps=-1", _set("steps=-1"), ("steps=-1", ">= 1")),
    Case("set_unknown_flow_preset", "--set flow_preset=slow", _set("flow_preset=slow"), ("slow", "medium")),
    Case("set_unknown_model", "--set model=giant", _set("model=giant"), ("giant", "fast, paper")),
    Case("set_unknown_components", "--set components=some", _set("components=some"), ("some", "auto, all")),
    Case("set_nan_learning_rate", "--set lr=nan", _set("lr=nan"), ("lr=nan", "finite")),
    Case("no_run_folder", "fit without --out", _no_out, ("no run folder", "--out"), watch=lambda d: d / "run"),
    Case(
        "paper_model_without_one_mask",
        "--preset paper with no --mask",
        _paper_without_mask,
        ("paper model", "0 --mask folders", "exactly one --mask"),
    ),
    Case("all_nan_clip", "float EXR frames holding only NaN", _all_nan_clip, ("nan_exr", "NaN or Inf", "re-export")),
    Case(
        "refit_with_resume",
        "--resume and --refit together",
        _resume_with("--refit"),
        ("--resume and --refit", "--refit to fit again"),
    ),
    Case(
        "resume_other_masks",
        "--resume with another --mask folder",
        _resume_other_masks,
        ("clip.json", "--mask", "other_masks", "new --out"),
    ),
    Case(
        "resume_other_frames",
        "--resume with another --frames range",
        _resume_with("--frames", "0:1"),
        ("--frames 0:1", "0:2"),
    ),
    Case(
        "resume_other_clip_path",
        "--resume naming a copy of the clip",
        _resume_other_clip_path,
        ("copy_of_frames", "this run fitted"),
    ),
    Case(
        "resume_changes_the_model",
        "--resume --set w_rgb=1",
        _resume_with("--set", "w_rgb=1"),
        ("config.json", "cannot change w_rgb", "steps, lr"),
    ),
    Case(
        "resume_with_another_preset",
        "--resume --preset final",
        _resume_with("--preset", "final"),
        ("--preset final", "draft"),
    ),
    Case(
        "fit_into_an_exported_run",
        "a plain fit into a run with exports whose checkpoint was deleted",
        _exported_without_checkpoint,
        ("already holds a fit (exports/)", "--refit", "new --out"),
    ),
    Case(
        "config_json_not_an_object",
        "--resume of a run whose config.json holds a list",
        _edited(RUN_CONFIG, lambda data: [data]),
        ("config.json", "not a JSON object"),
    ),
    Case(
        "config_json_out_of_range",
        "--resume of a run whose config.json says batch 0",
        _edited(RUN_CONFIG, lambda data: data["config"].update(batch=0)),
        ("config.json", "'batch' must be an int in 1..10000000"),
    ),
    Case(
        "clip_json_wrong_type",
        '--resume of a run whose clip.json says layers "two"',
        _edited(RUN_CLIP, lambda data: data.update(layers="two")),
        ("clip.json", "'layers' is not an int"),
    ),
    Case(
        "scene_json_wrong_value",
        '--resume of a run whose scene.json says background_motion "sideways"',
        _edited(SCENE_FILE, lambda data: data.update(background_motion="sideways")),
        ("scene.json", "sideways"),
    ),
    Case(
        "checkpoint_of_another_clip",
        "--resume with the checkpoint of another clip's fit",
        _checkpoint_of_another_clip,
        ("checkpoint.pt", "another clip", "--refit"),
    ),
    Case(
        "checkpoint_without_optimiser",
        "--resume with a checkpoint missing its optimiser state",
        _checkpoint_edit(_drop_optimiser),
        ("checkpoint.pt", "no 'optim'"),
    ),
    Case(
        "checkpoint_of_another_shape",
        "--resume with a checkpoint whose first weight has another shape",
        _checkpoint_edit(_reshape_first_weight),
        ("checkpoint.pt", "does not fit this run's model", "--refit"),
    ),
)
