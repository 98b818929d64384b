"""A damaged movie is refused with the same message on every machine: the decoder's threading, which FFmpeg
would pick from the core count, never decides which error the user reads, and the test movies' bytes do not
depend on the CPU that encoded them."""

from __future__ import annotations

import hashlib
import subprocess
import sys
import tempfile
from pathlib import Path

import av
import numpy as np
import pytest

from engine.errors import InputError
from engine.io import movie as clip
from engine.io.clip import open_clip, read_frames
from engine.io.movie import DECODER_THREADS
from tests.media_files import _ENCODE, X264_PARAMS, textured_frames, write_movie
from tests.packet_damage import invert_packet
from tests.paths import ROOT

FRAMES = 40
#: The damaged packet: late enough that 16 frame threads reach the end of the file before its error surfaces.
DAMAGED_PACKET = 30
#: What a machine with 16 or more cores gets from FFmpeg's automatic frame threading.
MANY_CORE_THREADS = 16
#: The frames the decoder gives before the damaged packet (B-frames delay its output by two).
GOOD_FRAMES = 28
MESSAGE = (
    "cannot decode frame 28 ([Errno 1094995529] Invalid data found when processing input: 'avcodec_send_packet()') "
    "— re-encode the movie (e.g. with ffmpeg) or export it as an image sequence"
)


def _damaged(tmp_path: Path, container: str) -> Path:
    whole = write_movie(tmp_path / f"whole.{container}", textured_frames(FRAMES))
    return invert_packet(whole, tmp_path / f"damaged.{container}", DAMAGED_PACKET)


def _decode(path: Path, thread_type: str, threads: int) -> tuple[int, str | None]:
    """Frames decoded and the error's name, by a decoder with the given threading."""
    decoded, error = 0, None
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        stream.thread_type = thread_type
        stream.codec_context.thread_count = threads
        try:
            for packet in container.demux(stream):
                decoded += len(packet.decode())
        except av.FFmpegError as exc:
            error = type(exc).__name__
    return decoded, error


def _refusal(path: Path) -> str:
    with pytest.raises(InputError) as exc:
        read_frames(open_clip(path))
    return str(exc.value)


@pytest.mark.parametrize("container", ["mp4", "avi"])
def test_the_fixture_reads_differently_with_frame_threads(tmp_path: Path, container: str) -> None:
    """The premise: one decoder thread stops at the damaged packet; 16 frame threads reach the end first and
    the error is lost in the flush, the frame simply missing."""
    damaged = _damaged(tmp_path, container)
    assert _decode(damaged, "SLICE", DECODER_THREADS) == (GOOD_FRAMES, "InvalidDataError")
    assert _decode(damaged, "FRAME", MANY_CORE_THREADS) == (GOOD_FRAMES, None)


@pytest.mark.parametrize("container", ["mp4", "avi"])
def test_damaged_movie_message_is_the_same_on_a_many_core_machine(
    tmp_path: Path, container: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """FFmpeg's automatic threading gives a 16-core machine 16 frame threads. Simulated by opening every
    container with them preset: the message is still the one-thread one, word for word (it was "the decoder
    gave 28 frames for the 40 the file holds" there, and this one on a 2-core machine)."""
    damaged = _damaged(tmp_path, container)
    expected = f"{damaged}: {MESSAGE}"
    assert _refusal(damaged) == expected

    opened = clip._open_container

    def many_core_defaults(path: str) -> av.container.InputContainer:
        container = opened(path)
        for stream in container.streams.video:
            stream.thread_type = "FRAME"
            stream.codec_context.thread_count = MANY_CORE_THREADS
        return container

    monkeypatch.setattr(clip, "_open_container", many_core_defaults)
    assert _refusal(damaged) == expected


def _encode_without_simd(frames: np.ndarray, path: Path) -> Path:
    """``write_movie``'s encoder with x264's assembly switched off: the plain-C paths a CPU without SIMD runs."""
    with tempfile.TemporaryDirectory() as tmp:
        source = Path(tmp) / "frames.npy"
        np.save(source, frames)
        params = f"{X264_PARAMS}:asm=0"
        subprocess.run([sys.executable, "-c", _ENCODE, str(source), str(path), "24", params], cwd=ROOT, check=True)
    return path


@pytest.mark.parametrize("container", ["mp4", "mkv", "avi"])
def test_test_movies_are_the_same_bytes_on_every_cpu(tmp_path: Path, container: str) -> None:
    """x264's SIMD paths round differently from its C paths (a damaged .avi held 22 packets on one machine and 21
    on another); ``write_movie`` asks for the CPU-independent ones, so its bytes equal an encode with no SIMD."""
    frames = textured_frames(FRAMES)
    ours = write_movie(tmp_path / f"simd.{container}", frames)
    plain = _encode_without_simd(np.stack(frames), tmp_path / f"plain.{container}")
    assert hashlib.sha256(ours.read_bytes()).hexdigest() == hashlib.sha256(plain.read_bytes()).hexdigest()
