"""Read channels of a scanline OpenEXR file and write a plain float RGB one, in numpy (no bpy, no OpenEXR module).

Why: a shader's Image Texture node cannot pick the pass of a multilayer EXR from Python (``ImageUser.multilayer_layer``
and ``multilayer_pass`` are read-only on Blender 4.5 and 5.0, and a new node shows the file's first pass), and the
Python that Blender ships has no EXR module. The live preview therefore splits each layer's UV pass
(``Atlas.UV<Layer>.X/Y/Z``) of every pass file into a plain RGB float EXR (R=u, G=v, B=alpha) that an Image
Texture reads as it is. The values are copied bit for bit (float32), so the preview samples the same UVs as
``engine render``. Supported: single-part scanline files, compression NONE, ZIPS or ZIP (what the engine writes).
"""

from __future__ import annotations

import os
import struct
import zlib
from typing import Any

import numpy as np

MAGIC = 20000630
NO_COMPRESSION, ZIPS_COMPRESSION, ZIP_COMPRESSION = 0, 2, 3
LINES_PER_BLOCK = {NO_COMPRESSION: 1, ZIPS_COMPRESSION: 1, ZIP_COMPRESSION: 16}
#: EXR pixel types: UINT, HALF, FLOAT -> numpy little-endian dtype
PIXEL_TYPES: dict[int, np.dtype[Any]] = {0: np.dtype("<u4"), 1: np.dtype("<f2"), 2: np.dtype("<f4")}


class ExrError(ValueError):
    """A file this reader cannot read (the message names the file and why)."""


def _cstr(data: bytes, pos: int) -> tuple[str, int]:
    end = data.index(b"\0", pos)
    return data[pos:end].decode("latin-1"), end + 1


def _header(data: bytes, path: str) -> tuple[dict[str, tuple[str, bytes]], int]:
    magic, version = struct.unpack_from("<ii", data, 0)
    if magic != MAGIC:
        raise ExrError(f"{path}: not an OpenEXR file")
    if version & 0x1A00:  # tiled (0x200), deep (0x800) or multi-part (0x1000); long names (0x400) are fine
        raise ExrError(f"{path}: only single-part scanline EXR files can be read (flags {version:#x})")
    attrs: dict[str, tuple[str, bytes]] = {}
    pos = 8
    while data[pos] != 0:
        name, pos = _cstr(data, pos)
        kind, pos = _cstr(data, pos)
        (size,) = struct.unpack_from("<i", data, pos)
        pos += 4
        attrs[name] = (kind, data[pos : pos + size])
        pos += size
    return attrs, pos + 1


def _channels(raw: bytes) -> list[tuple[str, int]]:
    out, pos = [], 0
    while raw[pos] != 0:
        name, pos = _cstr(raw, pos)
        (ptype,) = struct.unpack_from("<i", raw, pos)
        out.append((name, ptype))
        pos += 16  # type, pLinear + 3 reserved, xSampling, ySampling
    return out


def unzip_block(packed: bytes, size: int) -> bytes:
    """Undo the EXR ZIP stage: inflate, undo the byte predictor, re-interleave the two halves."""
    if len(packed) == size:  # stored uncompressed when compression would not have made it smaller
        return packed
    d = np.frombuffer(zlib.decompress(packed), np.uint8).copy()
    d[1:] -= np.uint8(128)  # modulo 256, as the predictor: bytes throughout (a wider type is 8x the memory traffic)
    t = np.cumsum(d, dtype=np.uint8)
    out = np.empty_like(t)
    half = (len(t) + 1) // 2
    out[0::2], out[1::2] = t[:half], t[half:]
    return out.tobytes()


def zip_block(raw: bytes) -> bytes:
    """The EXR ZIP stage: split even/odd bytes, byte predictor, deflate (raw when that is not smaller)."""
    t = np.frombuffer(raw, np.uint8)
    inter = np.concatenate((t[0::2], t[1::2]))
    d = inter.copy()
    d[1:] = inter[1:] - inter[:-1] + np.uint8(128)  # modulo 256, in bytes
    packed = zlib.compress(d.tobytes(), 4)
    return packed if len(packed) < len(raw) else raw


def read_channels(path: str, names: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """Channels (name -> float32 [H, W], rows top-first) of a scanline EXR; ``names``: only these (all must exist)."""
    with open(path, "rb") as f:
        data = f.read()
    attrs, pos = _header(data, path)
    comp = attrs["compression"][1][0]
    if comp not in LINES_PER_BLOCK:
        raise ExrError(f"{path}: compression {comp} is not read here (NONE, ZIPS or ZIP are); re-export the passes")
    x0, y0, x1, y1 = struct.unpack("<4i", attrs["dataWindow"][1])
    w, h = x1 - x0 + 1, y1 - y0 + 1
    chans = sorted(_channels(attrs["channels"][1]))
    wanted = tuple(n for n, _ in chans) if names is None else names
    missing = [n for n in wanted if n not in {c for c, _ in chans}]
    if missing:
        raise ExrError(f"{path}: has no channel(s) {missing}; export the passes again")
    lines = LINES_PER_BLOCK[comp]
    blocks = (h + lines - 1) // lines
    offsets = struct.unpack_from(f"<{blocks}Q", data, pos)
    out = {n: np.empty((h, w), np.float32) for n, _ in chans}
    for off in offsets:
        y, size = struct.unpack_from("<ii", data, off)
        row = y - y0
        n_lines = min(lines, h - row)
        raw_size = n_lines * w * sum(PIXEL_TYPES[t].itemsize for _, t in chans)
        raw = data[off + 8 : off + 8 + size]
        block = raw if comp == NO_COMPRESSION else unzip_block(raw, raw_size)
        at = 0
        for k in range(n_lines):
            for name, ptype in chans:
                dt = PIXEL_TYPES[ptype]
                n = w * dt.itemsize
                out[name][row + k] = np.frombuffer(block, dt, w, at).astype(np.float32)
                at += n
    return {n: out[n] for n in wanted}


def write_rgb(path: str, r: np.ndarray, g: np.ndarray, b: np.ndarray, compression: int = ZIP_COMPRESSION) -> None:
    """A plain float32 RGB scanline EXR, rows top-first, written beside ``path`` and renamed onto it.
    ``compression``: ZIP (the default: the smaller file) or NONE (loads several times faster: Blender's reader only
    copies the rows; the preview's proxies, loaded on every frame change, are written so)."""
    if compression not in (ZIP_COMPRESSION, NO_COMPRESSION):
        raise ValueError(f"compression {compression}: ZIP or NONE")
    h, w = r.shape
    planes = {"B": b, "G": g, "R": r}  # EXR stores channels sorted by name

    def attr(name: str, kind: str, value: bytes) -> bytes:
        return name.encode() + b"\0" + kind.encode() + b"\0" + struct.pack("<i", len(value)) + value

    chlist = b"".join(n.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for n in planes) + b"\0"
    box = struct.pack("<4i", 0, 0, w - 1, h - 1)
    header = struct.pack("<ii", MAGIC, 2) + b"".join(
        (
            attr("channels", "chlist", chlist),
            attr("compression", "compression", bytes([compression])),
            attr("dataWindow", "box2i", box),
            attr("displayWindow", "box2i", box),
            attr("lineOrder", "lineOrder", b"\0"),
            attr("pixelAspectRatio", "float", struct.pack("<f", 1.0)),
            attr("screenWindowCenter", "v2f", struct.pack("<2f", 0.0, 0.0)),
            attr("screenWindowWidth", "float", struct.pack("<f", 1.0)),
        )
    )
    header += b"\0"
    stacked = np.stack([np.ascontiguousarray(planes[n], "<f4") for n in planes], axis=1)  # [H, C, W]
    lines = LINES_PER_BLOCK[compression]
    chunks = []
    for y in range(0, h, lines):
        raw = stacked[y : y + lines].tobytes()
        packed = raw if compression == NO_COMPRESSION else zip_block(raw)
        chunks.append(struct.pack("<ii", y, len(packed)) + packed)
    table_end = len(header) + 8 * len(chunks)
    offsets, at = [], table_end
    for c in chunks:
        offsets.append(at)
        at += len(c)
    tmp = f"{path}.na-tmp"
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(tmp, "wb") as f:
        f.write(header + struct.pack(f"<{len(offsets)}Q", *offsets) + b"".join(chunks))
    os.replace(tmp, path)
