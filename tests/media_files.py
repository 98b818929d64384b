"""Test fixtures written to disk exactly as given: images through OpenImageIO, an audio-only movie."""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np
import OpenImageIO as oiio


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
    out = oiio.ImageOutput.create(str(path))
    assert out is not None, oiio.geterror()
    assert out.open(str(path), spec), out.geterror()
    assert out.write_image(np.ascontiguousarray(pixels)), out.geterror()
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
