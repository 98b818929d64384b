"""Image files the export reads and writes: float EXR (named channels), 8/16-bit PNG, atomically.

Every write goes to a hidden temp file in the destination folder and is renamed into place, so a killed
export or render never leaves a half-written file where a compositor would pick it up. Channel data is
float32, row 0 at the top (the file convention; Blender flips to bottom-up on load).

Two guards every reader of an image shares (``engine.io.image_reader`` too):

- an image is decoded only when its header declares no more than ``MAX_DECODED_BYTES`` (``check_declared_size``):
  a few megabytes of PNG can declare 30000x30000 pixels, which would ask for 10.8 GB before a single pixel is
  checked; refusing on the header keeps a corrupt or hostile file from exhausting the machine;
- a path whose bytes are not UTF-8 (a Linux name from another encoding reaches Python as surrogate escapes)
  is handed to the C libraries as bytes (``native_path``), which they accept, so such a file reads and writes
  like any other, and shown in messages with its odd bytes as ``\\xNN`` (``display_path``).
"""

from __future__ import annotations

import os
from fractions import Fraction
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import OpenEXR
import OpenImageIO as oiio

from ..errors import InputError
from .atomic import atomic_write, signals_held
from .timing import timecode_at

#: Every image is decoded as float32: the bytes per channel a decode allocates, whatever the file stores.
DECODED_BYTES_PER_CHANNEL = 4
#: The largest image the engine decodes: 16k x 16k RGBA as float32 (4 GiB). A real plate is far smaller (an 8K
#: RGBA float frame is 0.57 GB); a header asking for more is corrupt or hostile, and refused before decoding.
MAX_DECODED_SIDE = 16384
MAX_DECODED_BYTES = MAX_DECODED_SIDE * MAX_DECODED_SIDE * 4 * DECODED_BYTES_PER_CHANNEL
#: Bytes in the gigabyte of the size messages.
GB = 1e9
_OVERSIZED_FIX = "re-export it at its real size (a header this large is usually a corrupt or truncated file)"


def native_path(path: str | os.PathLike[str]) -> str | bytes:
    """``path`` as OpenImageIO and OpenEXR take it: the text when it is valid UTF-8, else the file system's bytes
    (their text conversion refuses the surrogate escapes that stand for a name's undecodable bytes)."""
    text = os.fspath(path)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return os.fsencode(text)
    return text


def display_path(path: str | os.PathLike[str]) -> str:
    """``path`` as text any terminal, log or JSON file takes: bytes that are not UTF-8 shown as ``\\xNN``."""
    return os.fsencode(os.fspath(path)).decode("utf-8", "backslashreplace")


def cv2_write(path: str | os.PathLike[str], image: np.ndarray) -> None:
    """Write ``image`` (OpenCV's BGR order) in the format of ``path``'s suffix. Encoded in memory and written by
    Python: OpenCV's own file functions take a path only as UTF-8 text and crash on any other name."""
    ok, encoded = cv2.imencode(Path(path).suffix or ".png", image)
    if not ok:
        raise OSError(f"could not encode {display_path(path)}")
    with open(path, "wb") as f:
        f.write(encoded.tobytes())


def cv2_read(path: str | os.PathLike[str], flags: int = cv2.IMREAD_UNCHANGED) -> np.ndarray | None:
    """An image as OpenCV decodes it (BGR order), read by Python (any path); None when it cannot be decoded."""
    data = np.fromfile(path, np.uint8)
    return cv2.imdecode(data, flags) if data.size else None


def open_image_input(path: str | os.PathLike[str], config: oiio.ImageSpec | None = None) -> oiio.ImageInput | None:
    """``oiio.ImageInput.open`` of any path (``native_path``); None when OpenImageIO cannot open it."""
    name = native_path(path)
    # the binding takes bytes as well as text (its stubs name only str)
    if config is None:
        return oiio.ImageInput.open(name)  # type: ignore[arg-type]
    return oiio.ImageInput.open(name, config)  # type: ignore[arg-type]


def declared_bytes(spec: oiio.ImageSpec) -> int:
    """What decoding the image of ``spec`` allocates: its data window, or its display window when larger (the
    pixels are placed into it), times its channels, as float32."""
    width = max(spec.width, spec.full_width)
    height = max(spec.height, spec.full_height)
    return width * height * max(spec.nchannels, 1) * DECODED_BYTES_PER_CHANNEL


def check_declared_size(path: str | os.PathLike[str], spec: oiio.ImageSpec, noun: str = "image") -> None:
    """Refuse, in one line naming the file, its declared size and the cap, an image whose header asks for more
    than ``MAX_DECODED_BYTES`` decoded: checked before a pixel is read."""
    need = declared_bytes(spec)
    if need <= MAX_DECODED_BYTES:
        return
    width, height = max(spec.width, spec.full_width), max(spec.height, spec.full_height)
    raise InputError(
        display_path(path),
        f"this {noun} declares {width}x{height} pixels with {spec.nchannels} channels ({need / GB:.1f} GB "
        f"decoded), more than the {MAX_DECODED_BYTES / GB:.1f} GB limit ({MAX_DECODED_SIDE}x{MAX_DECODED_SIDE} "
        "RGBA float)",
        _OVERSIZED_FIX,
    )


def write_exr(
    path: Path,
    channels: dict[str, np.ndarray],
    compression: str = "zip",
    chromaticities: tuple[float, ...] | None = None,
    attributes: dict[str, Any] | None = None,
) -> Path:
    """Write float32 ``channels`` (name -> [H, W]) to one scanline EXR part, atomically. ``chromaticities``
    (rx, ry, gx, gy, bx, by, wx, wy) tag the colour's primaries and white (``engine.io.colour.chromaticities``);
    ``attributes`` are added to its header (``oiio:ColorSpace`` names the colour space for OCIO readers;
    ``exr_timing``: frame rate, pixel aspect ratio, timecode)."""
    shapes = {c.shape for c in channels.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"EXR channels must share one [H, W] shape, got {shapes}")
    comp = {"zip": OpenEXR.ZIP_COMPRESSION, "piz": OpenEXR.PIZ_COMPRESSION, "none": OpenEXR.NO_COMPRESSION}[compression]
    data = {name: np.ascontiguousarray(c, dtype=np.float32) for name, c in channels.items()}
    header: dict[str, Any] = {"compression": comp, "type": OpenEXR.scanlineimage}
    if chromaticities is not None:
        header["chromaticities"] = tuple(float(v) for v in chromaticities)
    header.update(attributes or {})

    def write(tmp: str) -> None:
        with OpenEXR.File(header, data) as f:
            f.write(native_path(tmp))

    return atomic_write(path, write)


def write_rgba_exr(
    path: Path,
    rgba: np.ndarray,
    chromaticities: tuple[float, ...] | None = None,
    colorspace: str | None = None,
    attributes: dict[str, Any] | None = None,
) -> Path:
    """An ordinary (single-layer) RGBA or RGB float EXR, tagged with its chromaticities and colour space
    (``attributes``: added to its header)."""
    names = "RGBA"[: rgba.shape[2]]
    tags: dict[str, Any] = {"oiio:ColorSpace": colorspace} if colorspace else {}
    tags.update(attributes or {})
    return write_exr(path, {n: rgba[..., i] for i, n in enumerate(names)}, "zip", chromaticities, tags)


#: Header attributes of a plate frame that ``write_like`` carries into a file written in its image (the bit depth,
#: the DPX transfer and the colour tags: what a reader needs to decode the values the same way).
LIKE_ATTRIBUTES = ("oiio:BitsPerSample", "dpx:Transfer", "dpx:Colorimetric", "chromaticities", "compression")


def write_like(path: Path, rgb: np.ndarray, plate: oiio.ImageSpec) -> Path:
    """Write [H, W, 3] values (in the file's own encoding: integers as [0, 1]) in ``path``'s file type with the pixel
    type and bit depth of the header ``plate`` (a plate frame's, ``read_spec``), atomically: a plate's code values
    come back exactly."""
    h, w = rgb.shape[:2]
    spec = oiio.ImageSpec(w, h, 3, plate.format)
    for name in LIKE_ATTRIBUTES:
        value = plate.getattribute(name)
        if isinstance(value, tuple):  # chromaticities: float[8]
            spec.attribute(name, oiio.TypeDesc(f"float[{len(value)}]"), value)
        elif value is not None:
            spec.attribute(name, value)
    ext = os.path.splitext(os.fspath(path))[1].lstrip(".")
    return _write_oiio(path, ext, spec, np.ascontiguousarray(rgb, dtype=np.float32))


def _write_oiio(path: Path, file_format: str, spec: oiio.ImageSpec, pixels: np.ndarray) -> Path:
    """Write one image with OpenImageIO's ``file_format`` writer (a name or an extension), atomically. The open,
    write and close run with SIGINT/SIGTERM held: a cancel that lands between them would otherwise close a file with
    no pixel data, and the codec (libpng: "No IDATs written into file") prints its complaint past the one-line
    message."""

    def write(tmp: str) -> None:
        with signals_held():
            out = oiio.ImageOutput.create(file_format)
            if out is None or not out.open(native_path(tmp), spec):  # type: ignore[arg-type]  # bytes taken too
                raise OSError(f"cannot write {path}: {oiio.geterror()}")
            ok = out.write_image(pixels)
            out.close()
        if not ok:
            raise OSError(f"cannot write {path}: {out.geterror()}")

    return atomic_write(path, write)


def exr_timing(
    rate: tuple[int, int] | None, pixel_aspect: float, first_timecode: str | None = None, offset: int = 0
) -> dict[str, Any]:
    """The standard OpenEXR header attributes of a frame's timing, the plate's carried into every pass and render so
    a compositor lines them up with it: ``framesPerSecond`` (a rational: 24000/1001 stays exact),
    ``pixelAspectRatio`` and ``timeCode`` (SMPTE 12M, what Nuke, RV and OIIO show): ``first_timecode`` (the clip's
    first frame) plus ``offset`` frames. Absent values are left out (OpenEXR's defaults: no rate, no timecode)."""
    exact = None if rate is None else Fraction(*rate)
    header: dict[str, Any] = {"pixelAspectRatio": float(pixel_aspect)}
    if exact is not None:
        header["framesPerSecond"] = exact
    timecode = timecode_at(first_timecode, exact, offset)
    if timecode is not None:
        code = OpenEXR.TimeCode()
        code.hours, code.minutes, code.seconds, code.frame = timecode.fields()
        code.dropFrame = timecode.drop
        header["timeCode"] = code
    return header


def read_exr(path: str | Path) -> dict[str, np.ndarray]:
    """All channels of an EXR as float32 [H, W] arrays by full name; a bad file is a one-line InputError."""
    try:
        with OpenEXR.File(native_path(path), separate_channels=True) as f:
            chans = f.channels()
            return {name: np.asarray(ch.pixels, dtype=np.float32) for name, ch in chans.items()}
    except FileNotFoundError:
        raise InputError(path, "EXR file does not exist", "export the run again") from None
    except Exception as exc:  # OpenEXR raises plain exceptions for truncated or foreign files
        raise InputError(path, f"cannot read this EXR ({type(exc).__name__})", "export the run again") from None


def write_png(path: Path, pixels: np.ndarray, bits: int = 8, srgb: bool = True) -> Path:
    """Write [H, W, C] values in [0, 1] (already encoded: sRGB, straight alpha) as an 8 or 16-bit PNG, with its
    sRGB chunk (``srgb``; data such as masks are written without it)."""
    if bits not in (8, 16):
        raise ValueError("PNG bit depth must be 8 or 16")
    top = 255.0 if bits == 8 else 65535.0
    dtype = np.uint8 if bits == 8 else np.uint16
    q = np.rint(np.clip(np.nan_to_num(pixels, nan=0.0), 0.0, 1.0) * top).astype(dtype)
    h, w, c = q.shape
    spec = oiio.ImageSpec(w, h, c, oiio.UINT8 if bits == 8 else oiio.UINT16)
    if srgb:
        spec.attribute("oiio:ColorSpace", "sRGB")  # OIIO writes the PNG sRGB chunk for it
    if c == 4:
        spec.attribute("oiio:UnassociatedAlpha", 1)  # values are straight alpha: do not premultiply
    return _write_oiio(path, "png", spec, q)


def read_spec(path: str | Path) -> oiio.ImageSpec:
    """The file's header (OpenImageIO's spec), without decoding pixels; a file that cannot be opened is one line."""
    inp = open_image_input(path)
    if inp is None:
        raise InputError(path, f"cannot open this image ({' '.join(oiio.geterror().split())})", "check the file")
    try:
        return inp.spec()
    finally:
        inp.close()


def image_header(path: str | Path) -> tuple[int, int, int]:
    """(width, height, bits per channel) from the file's header, without decoding pixels."""
    spec = read_spec(path)
    return spec.width, spec.height, spec.format.size() * 8


def read_image(path: str | Path) -> tuple[np.ndarray, bool]:
    """Any image as float32 [H, W, C] in its own encoding (integers normalised, straight alpha kept
    straight), and whether the file stores floats (EXR: linear, premultiplied by convention)."""
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    inp = open_image_input(path, config)
    if inp is None:
        raise InputError(path, f"cannot open this image ({' '.join(oiio.geterror().split())})", "check the file")
    try:
        spec = inp.spec()
        check_declared_size(path, spec)
        pixels = inp.read_image(0, 0, 0, spec.nchannels, "float")
        if pixels is None or inp.geterror():
            raise InputError(path, "cannot read this image (truncated or corrupt)", "save the image again")
        is_float = spec.format.basetype in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE)
        return np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, -1), is_float
    finally:
        inp.close()


__all__ = [
    "MAX_DECODED_BYTES",
    "check_declared_size",
    "declared_bytes",
    "display_path",
    "image_header",
    "native_path",
    "open_image_input",
    "read_exr",
    "read_image",
    "read_spec",
    "write_exr",
    "write_png",
    "write_rgba_exr",
]
