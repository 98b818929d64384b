"""What ``fit`` may do to a run folder that already holds a fit, through the real CLI.

- ``--resume`` continues the SAME fit: the clip, masks, scribbles and frames clip.json records, the config
  config.json holds; ``--set`` may change only the schedule (``config.RESUMABLE_FIELDS``), which is recorded in
  config.json. Anything else is one line and the folder stays byte-identical.
- A plain ``fit`` into a folder that holds a fit (a checkpoint, metrics, or non-empty edits/ or exports/) is one
  line; ``--refit`` fits again and keeps edits/ and exports/ byte-identical (SHA-256).
- A checkpoint is checked against the run's other files when loaded: another clip's or another config's is one
  line, for a resume and for an export alike.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil
from pathlib import Path

import pytest
import torch

from engine import contract as C
from engine.config import PRESETS, resume_changes, same_phases
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.errors import InputError
from engine.fit.fitted_run import load_fitted
from engine.fit.run_folder import RunFolder
from engine.loss_terms import loss_weights
from engine.terms.export_names import EDITS_DIR
from engine.terms.run_folder import RUN_CHECKPOINT_SCHEMA, RUN_CHECKPOINT_SCHEMA_WITHOUT_CONFIG, RUN_CONFIG
from tests.engine_cli import run_cli
from tests.folders import tree_digest
from tests.stability.bad_inputs import TINY_FIT

SPEC = SceneSpec(width=32, height=24, frames=3, fg_size=(12, 10), fg_start=(8.0, 6.0))


@pytest.fixture(scope="module")
def fitted(tmp_path_factory) -> tuple[Path, Path, Path]:
    """A finished tiny fit: (frames, masks, run folder). Tests work on copies of the run folder."""
    d = tmp_path_factory.mktemp("resume_checks")
    frames, masks = write_scene(make_scene(SPEC), d / "clip")
    code, lines = run_cli("fit", str(frames), "--mask", str(masks), "--out", str(d / "run"), *TINY_FIT)
    assert code == C.EXIT_OK, lines
    return frames, masks, d / "run"


@pytest.fixture
def run(fitted, tmp_path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(fitted[2], copy)
    return copy


def _refused(run: Path, *argv: str, needles: tuple[str, ...]) -> str:
    """``fit ARGV`` is refused: exit 2, one line holding ``needles``, the run folder byte-identical."""
    before = tree_digest(run)
    code, lines = run_cli("fit", *argv)
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and lines[0].startswith("error: "), lines
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    assert tree_digest(run) == before, "a refused fit changed the run folder"
    return lines[0]


@pytest.mark.parametrize(
    ("extra", "needles"),
    [
        (["--set", "seed=3"], ("cannot change seed (0 -> 3)",)),
        (["--set", "model=paper"], ("cannot change model",)),
        (["--set", "long_edge=24"], ("cannot change long_edge",)),
        (["--frames", "1:2"], ("--frames 1:2", "0:2")),
        (["--refit"], ("--resume and --refit",)),
        (["--preset", "final"], ("--preset final", "draft")),
    ],
)
def test_a_resume_that_would_not_continue_the_same_fit_is_one_line(run, extra, needles):
    _refused(run, "--resume", "--out", str(run), "--no-bar", *extra, needles=needles)


def test_a_resume_with_another_mask_folder_is_refused_not_fitted(run, fitted, tmp_path):
    """A different mask folder used to be fitted silently while clip.json kept naming the old one."""
    other = tmp_path / "other_masks"
    shutil.copytree(fitted[1], other)
    _refused(run, "--resume", "--out", str(run), "--mask", str(other), needles=("--mask", "other_masks", "new --out"))
    _refused(run, "--resume", "--out", str(run), "--scribbles", str(other), needles=("--scribbles", "no scribbles"))


def test_a_resume_naming_the_recorded_inputs_again_is_accepted(run, fitted):
    frames, masks, _ = fitted
    code, lines = run_cli("fit", str(frames), "--mask", str(masks), "--frames", "0:2", "--resume", "--out", str(run))
    assert code == C.EXIT_OK, lines


def test_a_resume_may_change_the_schedule_and_records_it(run):
    """``--resume --set steps=.. lr=..`` continues the fit with the new schedule, written to config.json before
    the next checkpoint (whose own config then says so too)."""
    before = RunFolder(run).read_config()
    code, lines = run_cli("fit", "--resume", "--out", str(run), "--no-bar", "--set", "steps=4", "--set", "lr=5e-4")
    assert code == C.EXIT_OK, lines
    after = RunFolder(run).read_config()
    assert (after.steps, after.lr) == (4, 5e-4) and after.lr_grid == before.lr_grid
    state = torch.load(run / C.RUN_CHECKPOINT, weights_only=True)
    assert state["step"] == 4 and state["config"]["lr"] == 5e-4
    assert json.loads((run / C.RUN_METRICS).read_text())["steps"] == 4


def _sha256(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _with_artist_work(run: Path) -> None:
    """Paint in edits/ (with its history) and an export in exports/: what a refit must never touch."""
    (run / EDITS_DIR / "history").mkdir(parents=True)
    (run / EDITS_DIR / "Foreground.png").write_bytes(b"paint" * 100)
    (run / EDITS_DIR / "history" / "Foreground.1.png").write_bytes(b"older paint")
    (run / C.EXPORTS_DIR / "v001" / "passes").mkdir(parents=True)
    (run / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME).write_text('{"export": 1}')
    (run / C.EXPORTS_DIR / "v001" / "passes" / "atlas.00000.exr").write_bytes(b"\x00" * 4096)


@pytest.mark.parametrize(
    ("keep", "held"),
    [
        ((C.RUN_CHECKPOINT,), "checkpoint.pt"),
        ((C.RUN_METRICS,), "metrics.json"),
        ((EDITS_DIR,), "edits/"),
        ((C.EXPORTS_DIR,), "exports/"),
        ((C.RUN_CHECKPOINT, EDITS_DIR, C.EXPORTS_DIR), "checkpoint.pt, edits/, exports/"),
    ],
)
def test_a_plain_fit_into_a_folder_that_holds_a_fit_is_refused(run, fitted, keep, held):
    """An exported run whose checkpoint was deleted used to be refitted silently: what the folder holds of a fit
    (its checkpoint, metrics, the artist's edits and exports) is named, with the ways out."""
    frames, masks, _ = fitted
    _with_artist_work(run)
    for entry in (C.RUN_CHECKPOINT, C.RUN_METRICS, EDITS_DIR, C.EXPORTS_DIR):
        if entry not in keep:
            path = run / entry
            shutil.rmtree(path) if path.is_dir() else path.unlink()
    _refused(
        run,
        str(frames),
        "--mask",
        str(masks),
        "--out",
        str(run),
        *TINY_FIT,
        needles=(f"already holds a fit ({held})", "--resume", "--refit", "new --out"),
    )


def test_a_fit_stopped_before_its_first_checkpoint_may_be_started_over(run, fitted):
    """Only config, clip record, scene analysis and flow cache (and a dead export's hidden staging folder): no
    fit to lose, so a plain fit starts over (reusing the cached flow)."""
    frames, masks, _ = fitted
    (run / C.RUN_CHECKPOINT).unlink()
    (run / C.RUN_METRICS).unlink()
    (run / C.EXPORTS_DIR / ".v001.partial").mkdir(parents=True)
    assert RunFolder(run).fit_contents() == []
    code, lines = run_cli("fit", str(frames), "--mask", str(masks), "--out", str(run), *TINY_FIT)
    assert code == C.EXIT_OK, lines


def test_refit_replaces_the_fit_and_keeps_edits_and_exports_byte_identical(run, fitted):
    frames, masks, _ = fitted
    _with_artist_work(run)
    artist = {d: _sha256(run / d) for d in (EDITS_DIR, C.EXPORTS_DIR)}
    old = {n: (run / n).read_bytes() for n in (RUN_CONFIG, C.RUN_CHECKPOINT, C.RUN_METRICS)}
    argv = [str(frames), "--mask", str(masks), "--out", str(run), *TINY_FIT, "--set", "steps=3", "--refit"]
    code, lines = run_cli("fit", *argv)
    assert code == C.EXIT_OK, lines
    assert {d: _sha256(run / d) for d in (EDITS_DIR, C.EXPORTS_DIR)} == artist
    assert all((run / n).read_bytes() != data for n, data in old.items())
    assert RunFolder(run).read_config().steps == 3 and RunFolder(run).read_metrics()["steps"] == 3
    assert torch.load(run / C.RUN_CHECKPOINT, weights_only=True)["step"] == 3


def test_a_refused_refit_changes_nothing(run, tmp_path):
    """--refit reads and checks its input before it replaces anything: a missing clip leaves the fit as it was."""
    _with_artist_work(run)
    _refused(run, str(tmp_path / "no_such_clip"), "--out", str(run), *TINY_FIT, "--refit", needles=("does not exist",))


def _another_config_checkpoint(run: Path, fitted: tuple[Path, Path, Path], tmp_path: Path) -> None:
    """Copy over ``run``'s checkpoint that of a fit of the same clip with another weight."""
    frames, masks, _ = fitted
    other = tmp_path / "other"
    code, lines = run_cli("fit", str(frames), "--mask", str(masks), "--out", str(other), *TINY_FIT, "--set", "w_rgb=7")
    assert code == C.EXIT_OK, lines
    shutil.copyfile(other / C.RUN_CHECKPOINT, run / C.RUN_CHECKPOINT)


def test_a_checkpoint_of_another_config_is_refused_by_resume_and_export(run, fitted, tmp_path):
    _another_config_checkpoint(run, fitted, tmp_path)
    _refused(run, "--resume", "--out", str(run), needles=("checkpoint.pt", "another config", "w_rgb 7.0, not 5000.0"))
    with pytest.raises(InputError, match=r"another config than config\.json") as err:
        load_fitted(run)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(
    ("edit", "needle"),
    [
        (lambda s: s["model"].pop(next(iter(s["model"]))), "Missing key"),
        (lambda s: s["model"].update(extra=torch.zeros(2)), "Unexpected key"),
        (lambda s: s.update(motions=[{"to_ref": 1}]), "does not fit this run's model"),
        (lambda s: s.update(gen=torch.zeros(3, dtype=torch.uint8)), "does not fit this run's model"),
        (lambda s: s["optim"].update(param_groups=[]), "does not fit this run's model"),
    ],
)
def test_an_incomplete_checkpoint_is_one_line(run, edit, needle):
    path = run / C.RUN_CHECKPOINT
    state = torch.load(path, weights_only=True)
    edit(state)
    torch.save(state, path)
    line = _refused(run, "--resume", "--out", str(run), needles=("checkpoint.pt", needle, "--refit"))
    assert "Traceback" not in line


def test_a_field_missing_from_config_json_is_refused_when_its_default_is_not_what_was_fitted(run):
    """config.json without ``w_mask_prior`` reads with the default (0), but the fit used the draft preset's 20: the
    checkpoint's own config says so, and the resume is one line instead of a fit with another objective."""
    path = run / RUN_CONFIG
    data = json.loads(path.read_text())
    del data["config"]["w_mask_prior"]
    path.write_text(json.dumps(data))
    _refused(run, "--resume", "--out", str(run), needles=("another config", "w_mask_prior 20.0, not 0.0"))


def test_a_checkpoint_from_before_configs_were_recorded_still_exports_and_resumes(run):
    """A fit made when checkpoints did not record their config (schema 1) is not lost: it exports, and it
    resumes (the checkpoint it then saves records the config)."""
    import torch

    path = run / C.RUN_CHECKPOINT
    state = torch.load(path, map_location="cpu", weights_only=True)
    del state["config"]
    state["schema"] = RUN_CHECKPOINT_SCHEMA_WITHOUT_CONFIG
    torch.save(state, path)
    code, lines = run_cli("export", str(run), "--atlas-size", "32", "--no-bar")
    assert code == C.EXIT_OK, lines
    code, lines = run_cli("fit", "--resume", "--out", str(run), "--no-bar", "--set", "steps=4")
    assert code == C.EXIT_OK, lines
    saved = torch.load(path, map_location="cpu", weights_only=True)
    assert saved["schema"] == RUN_CHECKPOINT_SCHEMA and isinstance(saved["config"], dict)


@pytest.mark.parametrize(("bootstrap", "after"), [(2, 5), (1, 1)])
def test_a_refine_keeps_the_masks_held_when_the_fit_held_them_to_its_last_step(fitted, tmp_path, bootstrap, after):
    """``fit --refine 3`` of a 2-step fit: a mask bootstrap that lasted the whole fit (2 of 2 steps, as `draft` and
    `balanced` fit) lasts the whole refine (5 of 5, in config.json and in the checkpoint, the mask term on at its
    last step); one the fit was past (1 of 2) stays where it ended. A ``--resume`` of the refined fit accepts both."""
    frames, masks, _ = fitted
    run = tmp_path / "run"
    argv = ("fit", str(frames), "--mask", str(masks), "--out", str(run), *TINY_FIT)
    assert run_cli(*argv, "--set", f"bootstrap_steps={bootstrap}")[0] == C.EXIT_OK
    code, lines = run_cli("fit", "--out", str(run), C.FIT_REFINE_FLAG, "3", "--no-bar")
    assert code == C.EXIT_OK, lines
    cfg = RunFolder(run).read_config()
    assert (cfg.steps, cfg.bootstrap_steps, cfg.global_rigidity_steps) == (
        5,
        after,
        PRESETS["draft"].global_rigidity_steps,
    )
    assert (loss_weights(cfg, 4)["mask"] > 0) == (after == 5)
    state = torch.load(run / C.RUN_CHECKPOINT, weights_only=True)
    assert (state["step"], state["config"]["bootstrap_steps"]) == (5, after)
    code, lines = run_cli("fit", "--resume", "--out", str(run), "--no-bar", "--set", "steps=6")
    assert code == C.EXIT_OK, lines
    assert RunFolder(run).read_config().bootstrap_steps == (6 if after == 5 else 1)  # a resume's new steps likewise
    by_hand = ("--set", "steps=7", "--set", "bootstrap_steps=6")
    code, lines = run_cli("fit", "--resume", "--out", str(run), "--no-bar", *by_hand)
    if after == 5:  # a phase given by hand is not moved on (here it ends where it ended: a change a resume may make)
        assert code == C.EXIT_OK and RunFolder(run).read_config().bootstrap_steps == 6, lines
    else:  # 1 -> 6 changes what the fit computes
        assert code == C.EXIT_BAD_INPUT and "bootstrap_steps" in lines[0], lines


def test_only_a_phase_that_lasts_both_fits_may_move_on_a_resume():
    """``resume_changes``: a loss phase moved with the steps so that it lasts the whole fit before and after is the
    same phase; moved anywhere else it changes what the fit computes and is refused."""
    held = dataclasses.replace(PRESETS["draft"], steps=800, bootstrap_steps=800)
    assert resume_changes(held, dataclasses.replace(held, steps=1800, bootstrap_steps=1800)) == (
        ["steps", "bootstrap_steps"],
        [],
    )
    assert resume_changes(held, dataclasses.replace(held, steps=1800, bootstrap_steps=5000)) == (
        ["steps", "bootstrap_steps"],
        [],
    )
    assert resume_changes(held, dataclasses.replace(held, steps=1800, bootstrap_steps=1000))[1] == ["bootstrap_steps"]
    released = dataclasses.replace(held, bootstrap_steps=300)
    assert resume_changes(released, dataclasses.replace(released, steps=1800, bootstrap_steps=1800))[1] == [
        "bootstrap_steps"
    ]
    assert not same_phases({"steps": 10, "w_rgb": 1.0}, {"steps": 20, "w_rgb": 2.0}, "w_rgb")
