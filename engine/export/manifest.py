"""An export as the engine reads it back: manifest.json resolved to paths, and per-frame passes.

Torch-free (render, project-frame and preview work from the files alone, exactly what Blender sees).
The schema itself lives in ``engine.contract``; this module only resolves paths and reads passes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from engine import contract as C
from engine.errors import InputError
from engine.io.images import read_exr


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
            raise InputError(None, str(exc).split(" — ")[0], "run `python -m engine export RUN_DIR` again") from None
        self.folder = self.path.parent

    def resolve(self, rel: str) -> Path:
        """A path from the manifest (``contract.resolve_manifest_path``: the add-on resolves them the same way)."""
        return Path(C.resolve_manifest_path(str(self.path), rel))

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
        names = ", ".join(layer["name"] for layer in self.layers)
        raise InputError(self.path, f"no layer called {name!r}", f"use one of {names}")

    def edit_path(self, layer: dict[str, Any]) -> Path:
        return self.resolve(layer["edit_layer"])

    def pass_path(self, frame: int) -> Path:
        return self.resolve(self.data["passes"]["dir"]) / C.pass_file_name(frame)

    def check_frame(self, frame: int) -> None:
        if frame not in self.frames:
            f = self.frames
            raise InputError(
                self.path,
                f"frame {frame} has no passes in this export (frames {f[0]}..{f[-1]})",
                "pick a frame inside the exported range or export it with --frames",
            )

    def read_passes(self, frame: int) -> list[LayerPasses]:
        """Every layer's passes of plate frame ``frame``."""
        self.check_frame(frame)
        path = self.pass_path(frame)
        chans = read_exr(path)
        out = []
        for layer in self.layers:
            names = [C.channel_name(layer["uv_pass"], c) for c in layer["uv_channels"]]
            alpha_name = C.channel_name(layer["alpha_pass"], layer["alpha_channels"][0])
            missing = [n for n in [*names, alpha_name] if n not in chans]
            if missing:
                raise InputError(path, f"pass file lacks channels {missing}", "export the run again")
            out.append(
                LayerPasses(
                    uv=np.stack((chans[names[0]], chans[names[1]]), -1),
                    z=chans[names[2]],
                    alpha=chans[alpha_name],
                )
            )
        return out


__all__ = ["LayerPasses", "Manifest"]
