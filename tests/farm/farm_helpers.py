"""Tiny synthetic shots for the farm tests: a few frames of a small clip each, and a shots file naming them."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path
from typing import Any

from engine import contract as C
from engine.data.synthetic import SceneSpec, make_scene, write_scene

#: A clip that fits in seconds on a CPU: 5 frames of 48x32 with one moving sprite.
TINY_SPEC = SceneSpec(width=48, height=32, frames=5, fg_start=(10.0, 8.0), fg_size=(12, 10), bg_velocity=(1.0, 0.5))
#: fit --set overrides for a fit of a few seconds, the same on every run (seed fixed).
TINY_SET = ["steps=30", "batch=500", "eval_every=15", "bootstrap_steps=10", "global_rigidity_steps=10", "seed=3"]


def write_clip(folder: Path, seed: int = 0) -> tuple[Path, Path]:
    """(frames folder, masks folder) of a tiny synthetic clip (frames numbered 00000..00004)."""
    return write_scene(make_scene(dataclasses.replace(TINY_SPEC, seed=seed)), folder)


def write_shots(folder: Path, shots: list[dict[str, Any]], defaults: dict[str, Any] | None = None) -> Path:
    """A JSON shots file in ``folder`` (paths in ``shots`` relative to it, as a studio writes them)."""
    data: dict[str, Any] = {C.SHOTS_TAG: C.SHOTS_VERSION, C.SHOTS_LIST_KEY: shots}
    if defaults is not None:
        data[C.SHOTS_DEFAULTS_KEY] = defaults
    path = folder / "shots.json"
    path.write_text(json.dumps(data, indent=2), encoding="utf-8")
    return path


def two_shot_file(folder: Path, **defaults: Any) -> Path:
    """Two tiny shots: sh010 with its masks and a render, sh020 with auto masks and frames 1-4."""
    write_clip(folder / "clips" / "a", seed=0)
    write_clip(folder / "clips" / "b", seed=1)
    shots = [
        {"name": "sh010", "plate": "clips/a/frames", "masks": ["clips/a/masks"], "render": "renders/sh010"},
        {"name": "sh020", "plate": "clips/b/frames", "auto_masks": True, "frames": "1-4", "preview": False},
    ]
    return write_shots(folder, shots, {"preset": "draft", "set": TINY_SET, "export_chunk": 2, **defaults})


def openjd_commands(bundle: Path) -> list[tuple[str, list[str]]]:
    """(step name, command line) of every task of an OpenJD bundle, with the job parameters (its
    job_parameters.json) and each chunk's ``Frames`` task parameter substituted, as ``openjd run`` runs them."""
    template = json.loads((bundle / "template.json").read_text(encoding="utf-8"))
    values = json.loads((bundle / "job_parameters.json").read_text(encoding="utf-8"))
    params = {f"Param.{k}": v for k, v in values.items()}

    def substitute(text: str, names: dict[str, str]) -> str:
        return re.sub(r"\{\{\s*([A-Za-z0-9_.]+)\s*\}\}", lambda m: names[m.group(1)], text)

    commands = []
    for step in template["steps"]:
        action = step["script"]["actions"]["onRun"]
        space = step.get("parameterSpace", {}).get("taskParameterDefinitions", [])
        for frames in space[0]["range"] if space else [None]:
            names = {**params, "Task.Param.Frames": frames} if frames else params
            commands.append((step["name"], [substitute(a, names) for a in [action["command"], *action["args"]]]))
    return commands
