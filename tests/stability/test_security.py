"""Security: no shell strings (every child process is an argv list), checkpoints load with
``weights_only=True`` (a pickled payload in a checkpoint is refused, never executed), and paths with
spaces and non-ASCII characters work end to end for fit and resume."""

from __future__ import annotations

import ast
import contextlib
import io
import json
from pathlib import Path

import pytest
import torch

from engine import cli
from engine import contract as C
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.errors import InputError
from engine.fit.checkpoint import load_checkpoint
from engine.terms.run_folder import RUN_CLIP
from tests.paths import ROOT

SCANNED = ("engine", "addon")
#: Calls that hand a string to a shell.
SHELL_CALLS = {("os", "system"), ("os", "popen"), ("subprocess", "getoutput"), ("subprocess", "getstatusoutput")}


def _sources() -> list[Path]:
    files = [p for d in SCANNED for p in sorted((ROOT / d).rglob("*.py"))]
    assert len(files) > 10
    return files


def _dotted(node: ast.AST) -> tuple[str, ...]:
    parts: list[str] = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        parts.append(node.id)
    return tuple(reversed(parts))


def test_no_shell_strings_in_engine_or_addon():
    offenders = []
    for path in _sources():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            if not isinstance(node, ast.Call):
                continue
            where = f"{path.relative_to(ROOT)}:{node.lineno}"
            name = _dotted(node.func)
            if name[-2:] in SHELL_CALLS:
                offenders.append(f"{where} {'.'.join(name)}")
            for kw in node.keywords:
                if kw.arg == "shell" and not (isinstance(kw.value, ast.Constant) and kw.value.value is False):
                    offenders.append(f"{where} shell={ast.unparse(kw.value)}")
    assert not offenders, offenders


def test_every_torch_load_is_weights_only():
    loads = []
    for path in _sources():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.Call) and _dotted(node.func)[-2:] == ("torch", "load"):
                ok = any(
                    kw.arg == "weights_only" and isinstance(kw.value, ast.Constant) and kw.value.value is True
                    for kw in node.keywords
                )
                loads.append((f"{path.relative_to(ROOT)}:{node.lineno}", ok))
    assert loads, "expected at least the checkpoint loader"
    assert all(ok for _, ok in loads), [w for w, ok in loads if not ok]


class _Payload:
    """Pickles to a call that would create a file when unpickled by a full (unsafe) load."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):  # type: ignore[no-untyped-def]
        return (Path.touch, (self.marker,))


def test_checkpoint_with_a_pickled_payload_is_refused_not_run(tmp_path):
    marker = tmp_path / "payload_ran"
    path = tmp_path / C.RUN_CHECKPOINT
    torch.save({"step": 1, "model": {}, "evil": _Payload(marker)}, path)
    with pytest.raises(InputError) as exc:
        load_checkpoint(path, torch.device("cpu"))
    assert C.RUN_CHECKPOINT in str(exc.value) and "\n" not in str(exc.value)
    assert not marker.exists()


@pytest.mark.parametrize(
    "clip_dir,run_dir",
    [("shot 01/plate frames", "runs/run with spaces"), ("plåte ünïcødé 日本/フレーム", "ränder 実行/run é")],
    ids=["spaces", "non_ascii"],
)
def test_paths_with_spaces_and_non_ascii_fit_and_resume(tmp_path, clip_dir, run_dir):
    frames, masks = write_scene(
        make_scene(SceneSpec(width=32, height=24, frames=2, fg_size=(12, 10), fg_start=(8.0, 6.0))),
        tmp_path / clip_dir,
    )
    run = tmp_path / run_dir
    sets = ["steps=3", "batch=64", "eval_pixels=256", "eval_every=1"]
    argv = ["fit", str(frames), "--mask", str(masks), "--out", str(run), "--preset", "draft", "--no-bar"]
    argv += [a for s in sets for a in ("--set", s)]
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        assert cli.main(argv) == C.EXIT_OK, err.getvalue()
        record = json.loads((run / RUN_CLIP).read_text(encoding="utf-8"))
        assert record["source"] == str(frames) and record["masks"] == [str(masks)]
        # resume reads the recorded non-ASCII paths back (a finished fit just re-evaluates)
        assert cli.main(["fit", "--resume", "--out", str(run), "--no-bar"]) == C.EXIT_OK, err.getvalue()
    assert json.loads((run / C.RUN_METRICS).read_text())["steps"] == 3
