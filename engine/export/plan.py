"""What every part of one export shares (``Plan``): the layers, each layer's atlas frame and the frames exported.

A whole export makes it once; a staged export's atlases stage makes it and records it (``Plan.to_record``), and
its passes and publish stages read it back (``Plan.from_record``), so every chunk writes the passes the whole
export would. An existing edit layer's frame (``edits/layout.json``) wins over the one the coverage gives: its
paint must not shift.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np

from .. import contract as C
from ..errors import InputError
from ..fit.fitted_run import FittedRun
from ..fit.progress import Reporter
from ..fit.run_files import Kind, RunFile, record_problem
from ..fit.run_folder import ClipRecord
from ..terms.export_names import EDIT_LAYER_EXT, EDITS_LAYOUT, PASS_PRECISION_COMPACT, layer_name
from ..terms.versions import SCHEMA_VERSION
from .atlas_frame import LayerFrame, _Coverage, layer_frame_for
from .sampling import eval_pixels, pixel_grid
from .stage_record import STAGE_SCHEMA, LayerFrameRecord, StageFile


class EditLayout(RunFile):
    """``edits/layout.json``: the atlas frame each edit layer was painted in, by layer name (an export keeps a
    painted layer's frame, so its paint does not shift)."""

    layers: Annotated[dict[str, LayerFrameRecord], Kind("dict of atlas frames")]


#: The fix of an edit layout that cannot be used.
LAYOUT_FIX = "restore it or delete it (paint may shift)"


def read_layout(edits_dir: Path) -> dict[str, Any]:
    """The run's edit layout (an empty one when there is none), checked against ``EditLayout``; one that cannot be
    read is one line: restoring it keeps the paint where it was painted."""
    path = edits_dir / EDITS_LAYOUT
    if not path.exists():
        return {"schema": SCHEMA_VERSION, "layers": {}}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        raise InputError(path, "edit layout is not valid JSON", "restore it from a backup or delete it") from None
    if not isinstance(data, dict) or data.get("schema") != SCHEMA_VERSION:
        raise InputError(path, "edit layout has an unknown schema", LAYOUT_FIX)
    problem = record_problem("edit layout", EditLayout, data)
    if problem is not None:
        raise InputError(path, problem, LAYOUT_FIX)
    return data


def selected_frames(clip: ClipRecord, frames: tuple[int, int] | None) -> list[int]:
    """Run frame indices to export; ``frames`` are the plate's frame numbers, like `fit --frames`."""
    numbers = list(clip.frame_numbers)
    if frames is None:
        return list(range(clip.num_frames))
    a, b = frames
    if a > b or a not in numbers or b not in numbers:
        first, last = numbers[0], numbers[-1]
        raise InputError(
            None,
            f"--frames {a}-{b} is outside the fitted frames {first}-{last}",
            f"choose a range inside {first}-{last} (the plate's frame numbers)",
        )
    return list(range(numbers.index(a), numbers.index(b) + 1))


@dataclass
class Plan:
    """What every part of one export shares: the layers, the atlas frame of each and the frames exported."""

    names: list[str]
    frames_by_layer: list[LayerFrame]
    selected: list[int]  # run frame indices
    atlas_size: int
    #: Whether the export follows the flow (``export --follow-flow``), and the layers whose UV it moved: those that
    #: slip against the flow (``engine.export.follow_flow``).
    follow_flow: bool = False
    follows: frozenset[int] = frozenset()
    #: The bits the pass files keep (``terms.export_names.PASS_PRECISIONS``; ``pass_files.kept_precision``) and
    #: whether each pass file also holds an STMap copy of each layer's UV (``export --stmap``): the export's choices
    #: (a staged record's: ``from_record``).
    precision: str = PASS_PRECISION_COMPACT
    stmap: bool = False

    def numbers(self, clip: ClipRecord) -> list[int]:
        return [clip.frame_numbers[t] for t in self.selected]

    def to_record(self, clip: ClipRecord, source: dict[str, str]) -> dict[str, Any]:
        """The staged export's record (``STAGE_RECORD``): JSON keeps each float exactly, so every pass a chunk
        writes from it is the whole export's; ``source`` (``stage_record.fit_source``) is the fit it is made from,
        which every later stage checks."""
        numbers = self.numbers(clip)
        layers = [
            {"name": n, "atlas_box": list(fr.box), "atlas_size": list(fr.size)}
            for n, fr in zip(self.names, self.frames_by_layer, strict=True)
        ]
        return {"schema": STAGE_SCHEMA, "frames": [numbers[0], numbers[-1]], "atlas_size": self.atlas_size,
                "layers": layers, "source": source, "follow_flow": self.follow_flow,
                "follows": sorted(self.follows), "precision": self.precision, "stmap": self.stmap}  # fmt: skip

    @classmethod
    def from_record(cls, record: StageFile, clip: ClipRecord) -> Plan:
        """The plan a staged export's record (``stage_record.read_stage``) says; the choices an older record does
        not name take ``StageFile``'s defaults (what the engine that wrote it did)."""
        first, last = record.frames
        return cls(
            [layer.name for layer in record.layers],
            [LayerFrame(tuple(layer.atlas_box), tuple(layer.atlas_size)) for layer in record.layers],  # type: ignore[arg-type]
            selected_frames(clip, (first, last)),
            record.atlas_size,
            record.follow_flow,
            frozenset(record.follows),
            record.precision,
            record.stmap,
        )


def plan_export(
    reporter: Reporter,
    fitted: FittedRun,
    atlas_size: int,
    frames: tuple[int, int] | None,
    bar: Any,
    on_frame: Callable[[int, list[np.ndarray], np.ndarray], None] | None = None,
) -> tuple[Plan, list[_Coverage]]:
    """Where each layer's mapping lands (every frame, working resolution) and each layer's atlas frame: an existing
    edit layer's frame wins (its paint must not shift). ``on_frame(t, uvs, weights)`` is given each frame's
    evaluation (the flow-following export keeps the layers' UV of this one pass rather than evaluating again)."""
    model, clip = fitted.model, fitted.clip
    device = next(model.parameters()).device
    selected = selected_frames(clip, frames)
    names = [layer_name(i, model.num_layers) for i in range(model.num_layers)]
    reporter.emit(C.EVENT_STAGE, stage="atlas", message="atlas extent and coverage")
    cov = [_Coverage(model.uv_per_px(i), clip.num_frames, foreground=i > 0) for i in range(model.num_layers)]
    xy_work = pixel_grid(clip.working_size, (1.0, 1.0), device)
    for t in range(clip.num_frames):
        uvs, wts = eval_pixels(model, xy_work, t)
        for i in range(model.num_layers):
            cov[i].add(t, uvs[i], wts[:, i])
        if on_frame is not None:
            on_frame(t, uvs, wts)
        bar.update(1)
    edits_dir = fitted.folder.edits
    layout = read_layout(edits_dir)
    frames_by_layer: list[LayerFrame] = []
    for i, name in enumerate(names):
        rec = layout["layers"].get(name)
        painted = any((edits_dir / f"{name}{ext}").exists() for ext in (EDIT_LAYER_EXT, C.EDIT_LAYER_FLOAT_EXT))
        if rec is not None and painted:
            frames_by_layer.append(layer_frame_for(tuple(rec["atlas_box"]), atlas_size))  # type: ignore[arg-type]
        else:
            frames_by_layer.append(layer_frame_for(cov[i].box(), atlas_size))
    return Plan(names, frames_by_layer, selected, atlas_size), cov


__all__ = [
    "EditLayout",
    "Plan",
    "plan_export",
    "read_layout",
    "selected_frames",
]
