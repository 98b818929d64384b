"""The run folder: the one module that knows its layout and reads and writes its files.

A fit writes ``config.json`` (the config), ``clip.json`` (what was fitted: ``ClipRecord``), ``scene.json`` (the
scene analysis), ``checkpoint.pt``, ``metrics.json`` and ``fit.log`` into RUN_DIR; ``fit --resume``, ``export``,
the demo and the bench read them back through ``RunFolder``. Every JSON file is checked against its versioned
schema in the contract (``contract.validate_run_file``) when it is read and before it is written; a file that
does not follow it is a one-line ``InputError`` naming the file and the fix.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch

from engine import contract as C
from engine.config import FitConfig
from engine.data.scene_analysis import SceneAnalysis, read_scene_file, write_scene_file
from engine.errors import InputError
from engine.fit.checkpoint import load_checkpoint, save_checkpoint
from engine.io.atomic import atomic_write_text
from engine.io.clip import NumberedFrames


@dataclass(frozen=True)
class ClipRecord(NumberedFrames):
    """``clip.json``: what was fitted, and everything a reader of the run needs of the clip without decoding
    it (export: the native and working sizes, the frames and their numbers, the layers)."""

    source: str
    kind: str
    frame_range: tuple[int, int]
    frame_numbers: tuple[int, ...]
    frame_files: tuple[str, ...]
    native_size: tuple[int, int]
    working_size: tuple[int, int]
    fps: float | None
    colorspace: str
    masks: tuple[str, ...]
    scribbles: str | None
    layers: int
    fingerprint: str

    def to_dict(self) -> dict[str, Any]:
        data = asdict(self)
        for key, value in data.items():
            if isinstance(value, tuple):
                data[key] = list(value)
        return {"schema": C.RUN_CLIP_SCHEMA, **data}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ClipRecord:
        """From a record that passed ``contract.validate_run_file``."""
        return cls(
            source=data["source"],
            kind=data["kind"],
            frame_range=(data["frame_range"][0], data["frame_range"][1]),
            frame_numbers=tuple(data["frame_numbers"]),
            frame_files=tuple(data["frame_files"]),
            native_size=(data["native_size"][0], data["native_size"][1]),
            working_size=(data["working_size"][0], data["working_size"][1]),
            fps=data["fps"],
            colorspace=data["colorspace"],
            masks=tuple(data["masks"]),
            scribbles=data["scribbles"],
            layers=data["layers"],
            fingerprint=data["fingerprint"],
        )


def _entry(name: str) -> property:
    """A path inside the run folder (read-only)."""
    return property(lambda self: self.path / name)


class RunFolder:
    """RUN_DIR: its files' paths, and their reading (validated) and writing (validated, atomic)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    # --- layout: each entry's name is the contract's
    config = _entry(C.RUN_CONFIG)
    clip = _entry(C.RUN_CLIP)
    metrics = _entry(C.RUN_METRICS)
    scene = _entry(C.SCENE_FILE)
    checkpoint = _entry(C.RUN_CHECKPOINT)
    log = _entry(C.RUN_LOG)
    flow_cache = _entry(C.FLOW_CACHE_DIR)
    auto_masks = _entry(C.AUTO_MASKS_DIR)
    exports = _entry(C.EXPORTS_DIR)
    edits = _entry(C.EDITS_DIR)

    # --- checks
    def holds_fit(self) -> bool:
        """A fit has checkpointed here (finished or not)."""
        return self.checkpoint.exists()

    def require_fit(self) -> None:
        """One-line error unless this is the folder of a fit that checkpointed (what export reads)."""
        for path in (self.config, self.clip, self.checkpoint):
            if not path.exists():
                raise InputError(path, "this is not a fitted run folder", "pass the --out folder of a `fit`")

    def check_writable(self) -> None:
        """One-line error if the folder (or the nearest folder that exists above it) cannot be written."""
        probe = self.path
        while not probe.exists() and probe != probe.parent:
            probe = probe.parent
        if not (probe.is_dir() and os.access(probe, os.W_OK | os.X_OK)):
            raise InputError(self.path, "output folder is not writable", "choose a folder you can write to with --out")

    # --- config.json
    def read_config(self) -> FitConfig:
        text = self._read_text(self.config, "no fit to resume here", "run `fit` without --resume first")
        self._validated(self.config, text)
        return FitConfig.from_json(text, self.config)

    def write_config(self, cfg: FitConfig) -> None:
        text = cfg.to_json()
        self._validated(self.config, text)
        atomic_write_text(self.config, text)

    # --- clip.json
    def read_clip(self) -> ClipRecord:
        text = self._read_text(
            self.clip, "this run folder has no record of its clip", "resume a folder written by `fit`"
        )
        return ClipRecord.from_dict(self._validated(self.clip, text))

    def write_clip(self, record: ClipRecord) -> None:
        self._write_json(self.clip, record.to_dict())

    # --- metrics.json
    def read_metrics(self) -> dict[str, Any] | None:
        """The finished fit's metrics; None while the fit has not finished."""
        if not self.metrics.exists():
            return None
        return self._validated(self.metrics, self._read_text(self.metrics, "no metrics", "let the fit finish"))

    def write_metrics(self, metrics: dict[str, Any]) -> None:
        self._write_json(self.metrics, {"schema": C.RUN_METRICS_SCHEMA, **metrics})

    # --- scene.json
    def read_scene(self) -> SceneAnalysis:
        return read_scene_file(self.path)

    def write_scene(self, scene: SceneAnalysis) -> None:
        write_scene_file(self.path, scene)

    # --- checkpoint.pt
    def load_checkpoint(self, device: torch.device) -> dict[str, Any]:
        state = load_checkpoint(self.checkpoint, device)
        missing = [k for k in C.RUN_CHECKPOINT_KEYS if k not in state] if isinstance(state, dict) else ["schema"]
        if missing:
            raise InputError(self.checkpoint, f"checkpoint has no {missing[0]!r}", C.RUN_FILE_OTHER_VERSION_FIX)
        if state["schema"] != C.RUN_CHECKPOINT_SCHEMA:
            problem = (
                f"checkpoint schema {state['schema']!r} is not supported (this engine writes {C.RUN_CHECKPOINT_SCHEMA})"
            )
            raise InputError(self.checkpoint, problem, C.RUN_FILE_OTHER_VERSION_FIX)
        return state

    def save_checkpoint(self, state: dict[str, Any]) -> None:
        save_checkpoint(self.checkpoint, {"schema": C.RUN_CHECKPOINT_SCHEMA, **state})

    # --- helpers
    @staticmethod
    def _read_text(path: Path, missing_problem: str, missing_fix: str) -> str:
        try:
            return path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise InputError(path, missing_problem, missing_fix) from None

    @staticmethod
    def _validated(path: Path, text: str) -> dict[str, Any]:
        try:
            return C.validate_run_file(path.name, json.loads(text))
        except json.JSONDecodeError:
            raise InputError(path, "not valid JSON", C.RUN_FILE_DAMAGED_FIX) from None
        except C.RunFileError as exc:
            raise InputError(path, exc.problem, exc.fix) from None

    @staticmethod
    def _write_json(path: Path, data: dict[str, Any]) -> None:
        text = json.dumps(data, indent=2)
        RunFolder._validated(path, text)
        atomic_write_text(path, text)


__all__ = ["ClipRecord", "RunFolder"]
