"""Damage to one packet of a movie, found by demuxing it: the bytes a decoder chokes on, at a frame the test
chooses (``tests.media_files.garble_movie`` damages a fraction of the file's bytes instead)."""

from __future__ import annotations

from pathlib import Path

import av

#: Bytes inverted at the start of the packet: its NAL header and slice header, which an H.264 decoder refuses.
INVERTED_BYTES = 8


def invert_packet(source: Path, target: Path, index: int) -> Path:
    """A copy of ``source`` whose video packet ``index`` (in file order, empty packets skipped) starts with
    ``INVERTED_BYTES`` inverted bytes: the container stays whole, one frame does not decode."""
    with av.open(str(source)) as container:
        packets = [p for p in container.demux(container.streams.video[0]) if p.size]
        start = packets[index].pos
    assert start is not None and start >= 0, f"packet {index} of {source} has no file position"
    data = bytearray(source.read_bytes())
    data[start : start + INVERTED_BYTES] = bytes(b ^ 0xFF for b in data[start : start + INVERTED_BYTES])
    target.write_bytes(bytes(data))
    return target
