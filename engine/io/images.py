"""Image files the export reads and writes: float EXR (named channels), 8/16-bit PNG, atomically.

Every write goes to a hidden temp file in the destination folder and is renamed into place, so a killed
export or render never leaves a half-written file where a compositor would pick it up. Channel data is
float32, row 0 at the top (the file convention; Blender flips to bottom-up on load).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenEXR
import OpenImageIO as oiio

from engine.errors import InputError
from engine.io.atomic import atomic_write


def write_exr(path: Path, channels: dict[str, np.ndarray], compression: str = "zip") -> Path:
    """Write float32 ``channels`` (name -> [H, W]) to one scanline EXR part, atomically."""
    shapes = {c.shape for c in channels.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"EXR channels must share one [H, W] shape, got {shapes}")
    comp = {"zip": OpenEXR.ZIP_COMPRESSION, "piz": OpenEXR.PIZ_COMPRESSION, "none": OpenEXR.NO_COMPRESSION}[
        compression
    ]
    data = {name: np.ascontiguousarray(c, dtype=np.float32) for name, c in channels.items()}
    header = {"compression": comp, "type": OpenEXR.scanlineimage}

    def write(tmp: str) -> None:
        with OpenEXR.File(header, data) as f:
            f.write(tmp)

    return atomic_write(path, write)


def write_rgba_exr(path: Path, rgba: np.ndarray) -> Path:
    """An ordinary (single-layer) RGBA or RGB float EXR."""
    names = "RGBA"[: rgba.shape[2]]
    return write_exr(path, {n: rgba[..., i] for i, n in enumerate(names)})


def read_exr(path: str | Path) -> dict[str, np.ndarray]:
    """All channels of an EXR as float32 [H, W] arrays by full name; a bad file is a one-line InputError."""
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            chans = f.channels()
            return {name: np.asarray(ch.pixels, dtype=np.float32) for name, ch in chans.items()}
    except FileNotFoundError:
        raise InputError(path, "EXR file does not exist", "export the run again") from None
    except Exception as exc:  # OpenEXR raises plain exceptions for truncated or foreign files
        raise InputError(path, f"cannot read this EXR ({type(exc).__name__})", "export the run again") from None


def write_png(path: Path, pixels: np.ndarray, bits: int = 8) -> Path:
    """Write [H, W, C] values in [0, 1] (already encoded: sRGB, straight alpha) as an 8 or 16-bit PNG."""
    if bits not in (8, 16):
        raise ValueError("PNG bit depth must be 8 or 16")
    top = 255.0 if bits == 8 else 65535.0
    dtype = np.uint8 if bits == 8 else np.uint16
    q = np.rint(np.clip(np.nan_to_num(pixels, nan=0.0), 0.0, 1.0) * top).astype(dtype)
    h, w, c = q.shape

    def write(tmp: str) -> None:
        out = oiio.ImageOutput.create("png")
        spec = oiio.ImageSpec(w, h, c, oiio.UINT8 if bits == 8 else oiio.UINT16)
        if c == 4:
            spec.attribute("oiio:UnassociatedAlpha", 1)  # values are straight alpha: do not premultiply
        if out is None or not out.open(tmp, spec):
            raise OSError(f"cannot write {path}: {oiio.geterror()}")
        ok = out.write_image(q)
        out.close()
        if not ok:
            raise OSError(f"cannot write {path}: {out.geterror()}")

    return atomic_write(path, write)


def image_header(path: str | Path) -> tuple[int, int, int]:
    """(width, height, bits per channel) from the file's header, without decoding pixels."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InputError(path, f"cannot open this image ({' '.join(oiio.geterror().split())})", "check the file")
    try:
        spec = inp.spec()
        return spec.width, spec.height, spec.format.size() * 8
    finally:
        inp.close()


def read_image(path: str | Path) -> tuple[np.ndarray, bool]:
    """Any image as float32 [H, W, C] in its own encoding (integers normalised, straight alpha kept
    straight), and whether the file stores floats (EXR: linear, premultiplied by convention)."""
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = oiio.ImageInput.open(str(path), config)
    if inp is None:
        raise InputError(path, f"cannot open this image ({' '.join(oiio.geterror().split())})", "check the file")
    try:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, "float")
        if pixels is None or inp.geterror():
            raise InputError(path, "cannot read this image (truncated or corrupt)", "save the image again")
        is_float = spec.format.basetype in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE)
        return np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, -1), is_float
    finally:
        inp.close()


__all__ = ["image_header", "read_exr", "read_image", "write_exr", "write_png", "write_rgba_exr"]
