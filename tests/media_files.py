"""Test fixtures written to disk exactly as given: images through OpenImageIO, movies through PyAV (whole, cut
short or garbled in the middle), an audio-only movie, and a PNG that declares a huge image in a few megabytes."""

from __future__ import annotations

import struct
import subprocess
import sys
import tempfile
import zlib
from collections.abc import Sequence
from pathlib import Path

import av
import numpy as np
import OpenImageIO as oiio

from engine.io.images import native_path


def write_image(path: Path, pixels: np.ndarray, fmt: str | None = None) -> Path:
    """Write ``pixels`` [H, W] or [H, W, C] as-is (``fmt`` defaults to the array's dtype); alpha stays
    unassociated, so straight-alpha fixtures read back unchanged."""
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    height, width, channels = pixels.shape
    fmt = fmt or {np.uint8: "uint8", np.uint16: "uint16", np.float32: "float"}[pixels.dtype.type]
    spec = oiio.ImageSpec(width, height, channels, fmt)
    spec.attribute("oiio:UnassociatedAlpha", 1)
    out = oiio.ImageOutput.create(Path(path).suffix.lstrip("."))  # the plug-in by its extension
    assert out is not None, oiio.geterror()
    assert out.open(native_path(path), spec), out.geterror()  # any name, UTF-8 or not
    assert out.write_image(np.ascontiguousarray(pixels)), out.geterror()
    out.close()
    return path


#: Mid grey in a 16-bit DPX buffer (OpenImageIO scales it to the file's 10 bits).
DPX_MID_GREY = 32768


def write_dpx(path: Path, size: tuple[int, int], transfer: str | None) -> Path:
    """A 10-bit DPX frame of mid grey whose header declares ``transfer`` (``dpx:Transfer``; None leaves it
    undefined)."""
    width, height = size
    spec = oiio.ImageSpec(width, height, 3, oiio.UINT16)
    spec.attribute("oiio:BitsPerSample", 10)
    if transfer is not None:
        spec.attribute("dpx:Transfer", transfer)
    out = oiio.ImageOutput.create("dpx")
    assert out is not None and out.open(str(path), spec), oiio.geterror()
    assert out.write_image(np.full((height, width, 3), DPX_MID_GREY, np.uint16)), out.geterror()
    out.close()
    return path


def write_audio_only_movie(path: Path) -> Path:
    """An .mp4 holding one AAC stream and no video stream."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream("aac", rate=44100)
        frame = av.AudioFrame.from_ndarray(np.zeros((1, 1024), np.float32), format="fltp", layout="mono")
        frame.sample_rate = 44100
        container.mux(stream.encode(frame))
        container.mux(stream.encode())
    return path


def write_movie(path: Path, frames: Sequence[np.ndarray], rate: int = 24) -> Path:
    """uint8 RGB ``frames`` [H, W, 3] as a yuv420p movie; the container comes from the suffix (.mp4, .mkv, .avi).

    Encoded in a fresh interpreter: in a process that has loaded torch, libx264 gives different bytes from run to
    run, and the damaged copies' messages count the packets the encoder made; a fresh process gives the same bytes
    every time. ``X264_PARAMS`` and the muxer's bitexact flag give the same bytes on every machine too."""
    with tempfile.TemporaryDirectory() as tmp:
        source = Path(tmp) / "frames.npy"
        np.save(source, np.stack([np.ascontiguousarray(f) for f in frames]))
        subprocess.run(
            [sys.executable, "-c", _ENCODE, str(source), str(path), str(rate), X264_PARAMS],
            cwd=Path(__file__).resolve().parents[1],
            check=True,
        )
    return path


#: libx264 picks SIMD code paths by the CPU (with rounding that differs) and a thread count by its cores; either
#: changes the bytes, so a damaged copy's frame counts would change from machine to machine. One thread and the
#: CPU-independent paths give the same bytes everywhere (the muxer's bitexact flag drops its version string).
X264_PARAMS = "threads=1:cpu-independent=1"

#: The encoder ``write_movie`` runs in a fresh interpreter (PyAV and numpy only).
_ENCODE = """\
import sys
import av, numpy as np
frames, path, rate = np.load(sys.argv[1]), sys.argv[2], int(sys.argv[3])
codec = "libx264" if "libx264" in av.codecs_available else "mpeg4"
options = {"x264-params": sys.argv[4]} if codec == "libx264" else {}
with av.open(path, "w", options={"fflags": "+bitexact"}) as container:
    stream = container.add_stream(codec, rate=rate, options=options)
    stream.width, stream.height, stream.pix_fmt = frames.shape[2], frames.shape[1], "yuv420p"
    for rgb in frames:
        container.mux(stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")))
    container.mux(stream.encode())
"""


def textured_frames(count: int, size: tuple[int, int] = (64, 48), seed: int = 0) -> list[np.ndarray]:
    """``count`` uint8 frames (W, H = ``size``) of noise with a moving bright square: every frame costs real bytes
    in a movie, so damage to the middle of the file lands on frames in the middle."""
    rng = np.random.default_rng(seed)
    width, height = size
    out = []
    for i in range(count):
        img = rng.integers(0, 60, (height, width, 3)).astype(np.uint8)
        x = (3 * i) % max(1, width - 16)
        img[height // 4 : height // 4 + 16, x : x + 16] = 255
        out.append(img)
    return out


def garble_movie(source: Path, target: Path, how: str) -> Path:
    """A damaged copy of a movie: ``"cut"`` keeps the first half of its bytes (a copy that stopped), ``"zeroed"``
    overwrites its middle third with zeros (a damaged disk or transfer)."""
    data = bytearray(source.read_bytes())
    size = len(data)
    if how == "cut":
        data = data[: size // 2]
    elif how == "zeroed":
        data[size // 3 : 2 * size // 3] = bytes(2 * size // 3 - size // 3)
    else:
        raise ValueError(f"unknown damage {how!r}")
    target.write_bytes(bytes(data))
    return target


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


#: Adler-32's modulus (the zlib stream's checksum).
ADLER_MOD = 65521


def write_blank_png(path: Path, width: int, height: int, channels: int = 3) -> Path:
    """A valid 8-bit PNG of ``width`` x ``height`` black pixels, built without holding or compressing the image:
    one zero row is deflated after a full flush (which resets the compressor, so every later row compresses to
    the same bytes) and repeated; the checksum of all-zero data is known in closed form. 30000x30000 RGB gives a
    3 MB file that a reader would decode into 10.8 GB of float32."""
    colour_type = {1: 0, 2: 4, 3: 2, 4: 6}[channels]
    row = bytes(1 + width * channels)  # filter byte 0, then the row's samples
    deflate = zlib.compressobj(9)
    first = deflate.compress(row) + deflate.flush(zlib.Z_FULL_FLUSH)
    again = deflate.compress(row) + deflate.flush(zlib.Z_FULL_FLUSH)
    assert deflate.compress(row) + deflate.flush(zlib.Z_FULL_FLUSH) == again, "rows do not compress alike"
    adler = ((len(row) * height) % ADLER_MOD) << 16 | 1  # Adler-32 of all-zero bytes: a stays 1, b counts them
    end = deflate.flush()[:-4] + struct.pack(">I", adler)
    idat = first + again * (height - 1) + end
    ihdr = struct.pack(">IIBBBBB", width, height, 8, colour_type, 0, 0, 0)
    png = b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr) + _png_chunk(b"IDAT", idat) + _png_chunk(b"IEND", b"")
    path.write_bytes(png)
    return path
