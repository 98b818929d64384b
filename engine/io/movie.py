"""Opening and decoding a movie file (PyAV), exactly: every frame from the start, no seeking.

A movie whose decoder stops early or skips frames is refused, naming the file: a fit of the frames that did
decode would be the wrong frames, or too few, without a word. Movies are decoded on one thread
(``DECODER_THREADS``), so a damaged one is refused with the same message on every machine.
"""

from __future__ import annotations

from collections.abc import Iterator
from fractions import Fraction

import av
import numpy as np

from ..errors import InputError
from .clip_info import MOVIE, ClipInfo, ColourChoice, check_range
from .clip_messages import one_line
from .timing import exact_rate, pixel_aspect, timecode_at

MOVIE_EXTENSIONS: tuple[str, ...] = (".mp4", ".mov", ".mkv", ".avi", ".webm", ".m4v")


#: A movie whose header stores no frame count (mkv, webm, some avi) is counted by its packets. When they cover
#: less than this fraction of the frames its duration declares (less one frame, for rounding), frames are
#: missing: the file is truncated or corrupt.
MOVIE_DURATION_COVERAGE = 0.95


#: Movies are decoded on one thread. With frame threads (FFmpeg's default picks one per core, up to 16) a corrupt
#: packet's error surfaces packets later, or not at all when it lands in the final flush, so one damaged file would
#: be refused with "cannot decode frame N" on a small machine and "the decoder gave N frames" on a large one.
#: Decoding is a small part of reading a frame (the RGB conversion costs more), so the threads buy little.
DECODER_THREADS = 1


_MOVIE_FIX = "re-encode the movie (e.g. with ffmpeg) or export it as an image sequence"


def open_movie(path: str, frame_range: tuple[int, int] | None, plate: ColourChoice, start_frame: int = 0) -> ClipInfo:
    with _open_container(path) as container:
        stream = _video_stream(container, path)
        rate = stream.average_rate or stream.guessed_rate
        aspect = stream.sample_aspect_ratio
        stamp = next((s.metadata["timecode"] for s in container.streams if "timecode" in s.metadata), None)
        stamp = stamp or container.metadata.get("timecode")
        count = stream.frames
        only_stream = len(container.streams) == 1
        duration = container.duration / av.time_base if container.duration else None
        _one_decoder_thread(stream)
        try:
            frame = next(container.decode(stream), None)
        except av.FFmpegError as exc:
            raise InputError(path, f"cannot decode the first frame ({one_line(exc)})", _MOVIE_FIX) from exc
    if frame is None:
        raise InputError(path, "the video stream has no frames", _MOVIE_FIX)
    if count <= 0:  # the container has no frame count (mkv, webm, some avi): count the packets instead
        count = _count_packets(path, float(rate) if rate else None, duration if only_stream else None)
    first, last = check_range(path, frame_range, count)
    exact = exact_rate(Fraction(rate)) if rate else None
    timecode = timecode_at(stamp, exact, first)
    decided = plate.decide(path, None)
    return ClipInfo(
        source=path,
        kind=MOVIE,
        frame_files=(),
        frame_numbers=tuple(range(start_frame + first, start_frame + last + 1)),
        width=frame.width,
        height=frame.height,
        fps=float(rate) if rate else None,
        colorspace=decided.space,
        channels=len(frame.format.components),
        colour_config=plate.config,
        colour_source=decided.source,
        colour_note=decided.note,
        rate=exact,
        pixel_aspect=pixel_aspect(float(aspect)) if aspect else 1.0,
        timecode=None if timecode is None else str(timecode),
        start_frame=start_frame,
    )


def _open_container(path: str) -> av.container.InputContainer:
    try:
        return av.open(path)
    except (av.FFmpegError, OSError, ValueError, UnicodeError) as exc:
        raise InputError(path, f"cannot open the movie ({one_line(exc)})", _MOVIE_FIX) from exc


def _video_stream(container: av.container.InputContainer, path: str) -> av.VideoStream:
    if not container.streams.video:
        raise InputError(
            path,
            "has no video stream",
            "pass a movie file with a video stream, or a folder holding an image sequence",
        )
    return container.streams.video[0]


def _count_packets(path: str, rate: float | None = None, duration: float | None = None) -> int:
    """Frame count by demuxing (cheap: no decoding) for containers whose header does not store it.

    With the stream's ``rate`` the count is checked against the span of the packets' timestamps and, when given,
    the container's declared ``duration`` (seconds; pass it only for a file whose one stream is this video): a
    demuxer that resynchronises past garbage, or a file cut short, yields fewer packets than the movie declares,
    and a fit of those would be the wrong frames or too few.
    """
    with _open_container(path) as container:
        stream = _video_stream(container, path)
        stamps = []
        try:
            for packet in container.demux(stream):
                if packet.size and not packet.is_discard:
                    stamps.append(packet.pts)
        except av.FFmpegError as exc:
            raise InputError(path, f"cannot read the movie ({one_line(exc)})", _MOVIE_FIX) from exc
        time_base = float(stream.time_base) if stream.time_base else None
    count = len(stamps)
    declared = []
    timed = [t for t in stamps if t is not None]
    if rate and time_base and len(timed) > 1:
        declared.append(("its timestamps span", (max(timed) - min(timed)) * time_base * rate + 1))
    if rate and duration:
        declared.append((f"its declared duration ({duration:.2f} s at {rate:g} fps) holds", duration * rate))
    for what, frames in declared:
        if count + 1 < MOVIE_DURATION_COVERAGE * frames:
            raise InputError(
                path,
                f"only {count} frames can be read but {what} {round(frames)}: the file is truncated or corrupt",
                _MOVIE_FIX,
            )
    return count


def movie_frame_count(path: str) -> int:
    """The movie's frame count: its header's, else its packets counted (``_count_packets``)."""
    with _open_container(path) as container:
        count = _video_stream(container, path).frames
    return count if count > 0 else _count_packets(path)


def _one_decoder_thread(stream: av.VideoStream) -> None:
    """Give ``stream`` the decoder threading every read uses (``DECODER_THREADS``), before its first packet."""
    stream.thread_type = "SLICE"
    stream.codec_context.thread_count = DECODER_THREADS


def _decoded_frames(
    container: av.container.InputContainer, stream: av.VideoStream, path: str
) -> Iterator[av.VideoFrame]:
    """Every frame of the stream in order, then a check that the decoder gave one frame per packet it was fed.

    A decoder that meets a corrupt packet may drop its frame and carry on: every later frame would then be
    fitted under the wrong number. The whole stream is decoded (frames after the selection are not converted)
    so a dropped frame anywhere is a one-line refusal naming the file. (Timestamps cannot tell: some containers,
    AVI among them, carry none that follow the presentation order.)
    """
    fed = decoded = 0
    for packet in container.demux(stream):
        if packet.size and not packet.is_discard:
            fed += 1
        for frame in packet.decode():
            decoded += 1
            yield frame
    if decoded < fed:
        raise InputError(
            path,
            f"the decoder gave {decoded} frames for the {fed} the file holds: frames are corrupt and were dropped",
            _MOVIE_FIX,
        )


def decode_movie(info: ClipInfo) -> Iterator[np.ndarray]:
    """Yield the selected frames as float32 RGB in [0, 1], decoding from the start (exact, no seeking)."""
    first, last = info.frame_numbers[0] - info.start_frame, info.frame_numbers[-1] - info.start_frame
    produced = 0
    with _open_container(info.source) as container:
        stream = _video_stream(container, info.source)
        _one_decoder_thread(stream)
        try:
            for index, frame in enumerate(_decoded_frames(container, stream, info.source)):
                if not first <= index <= last:
                    continue  # decoded to the end all the same: a frame dropped later is refused too
                if (frame.width, frame.height) != (info.width, info.height):
                    raise InputError(
                        info.source,
                        f"frame {index} is {frame.width}x{frame.height} but the movie is {info.width}x{info.height}",
                        _MOVIE_FIX,
                    )
                deep = max(c.bits for c in frame.format.components) > 8
                if deep:
                    rgb = frame.to_ndarray(format="rgb48le").astype(np.float32) / 65535.0
                else:
                    rgb = frame.to_ndarray(format="rgb24").astype(np.float32) / 255.0
                yield rgb
                produced += 1
        except av.FFmpegError as exc:
            raise InputError(
                info.source, f"cannot decode frame {first + produced} ({one_line(exc)})", _MOVIE_FIX
            ) from exc
    if produced < info.num_frames:
        raise InputError(
            info.source,
            f"the decoder stopped after frame {first + produced - 1} but the movie declares frames up to {last} "
            f"(frames {first}..{last} were selected): the file is truncated or corrupt",
            f"{_MOVIE_FIX}, or choose a frame range that ends earlier",
        )
