"""An export as the engine reads it back: manifest.json resolved to paths, and per-frame passes.

Torch-free (render, project-frame and preview work from the files alone, exactly what Blender sees).
The schema itself lives in ``engine.contract``; this module only resolves paths and reads passes. Paths are
resolved relative to the manifest first (``contract.resolve_manifest_path``), so a run folder moved or mounted
elsewhere keeps working; every path written through (edit layers, their history, previews) must stay inside the
run folder (``contract.resolve_manifest_write_path``): a manifest cannot make the engine write anywhere else.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .. import contract as C
from ..errors import InputError
from ..io.clip import is_sequence_pattern
from ..io.images import read_exr

#: The fix of a manifest that cannot be used as it is.
EXPORT_AGAIN = f"run `python -m {C.CLI_MODULE} export RUN_DIR` again"
#: The fix of a plate that is not where the manifest says.
PLATE_FIX = (
    "put the plate back where the export was made from (its path is relative to the manifest), or tell the export "
    f"where it is now: python -m {C.CLI_MODULE} {C.VERB_RELINK} MANIFEST {C.RELINK_PLATE_ARG} PLATE"
)


@dataclass
class LayerPasses:
    """One layer's passes of one frame at native resolution (row 0 at the top)."""

    uv: np.ndarray  # float32 [H, W, 2]: u, v in [0, 1], origin bottom-left of the atlas
    z: np.ndarray  # float32 [H, W]: the layer's alpha where its atlas covers the pixel, else 0
    alpha: np.ndarray  # float32 [H, W]: the layer's alpha (opacity weight; the layers sum to 1)


class Manifest:
    """A validated manifest.json and the folder it lives in."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path).resolve()
        if self.path.is_dir():
            self.path = self.path / C.MANIFEST_NAME
        try:
            self.data: dict[str, Any] = C.load_manifest(str(self.path))
        except C.ManifestError as exc:
            raise InputError(None, str(exc).split(" — ")[0], EXPORT_AGAIN) from None
        self.folder = self.path.parent

    def resolve(self, rel: str) -> Path:
        """A path from the manifest, to READ (``contract.resolve_manifest_path``: the add-on resolves them the same
        way): relative to the manifest's folder; an absolute one as it is."""
        return Path(C.resolve_manifest_path(str(self.path), rel))

    def resolve_write(self, rel: str) -> Path:
        """A path from the manifest, to WRITE: relative and inside the run folder once symlinks and ``..`` are
        resolved (``contract.resolve_manifest_write_path``); anything else is a one-line InputError."""
        try:
            return Path(C.resolve_manifest_write_path(str(self.path), rel))
        except C.ManifestError as exc:
            raise InputError(None, str(exc).split(" — ")[0], EXPORT_AGAIN) from None

    @property
    def run_root(self) -> Path:
        """The run folder this export belongs to (``contract.manifest_run_root``: found from where the manifest
        is, so a moved run folder keeps working)."""
        return Path(C.manifest_run_root(str(self.path)))

    @property
    def layers(self) -> list[dict[str, Any]]:
        return self.data["layers"]

    @property
    def clip(self) -> dict[str, Any]:
        return self.data["clip"]

    @property
    def frames(self) -> list[int]:
        """Plate frame numbers that have passes."""
        return list(self.data["passes"]["frames"])

    @property
    def resolution(self) -> tuple[int, int]:
        w, h = self.data["passes"]["resolution"]
        return int(w), int(h)

    def layer(self, name: str) -> dict[str, Any]:
        for layer in self.layers:
            if layer["name"] == name:
                return layer
        raise InputError(self.path, f"no layer called {name!r}", f"use one of {self.layer_names()}")

    def layer_names(self) -> str:
        """The layers' names, for messages."""
        return ", ".join(layer["name"] for layer in self.layers)

    def check_layers(self, names: list[str] | None) -> None:
        """Every name in ``names`` is a layer of this export (one line listing the layers otherwise)."""
        for name in names or []:
            self.layer(name)

    def edit_path(self, layer: dict[str, Any]) -> Path:
        """The layer's edit layer as the export made it (``<Layer>.png``): a write path, inside the run folder."""
        return self.resolve_write(layer["edit_layer"])

    def edit_file(self, layer: dict[str, Any]) -> Path:
        """The edit layer file in use: its float twin ``<Layer>.exr`` when that exists (``contract.edit_layer_file``),
        else the PNG; both checked as write paths, so paint never lands outside the run folder."""
        png = self.edit_path(layer)
        twin = C.float_edit_layer(layer["edit_layer"])
        if C.edit_layer_file(str(png)) != str(png):
            return self.resolve_write(twin)
        return png

    def pass_path(self, frame: int) -> Path:
        """The pass file of plate frame ``frame``, named by the manifest's pattern (its padding is the plate's;
        exports made before it followed the plate's padding have five digits)."""
        return self.resolve(self.data["passes"]["dir"]) / self.data["passes"]["pattern"].format(frame=frame)

    def check_frame(self, frame: int) -> None:
        if frame not in self.frames:
            f = self.frames
            raise InputError(
                self.path,
                f"frame {frame} has no passes in this export (frames {f[0]}..{f[-1]})",
                "pick a frame inside the exported range or export it with --frames",
            )

    def plate_path(self, position: int | None = None) -> Path:
        """The plate (``position`` None) or its frame file at ``position``, unchecked: relative to the manifest, or
        as it was at export where that names nothing (``contract.resolve_plate_path``: the run folder moved alone)."""
        return Path(C.resolve_plate_path(str(self.path), self.clip, position))

    def plate_source(self) -> Path:
        """The plate (a folder of frames, a sequence pattern or a movie file), checked to exist as what the manifest
        says it is."""
        path = self.plate_path()
        is_sequence = self.clip["kind"] == C.CLIP_KINDS[0]
        if is_sequence and is_sequence_pattern(str(path)):  # plate.####.exr: its folder must be there
            if not path.parent.is_dir():
                raise InputError(path.parent, "plate folder does not exist", PLATE_FIX)
            return path
        if not (path.is_dir() if is_sequence else path.is_file()):
            what = "plate folder" if is_sequence else "plate movie"
            problem = f"{what} does not exist" if not path.exists() else f"is not the {what} the export was made from"
            raise InputError(path, problem, PLATE_FIX)
        return path

    def plate_frame_file(self, position: int) -> Path:
        """The plate's frame file at ``position`` in the manifest's frame list, checked to be a file."""
        path = self.plate_path(position)
        if not path.is_file():
            problem = "plate frame does not exist" if not path.exists() else "plate frame is not a file"
            raise InputError(path, problem, PLATE_FIX)
        return path

    def read_passes(self, frame: int) -> list[LayerPasses]:
        """Every layer's passes of plate frame ``frame``."""
        self.check_frame(frame)
        path = self.pass_path(frame)
        if not os.path.isfile(path):  # checked first: the EXR library would print its own line too
            raise InputError(path, "pass file does not exist", "export the run again")
        chans = read_exr(path)
        out = []
        for layer in self.layers:
            names = [C.channel_name(layer["uv_pass"], c) for c in layer["uv_channels"]]
            alpha_name = C.channel_name(layer["alpha_pass"], layer["alpha_channels"][0])
            missing = [n for n in [*names, alpha_name] if n not in chans]
            if missing:
                raise InputError(path, f"pass file lacks channels {missing}", "export the run again")
            passes = LayerPasses(uv=np.stack((chans[names[0]], chans[names[1]]), -1), z=chans[names[2]],
                                 alpha=chans[alpha_name])  # fmt: skip
            if passes.z.shape != self.resolution[::-1]:
                size = f"{passes.z.shape[1]}x{passes.z.shape[0]}"
                raise InputError(path, f"pass file is {size}, the manifest says {self.resolution}", "export again")
            out.append(passes)
        return out


__all__ = [
    "EXPORT_AGAIN",
    "PLATE_FIX",
    "LayerPasses",
    "Manifest",
]
