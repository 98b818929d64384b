"""Every bad input a verb can meet, as cases run through the real CLI (``engine.cli.main``).

Each case builds its input in a fresh folder and returns the argv. ``run_case`` runs it in-process and
returns the exit code, the stderr text and what changed on disk. The fit verb's cases are here; the other
areas' cases live in ``tests/stability/cases_*.py`` (each a ``CASES`` tuple of ``Case``), collected by
``all_cases``. The table of messages in docs/robustness.md is generated from these real outputs (and a test
checks it stays in sync):

    .venv/bin/python -m tests.stability.bad_inputs      # prints the markdown table
"""

from __future__ import annotations

import contextlib
import importlib
import io
import json
import os
import sys
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from engine import cli
from engine import contract as C
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.terms.run_folder import RUN_CONFIG
from tests.folders import tree_digest
from tests.media_files import write_audio_only_movie, write_image
from tests.stability.fitcheck import write_masks, write_sequence

#: Where the folders of a case live in the messages of the docs table.
PLACEHOLDER = "<dir>"
SPEC = SceneSpec(width=32, height=24, frames=3, fg_size=(12, 10), fg_start=(8.0, 6.0))
TINY_FIT = ["--preset", "draft", "--no-bar", "--set", "steps=2", "--set", "batch=64", "--set", "eval_pixels=256"]


@dataclass(frozen=True)
class Case:
    id: str
    what: str
    build: Callable[[Path], list[str]]
    """Creates the input under the folder and returns the argv after ``fit`` (always with --out <dir>/run)."""
    names: tuple[str, ...]
    """Text the one-line message must contain (the offending file, the fix)."""
    verb: str = C.VERB_FIT
    """The verb the argv is given to."""
    exit: int = C.EXIT_BAD_INPUT
    """The exit code the case must give."""
    watch: Callable[[Path], Path] | None = None
    """The folder that must stay byte-identical (or not be created) given the case's folder; default: the
    argv's --out."""
    env: Callable[[Path], dict[str, str]] | None = None
    """Environment variables the command runs with (``$OCIO``), given the case's folder; restored after it."""


def _clip(d: Path) -> tuple[Path, Path]:
    return write_scene(make_scene(SPEC), d / "clip")


def _fit_args(frames: Path, masks: Path | None, d: Path, *extra: str) -> list[str]:
    return [str(frames), *(["--mask", str(masks)] if masks else []), "--out", str(d / "run"), *TINY_FIT, *extra]


def _missing_clip(d: Path) -> list[str]:
    return _fit_args(d / "no_such_frames", None, d)


def _corrupt_png(d: Path) -> list[str]:
    frames, masks = _clip(d)
    data = (frames / "00001.png").read_bytes()
    (frames / "00001.png").write_bytes(data[: len(data) // 2])
    return _fit_args(frames, masks, d)


def _corrupt_jpeg(d: Path) -> list[str]:
    scene = make_scene(SPEC)
    frames = write_sequence(d / "jpg", scene.frames, ext="jpg")
    (frames / "00000.jpg").write_bytes(b"\xff\xd8\xff\xe0 this is not a jpeg")
    return _fit_args(frames, write_masks(d / "masks", scene.masks), d)


def _corrupt_exr(d: Path) -> list[str]:
    scene = make_scene(SPEC)
    frames = write_sequence(d / "exr", scene.frames, ext="exr", dtype=np.float32)
    data = (frames / "00002.exr").read_bytes()
    (frames / "00002.exr").write_bytes(data[: len(data) // 2])
    return _fit_args(frames, write_masks(d / "masks", scene.masks), d)


def _gap(d: Path) -> list[str]:
    frames, _ = _clip(d)
    (frames / "00001.png").unlink()
    return _fit_args(frames, None, d)


def _sizes(d: Path) -> list[str]:
    frames, masks = _clip(d)
    write_image(frames / "00002.png", np.zeros((20, 32, 3), np.uint8))
    return _fit_args(frames, masks, d)


def _mask_count(d: Path) -> list[str]:
    frames, masks = _clip(d)
    (masks / "00002.png").unlink()
    (masks / "00001.png").rename(masks / "00007.png")
    return _fit_args(frames, masks, d)


def _mask_size(d: Path) -> list[str]:
    frames, masks = _clip(d)
    for p in masks.iterdir():
        write_image(p, np.zeros((24, 40), np.uint8))
    return _fit_args(frames, masks, d)


def _empty_masks(d: Path) -> list[str]:
    frames, _ = _clip(d)
    (d / "empty_masks").mkdir()
    return _fit_args(frames, d / "empty_masks", d)


def _missing_masks(d: Path) -> list[str]:
    frames, _ = _clip(d)
    return _fit_args(frames, d / "no_such_masks", d)


def _no_video_stream(d: Path) -> list[str]:
    return _fit_args(write_audio_only_movie(d / "sound.mp4"), None, d)


def _good_clip_with(*option: str) -> Callable[[Path], list[str]]:
    """A good clip and masks, fitted with ``option`` added last (the bad one under test)."""

    def build(d: Path) -> list[str]:
        frames, masks = _clip(d)
        return _fit_args(frames, masks, d, *option)

    return build


def _not_writable(d: Path) -> list[str]:
    frames, masks = _clip(d)
    (d / "a_file").write_text("not a folder")
    return [str(frames), "--mask", str(masks), "--out", str(d / "a_file" / "run"), *TINY_FIT]


def _fitted(d: Path) -> tuple[Path, Path]:
    frames, masks = _clip(d)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        code = cli.main(["fit", *_fit_args(frames, masks, d)])
    assert code == C.EXIT_OK, code
    return frames, masks


def _resume(d: Path) -> list[str]:
    return ["--resume", "--out", str(d / "run"), "--no-bar"]


def _old_schema(d: Path) -> list[str]:
    _fitted(d)
    cfg = d / "run" / RUN_CONFIG
    data = json.loads(cfg.read_text())
    data["schema"] = 0
    cfg.write_text(json.dumps(data))
    return _resume(d)


def _resume_changed(d: Path) -> list[str]:
    frames, _ = _fitted(d)
    write_image(frames / "00001.png", np.full((24, 32, 3), 128, np.uint8))
    return _resume(d)


def _resume_nothing(d: Path) -> list[str]:
    (d / "run").mkdir()
    return _resume(d)


def _resume_before_checkpoint(d: Path) -> list[str]:
    """A fit killed after writing config.json and clip.json but before its first checkpoint."""
    _fitted(d)
    (d / "run" / C.RUN_CHECKPOINT).unlink()
    (d / "run" / C.RUN_METRICS).unlink()
    return _resume(d)


def _refit_existing(d: Path) -> list[str]:
    frames, masks = _fitted(d)
    return _fit_args(frames, masks, d)


CASES: tuple[Case, ...] = (
    Case("missing_clip", "clip folder does not exist", _missing_clip, ("no_such_frames", "check the path")),
    Case("unreadable_frame", "a later frame is truncated", _corrupt_png, ("00001.png", "re-export")),
    Case("corrupt_jpeg", "a JPEG frame that is not a JPEG", _corrupt_jpeg, ("00000.jpg", "re-export")),
    Case("corrupt_exr", "a truncated EXR frame", _corrupt_exr, ("00002.exr", "re-export")),
    Case("gap_in_numbering", "frame 00001 missing", _gap, ("00001 is missing", "frame range")),
    Case("frames_of_different_sizes", "one frame 32x20 in a 32x24 clip", _sizes, ("00002.png", "32x20")),
    Case("mask_count_mismatch", "2 masks for 3 frames", _mask_count, ("masks", "2 mask files", "one mask per frame")),
    Case("mask_size_mismatch", "masks 40x24 for a 32x24 clip", _mask_size, ("00000.png", "40x24", "aspect")),
    Case("empty_mask_folder", "a mask folder with no images", _empty_masks, ("empty_masks", "one mask image")),
    Case("missing_mask_folder", "a mask folder that does not exist", _missing_masks, ("no_such_masks",)),
    Case("movie_without_video", "an .mp4 with only audio", _no_video_stream, ("sound.mp4", "video stream")),
    Case(
        "unknown_preset", "--preset drafty", _good_clip_with("--preset", "drafty"), ("drafty", "did you mean 'draft'")
    ),
    Case(
        "unknown_config_key", "--set stesp=10", _good_clip_with("--set", "stesp=10"), ("stesp", "did you mean 'steps'")
    ),
    Case("bad_config_value", "--set steps=ten", _good_clip_with("--set", "steps=ten"), ("steps=ten", "int")),
    Case(
        "frame_range_outside_clip",
        "--frames 1-9 on frames 0..2",
        _good_clip_with("--frames", "1-9"),
        ("frame 9 is not in the plate", "0..2"),
    ),
    Case("unknown_device", "--device tpu", _good_clip_with("--device", "tpu"), ("tpu", "auto")),
    Case("output_not_writable", "--out below a regular file", _not_writable, ("a_file", "--out")),
    Case("incompatible_run_schema", "--resume of a run with config schema 0", _old_schema, ("config.json", "0")),
    Case("resume_changed_clip", "--resume after a frame changed", _resume_changed, ("clip", "changed", "new --out")),
    Case("resume_without_fit", "--resume of an empty folder", _resume_nothing, ("config.json", "without --resume")),
    Case(
        "resume_before_first_checkpoint",
        "--resume of a fit killed before its first checkpoint",
        _resume_before_checkpoint,
        ("checkpoint.pt", "without --resume"),
    ),
    Case("refit_into_a_fit", "fit again into a finished run", _refit_existing, ("run", "--resume")),
)


def all_cases() -> tuple[Case, ...]:
    """The fit verb's cases, then every ``tests/stability/cases_*.py`` module's ``CASES``, by module name."""
    cases = list(CASES)
    for path in sorted(Path(__file__).parent.glob("cases_*.py")):
        cases.extend(importlib.import_module(f"tests.stability.{path.stem}").CASES)
    return tuple(cases)


@dataclass
class Outcome:
    code: int
    stderr: str
    run_existed: bool
    run_before: dict[str, str]
    run_after: dict[str, str]
    run_exists_after: bool

    @property
    def lines(self) -> list[str]:
        return [ln for ln in self.stderr.splitlines() if ln.strip()]


def run_case(case: Case, folder: Path) -> Outcome:
    folder.mkdir(parents=True, exist_ok=True)
    argv = [case.verb, *case.build(folder)]
    run = case.watch(folder) if case.watch is not None else Path(argv[argv.index("--out") + 1])
    existed, before = run.exists(), tree_digest(run)
    err = io.StringIO()
    with (
        _environment(case.env(folder) if case.env is not None else {}),
        _native_stderr() as native,
        contextlib.redirect_stdout(io.StringIO()),
        contextlib.redirect_stderr(err),
    ):
        code = cli.main(argv)
    return Outcome(code, err.getvalue() + native[0], existed, before, tree_digest(run), run.exists())


@contextlib.contextmanager
def _environment(values: dict[str, str]) -> Iterator[None]:
    """``values`` set in ``os.environ`` for the block, the previous values (or their absence) restored after."""
    saved = {name: os.environ.get(name) for name in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for name, old in saved.items():
            if old is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = old


@contextlib.contextmanager
def _native_stderr():  # type: ignore[no-untyped-def]
    """Capture file descriptor 2 too: C libraries (codecs) write there, bypassing sys.stderr."""
    sys.stderr.flush()
    saved = os.dup(2)
    box: list[str] = []
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield box
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            box.append(tmp.read().decode("utf-8", errors="replace"))


def doc_message(outcome: Outcome, folder: Path) -> str:
    """The stderr line as the docs table shows it: the case folder replaced by <dir>, pipes escaped."""
    line = outcome.lines[0] if outcome.lines else ""
    return line.replace(str(folder), PLACEHOLDER).replace("|", "\\|")


def table_row(case: Case, message: str, code: int) -> str:
    return f"| `{case.id}` | {case.what} | {message} | {code} |"


def main() -> None:
    print("| case | input | message (stderr, one line) | exit |")
    print("|---|---|---|---|")
    for case in all_cases():
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp) / case.id
            outcome = run_case(case, folder)
            print(table_row(case, doc_message(outcome, folder), outcome.code))
    sys.stdout.flush()


if __name__ == "__main__":
    main()
