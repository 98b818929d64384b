"""Reading one image of a clip (a frame or a mask) through OpenImageIO, in the file's own encoding.

An image is decoded only when its header declares a size within ``engine.io.images.MAX_DECODED_BYTES``; a path that
is not valid UTF-8 reads like any other (``engine.io.images.native_path``). Any decoder complaint, even with partial
pixels, counts as a corrupt file: a fit of half a frame would be wrong without a word.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import OpenImageIO as oiio

from ..errors import InputError
from . import colour
from .clip_messages import Role, one_line
from .images import check_declared_size, open_image_input

_FLOAT_TYPES = (oiio.FLOAT, oiio.HALF, oiio.DOUBLE)


# --- reading one image through OpenImageIO ------------------------------------------------------------


@dataclass(frozen=True)
class _Image:
    """One decoded image, pixels in its display window, as float32 [H, W, C] in the file's encoding."""

    path: str
    pixels: np.ndarray
    channel_names: tuple[str, ...]
    alpha_channel: int
    is_float: bool
    spec: oiio.ImageSpec
    """The file's header (colour and timing facts are read from it: the file is not opened again)."""

    @property
    def width(self) -> int:
        return self.pixels.shape[1]

    @property
    def height(self) -> int:
        return self.pixels.shape[0]

    @property
    def channels(self) -> int:
        return self.pixels.shape[2]

    def _colour_channels(self) -> list[int]:
        return [i for i in range(self.channels) if i != self.alpha_channel]

    def rgb(self) -> np.ndarray:
        """[H, W, 3]: R,G,B by name when present (EXR can hold extra channels), grey replicated."""
        upper = [n.upper() for n in self.channel_names]
        if all(c in upper for c in "RGB"):
            index = [upper.index(c) for c in "RGB"]
        else:
            colour = self._colour_channels()
            if len(colour) == 1:
                index = colour * 3
            elif len(colour) >= 3:
                index = colour[:3]
            else:
                raise InputError(
                    self.path,
                    f"has channels {', '.join(self.channel_names)}, which are neither grey nor RGB",
                    "export the frames as RGB, RGBA or greyscale images",
                )
        return np.ascontiguousarray(self.pixels[:, :, index])

    def matte(self) -> np.ndarray:
        """[H, W] coverage: a varying alpha if there is one, else the max over colour channels."""
        pixels = np.nan_to_num(self.pixels, nan=0.0, posinf=1.0, neginf=0.0)
        colour = self._colour_channels()
        if self.alpha_channel >= 0:
            alpha = pixels[:, :, self.alpha_channel]
            if not colour or alpha.min() != alpha.max():
                return np.ascontiguousarray(alpha)
        return pixels[:, :, colour].max(axis=2)


def _read_config() -> oiio.ImageSpec:
    # Keep colour as written: by default OIIO premultiplies PNG/TIFF colour by alpha on read, which
    # would darken the plate wherever an exporter left a partial alpha we are about to drop anyway.
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    return config


@contextlib.contextmanager
def _quiet_codec_stderr() -> Iterator[None]:
    """Silence file descriptor 2 while a codec library decodes.

    libpng, libjpeg and OpenEXR print their complaints about a corrupt file straight to fd 2, which would
    put extra lines around our one-line error; OIIO's ``geterror()`` already carries the same text into it.
    """
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no usable fd 2 (embedded interpreter): nothing to silence
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


def _open_image(path: str, role: Role) -> oiio.ImageInput:
    """The open image, its header checked: a size beyond ``images.MAX_DECODED_BYTES`` is refused before decoding."""
    inp = open_image_input(path, _read_config())
    if inp is None:
        raise InputError(path, f"cannot open this {role.noun} image ({one_line(oiio.geterror())})", role.corrupt_fix)
    try:
        check_declared_size(path, inp.spec(), role.noun)
    except InputError:
        inp.close()
        raise
    return inp


def read_header(path: str, role: Role) -> tuple[int, int, bool, colour.FileColour]:
    """(width, height) of the display window, whether the pixels are floats and the colour facts, from the header
    only."""
    with _quiet_codec_stderr():
        inp = _open_image(path, role)
    try:
        spec = inp.spec()
        is_float = spec.format.basetype in _FLOAT_TYPES
        return spec.full_width or spec.width, spec.full_height or spec.height, is_float, colour.file_colour(spec, path)
    finally:
        inp.close()


def decode_image(path: str, role: Role) -> _Image:
    """Decode subimage 0; any decoder complaint (even with partial pixels) counts as corrupt."""
    with _quiet_codec_stderr():
        inp = _open_image(path, role)
    try:
        spec = inp.spec()
        with _quiet_codec_stderr():
            pixels = inp.read_image(0, 0, 0, spec.nchannels, "float")  # integers come back normalised
        error = inp.geterror()
        if pixels is None or error:
            raise InputError(path, f"cannot read this {role.noun} ({one_line(error)})", role.corrupt_fix)
        return _Image(
            path=path,
            pixels=_display_window(pixels.reshape(spec.height, spec.width, -1), spec),
            channel_names=tuple(spec.channelnames),
            alpha_channel=spec.alpha_channel,
            is_float=spec.format.basetype in _FLOAT_TYPES,
            spec=spec,
        )
    finally:
        inp.close()


def _display_window(pixels: np.ndarray, spec: oiio.ImageSpec) -> np.ndarray:
    """Place an EXR's data window (bounding box) into its display window, zeros outside."""
    fx, fy = spec.full_x, spec.full_y
    fw, fh = spec.full_width or spec.width, spec.full_height or spec.height
    if (spec.x, spec.y, spec.width, spec.height) == (fx, fy, fw, fh):
        return pixels
    out = np.zeros((fh, fw, pixels.shape[2]), dtype=np.float32)
    x0, x1 = max(spec.x, fx), min(spec.x + spec.width, fx + fw)
    y0, y1 = max(spec.y, fy), min(spec.y + spec.height, fy + fh)
    if x0 < x1 and y0 < y1:
        out[y0 - fy : y1 - fy, x0 - fx : x1 - fx] = pixels[y0 - spec.y : y1 - spec.y, x0 - spec.x : x1 - spec.x]
    return out
