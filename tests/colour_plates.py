"""Tiny exports of three studio plates for the colour tests (engine and add-on): an ACEScg half-float EXR, a log
(ACEScct) 10-bit DPX and an 8-bit sRGB PNG, with hand-made passes (no fit). Run as a script by the add-on tests:
``python -m tests.colour_plates KIND FOLDER [paint]`` prints the manifest's path."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from engine import contract as C
from engine.io.clip import open_clip
from engine.io.images import write_png
from engine.terms.colour import COLOUR_BUILTIN_CONFIG
from engine.terms.export_names import EDITS_DIR, layer_name
from engine.terms.manifest import validate_manifest
from tests.engine.fake_export import make_fake_export

W, H, T = 12, 8, 2
AP1 = (0.713, 0.293, 0.165, 0.830, 0.128, 0.044, 0.32168, 0.33767)


def _identity(t, xs, ys):
    return xs / W, 1.0 - ys / H, np.ones_like(xs)


def _half_layer(t, xs, ys):
    """Covers the left half of the frame only: the right half is no layer's."""
    return xs / W, 1.0 - ys / H, (xs < W / 2).astype(np.float64)


def _write(path: Path, rgb: np.ndarray, fmt, **attrs) -> None:
    spec = oiio.ImageSpec(W, H, 3, fmt)
    for key, value in attrs.items():
        if isinstance(value, tuple):
            spec.attribute(key, oiio.TypeDesc(f"float[{len(value)}]"), value)
        else:
            spec.attribute(key, value)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(np.ascontiguousarray(rgb, np.float32))
    out.close()


def _read(path: Path, native: bool = True) -> np.ndarray:
    inp = oiio.ImageInput.open(str(path))
    pixels = inp.read_image(0, 0, 0, 3, inp.spec().format if native else "float")
    inp.close()
    return np.asarray(pixels)


def _plate_values(rng: np.random.Generator, kind: str) -> np.ndarray:
    if kind == "acescg":
        return rng.uniform(0.0, 4.0, (T, H, W, 3)).astype(np.float16).astype(np.float32)  # HDR, half-exact
    if kind == "acescct":
        return np.rint(rng.uniform(0.1, 0.7, (T, H, W, 3)) * 1023.0).astype(np.float32) / 1023.0
    return np.rint(rng.uniform(0.0, 1.0, (T, H, W, 3)) * 255.0).astype(np.float32) / 255.0


#: kind -> (extension, writer attributes, colour space the plate is given / found by default)
KINDS = {
    "acescg": (".exr", {"fmt": oiio.HALF, "chromaticities": AP1}, "ACEScg"),
    "acescct": (".dpx", {"fmt": oiio.UINT16, "oiio:BitsPerSample": 10, "dpx:Transfer": "Printing density"}, "ACEScct"),
    "srgb": (".png", {"fmt": oiio.UINT8}, C.COLOUR_SRGB),
}


def export_plate(tmp_path: Path, kind: str, layer=_identity) -> tuple[Path, np.ndarray]:
    """A hand-made export of a plate of ``kind``, its manifest naming the plate's colour space (given for the DPX,
    found by default for the others). Returns (manifest, the plate's values as read)."""
    ext, attrs, space = KINDS[kind]
    values = _plate_values(np.random.default_rng(7), kind)
    manifest = make_fake_export(tmp_path, np.zeros((T, H, W, 3), np.float32), [(layer, (W, H))])
    clip_dir = tmp_path / "clip"
    for old in clip_dir.iterdir():
        old.unlink()
    attrs = dict(attrs)
    fmt = attrs.pop("fmt")
    for t in range(T):
        _write(clip_dir / f"plate.{t:04d}{ext}", values[t], fmt, **attrs)
    info = open_clip(clip_dir, colorspace="ACEScct" if kind == "acescct" else None)
    assert info.colorspace == space and info.colour_config == COLOUR_BUILTIN_CONFIG
    data = json.loads(manifest.read_text())
    data["clip"].update(
        frame_files=list(info.frame_files), colorspace=info.colorspace, colour_config=info.colour_config
    )
    manifest.write_text(json.dumps(validate_manifest(data)))
    return manifest, values


def paint(manifest: Path, rgba8: tuple[int, int, int, int] = (200, 3, 50, 255)) -> Path:
    """Paint the export's one edit layer a single sRGB colour (an 8-bit PNG, as Blender saves paint)."""
    edit = manifest.parents[2] / EDITS_DIR / f"{layer_name(0, 1)}.png"
    write_png(edit, np.broadcast_to(np.float32(rgba8) / 255.0, (H, W, 4)).copy(), 8)
    return edit


if __name__ == "__main__":
    kind, folder = sys.argv[1], Path(sys.argv[2])
    manifest, _ = export_plate(folder, kind, _half_layer)
    if sys.argv[3:] == ["paint"]:
        paint(manifest)
    print(manifest)
