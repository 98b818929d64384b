"""The H.264 movie of an edit (``render --movie``, the preview's movies): sRGB frames tagged BT.709, at the
plate's exact rate, with its pixel aspect ratio and timecode (docs/colour.md).

Written to a hidden temporary file beside the movie and renamed into place once complete, so a failure, a full disk
or a cancel leaves no half movie.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from .. import contract as C
from ..errors import DiskFullError, InputError
from ..export.manifest import Manifest
from ..io.atomic import disk_full_as_one_line
from ..io.timing import exact_rate, timecode_at
from .staged_folder import STAGING_SUFFIX, first_missing

#: Frames per second of the movie when the plate has no rate (image sequences).
DEFAULT_FPS = 25.0
#: The movie's colour tags (ISO/IEC 23091-2 codes: primaries BT.709 = 1, transfer IEC 61966-2-1 sRGB = 13, matrix
#: BT.709 = 1, range MPEG/limited = 1): what a player needs to show the sRGB frames as the PNGs show.
MOVIE_COLOUR_TAGS = (1, 13, 1, 1)
#: The largest numerator or denominator of a movie's sample aspect ratio (H.264 stores two 16-bit terms).
MAX_SAR_TERM = 1000
#: H.264 constant rate factor of the movies: visually lossless, so the movie judges the edit, not the codec.
MOVIE_CRF = 18
#: FFmpeg refuses a picture whose (width + 128) x (height + 128) reaches INT_MAX / 8 pixels (``av_image_check_size``):
#: an 8K or a 16384x8640 plate is written, a 16384x16384 one is not.
MOVIE_PAD_PX = 128
MOVIE_MAX_PADDED_PIXELS = (2**31 - 1) // 8


def movie_size_problem(size: tuple[int, int]) -> str | None:
    """Why FFmpeg cannot write a movie of ``size`` (W, H) pixels, or None when it can: said before any frame is
    rendered, not as a codec error after the first."""
    w, h = size
    w, h = w + w % 2, h + h % 2  # the codec's even sides (``MovieWriter``)
    if (w + MOVIE_PAD_PX) * (h + MOVIE_PAD_PX) < MOVIE_MAX_PADDED_PIXELS:
        return None
    return f"a {w}x{h} movie is larger than FFmpeg encodes (about 268 million pixels with its padding)"


MOVIE_SIZE_FIX = "write frames instead (render without --movie, preview with --no-movies)"


def _in_the_way(folder: Path) -> Path | None:
    """The file (not a folder) that stands where ``folder`` or one of its parents should be, if any."""
    for probe in (folder, *folder.parents):
        if probe.exists():
            return None if probe.is_dir() else probe
    return None


class MovieWriter:
    """H.264 (yuv420p) through PyAV; odd sizes are padded by one pixel (the codec needs even sides). Written to a
    hidden temporary file beside the movie and renamed into place by ``publish`` (``close`` = finish + publish);
    ``abort`` removes everything it made. A folder it cannot write is one line; so is a full disk."""

    def __init__(
        self,
        path: Path,
        fps: float | Fraction | None,
        size: tuple[int, int],
        pixel_aspect: float = 1.0,
        timecode: str | None = None,
    ) -> None:
        """``fps``: the rate, kept exact (24000/1001 is written as that fraction: ``timing.exact_rate``; none:
        ``DEFAULT_FPS``); ``pixel_aspect``: the stream's sample aspect ratio (2.0: anamorphic, shown 2x wide);
        ``timecode``: the first frame's, written as the movie's timecode track."""
        import av

        self.path = Path(path)
        too_big = movie_size_problem(size)
        if too_big is not None:
            raise InputError(self.path, too_big, MOVIE_SIZE_FIX)
        self.tmp = self.path.with_name(f".{self.path.stem}{STAGING_SUFFIX}{os.getpid()}{self.path.suffix}")
        self.created = first_missing(self.path.parent)
        self.container: Any = None
        fix = "choose a --movie path in a folder you can write to"
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with disk_full_as_one_line(self.path.parent):
                self.container = av.open(str(self.tmp), mode="w")
        except DiskFullError:
            self.abort()
            raise
        except (OSError, ValueError) as exc:  # PyAV's errors are OSError / ValueError subclasses
            self.abort()
            blocker = _in_the_way(self.path.parent)
            reason = f"{blocker} is a file" if blocker else getattr(exc, "strerror", None) or type(exc).__name__
            raise InputError(self.path, f"cannot write the movie here ({reason})", fix) from None
        self.rate = exact_rate(fps) or exact_rate(DEFAULT_FPS)
        self.stream = self.container.add_stream("libx264", rate=self.rate)
        if pixel_aspect != 1.0:
            self.stream.codec_context.sample_aspect_ratio = Fraction(pixel_aspect).limit_denominator(MAX_SAR_TERM)
        if timecode is not None:
            self.stream.metadata["timecode"] = timecode
        w, h = size
        self.size = (w + w % 2, h + h % 2)
        self.stream.width, self.stream.height = self.size
        self.stream.pix_fmt = "yuv420p"
        self.stream.options = {"crf": str(MOVIE_CRF)}
        # the frames are sRGB-encoded Rec.709, converted to Y'CbCr with the BT.709 matrix (``write``), limited range
        codec = self.stream.codec_context
        codec.color_primaries, codec.color_trc, codec.colorspace, codec.color_range = MOVIE_COLOUR_TAGS
        self.frames = 0

    def write(self, rgb_u8: np.ndarray) -> None:
        import av

        h, w = rgb_u8.shape[:2]
        if (w, h) != self.size:
            rgb_u8 = np.pad(rgb_u8, ((0, self.size[1] - h), (0, self.size[0] - w), (0, 0)), mode="edge")
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb_u8), format="rgb24")
        frame = frame.reformat(format="yuv420p", dst_colorspace="itu709")  # the matrix the stream is tagged with
        with disk_full_as_one_line(self.path.parent):
            for packet in self.stream.encode(frame):
                self.container.mux(packet)
        self.frames += 1

    def written_bytes(self) -> int:
        return self.tmp.stat().st_size if self.tmp.exists() else 0

    def finish(self) -> None:
        """Encode what the codec holds back and close the file (still under its temporary name)."""
        with disk_full_as_one_line(self.path.parent):
            for packet in self.stream.encode():
                self.container.mux(packet)
            self.container.close()
        self.container = None

    def publish(self) -> Path:
        self.tmp.replace(self.path)
        return self.path

    def close(self) -> Path:
        self.finish()
        return self.publish()

    def abort(self) -> None:
        """Close (best effort) and remove the temporary file, and the folders this writer created."""
        if self.container is not None:
            with contextlib.suppress(Exception):
                self.container.close()
            self.container = None
        with contextlib.suppress(OSError):  # its folder may be no folder at all (the refusal being reported)
            self.tmp.unlink(missing_ok=True)
        if self.created is not None:
            shutil.rmtree(self.created, ignore_errors=True)


def movie_writer(
    manifest: Manifest, path: Path, default_fps: float = DEFAULT_FPS, first_frame: int | None = None
) -> MovieWriter:
    """A movie of the manifest's exported frames (from plate frame ``first_frame``, default the first exported) at
    the plate's exact rate (``default_fps`` when it states none), with its pixel aspect ratio and the timecode of its
    first frame."""
    clip = manifest.clip
    rate = C.clip_rate(clip)
    first = (manifest.frames[0] if first_frame is None else first_frame) - clip["first_frame"]
    exact = None if rate is None else Fraction(*rate)
    timecode = timecode_at(clip.get("timecode"), exact, first)
    fps = exact if exact is not None else exact_rate(default_fps)
    tc = None if timecode is None else str(timecode)
    return MovieWriter(path, fps, manifest.resolution, clip.get("pixel_aspect", 1.0), tc)


__all__ = [
    "DEFAULT_FPS",
    "MOVIE_COLOUR_TAGS",
    "MOVIE_MAX_PADDED_PIXELS",
    "MOVIE_SIZE_FIX",
    "MovieWriter",
    "movie_size_problem",
    "movie_writer",
]
