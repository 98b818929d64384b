"""Hand-made exports as a pipeline names its plates (``plate.1001.exr``, half-float EXR frames), built on
``tests/engine/fake_export.py``: no fit, known UVs, so what render and the Nuke script do is exact."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import OpenEXR

from engine.terms.export_names import blender_pattern, pass_file_name, pass_pattern
from engine.terms.manifest import validate_manifest
from tests.engine.fake_export import make_fake_export

W, H, T = 16, 12, 3


def background(t: int, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return xs / W, 1.0 - ys / H, np.full(xs.shape, 0.7)


def foreground(t: int, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return (xs - 2 * t) / 10, 1.0 - (ys - 1) / 9, np.where(xs > 6, 0.3, 0.0)


def plate_pixels(seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).random((T, H, W, 3)).astype(np.float32)


def fake_export(folder: Path) -> Path:
    """Two layers over a 3-frame 8-bit sRGB PNG plate named 00000.png .. (five digits); the manifest's path."""
    return make_fake_export(folder, plate_pixels(), [(background, (W, H)), (foreground, (10, 9))])


def renumber(manifest_path: Path, first: int, padding: int, half_exr: bool = False) -> Path:
    """Make the fake export's plate ``plate.<first>..`` padded to ``padding`` digits (as a half-float, scene-linear
    EXR sequence with ``half_exr``) and its passes named as this engine names them for that plate; the manifest."""
    data = json.loads(manifest_path.read_text())
    clip, passes = data["clip"], data["passes"]
    export = manifest_path.parent
    numbers = [first + t for t in range(len(clip["frame_numbers"]))]
    files = []
    for old, number in zip(clip["frame_files"], numbers, strict=True):
        ext = ".exr" if half_exr else ".png"
        new = Path(old).with_name(f"plate.{number:0{padding}d}{ext}")
        if half_exr:
            rgb = plate_pixels()[numbers.index(number)] ** 2.2  # scene-linear values, any will do
            header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
            chans = {c: rgb[..., i].astype(np.float16) for i, c in enumerate("RGB")}
            with OpenEXR.File(header, chans) as f:
                f.write(str(new))
            os.unlink(old)
        else:
            os.replace(old, new)
        files.append(str(new))
        pass_old = export / passes["dir"] / passes["pattern"].format(frame=numbers.index(number))
        os.replace(pass_old, export / passes["dir"] / pass_file_name(number, padding))
    clip.update(frame_files=files, frame_numbers=numbers, first_frame=numbers[0], last_frame=numbers[-1])
    if half_exr:
        clip.update(colorspace="linear")
    passes.update(pattern=pass_pattern(padding), blender_pattern=blender_pattern(padding), frames=numbers)
    manifest_path.write_text(json.dumps(validate_manifest(data)))
    return manifest_path
