"""The live preview at a proxy size: its UV passes and plate written smaller, so a frame change loads less. No bpy.

**Why.** On every frame change Blender loads the preview's images for the new frame: the plate and one UV pass per
layer, all at the plate's size (``preview_plan``). At 4096x2160 that is a 4K PNG and a 4K float EXR per layer: a
tick of 2.9 s on a 2-core machine, 0.44 s at half size, a quarter of the pixels (``docs/addon.md``, *Live
preview*). The edit layers (what is painted) are not proxied: they are atlases, and paint lands in them at their
own size, so painting is exactly as it is at full size; only what the preview shows of the clip is smaller. Render
Edited Clip (the compositor) and ``engine render`` read the export's own passes and the plate: the render is
full size always.

**Sizes.** Blender's proxy sizes (the Movie Clip Editor's and the Sequencer's): 25, 50, 75 and 100 % of the plate,
each side ``side * percent // 100`` (Blender's integer rule). **Auto**, the default, is the largest of them that
keeps the preview within 2K (``AUTO_LONG_EDGE`` on its longer side): a 2K plate or smaller is previewed at 100 %
(every pixel, and its tick is already short), UHD and 4K at 50 % (1920x1080, 2048x1080), 6K at 25 %. The cost of
a tick grows with the pixels loaded, so Auto keeps it about that of a 2K plate whatever the plate's size; the
panel shows the size it picked, and any of the four can be chosen instead.

**Sampling.** Each proxy pixel takes the full-size pixel under its centre (``centres``): u, v and Z of that one
pixel, unchanged, and the plate's pixel there. Not an average: averaging u and v across a layer's outline (where Z
falls to 0 and u, v belong to nothing shown) or across a seam of the atlas would give UVs of neither side, and paint
from an unrelated place of the atlas would show along every edge. Sampled so, the proxy preview is exactly the
full-size preview at those pixels (the plate and the paint line up pixel for pixel), and it is the pixel Blender's
Closest interpolation reads from the full-size image at the proxy pixel's centre. The price is aliasing: fine plate
detail shimmers at 25 % as it would in any decimated image; 100 % shows every pixel.
"""

from __future__ import annotations

import os
import struct
import zlib

import numpy as np

#: The panel's choice that picks a size from the plate's (``proxy_percent``).
AUTO = "AUTO"
#: Blender's proxy sizes, percent of the plate's sides.
PERCENTS = (25, 50, 75, 100)
FULL = 100
#: Auto: the largest proxy size whose longer side is at most this many pixels (2K).
AUTO_LONG_EDGE = 2048
#: The folder beside the manifest with each proxy size's files: ``preview_proxy/proxy_50/<Layer>/uv.#####.exr`` and
#: ``preview_proxy/proxy_50/plate.#####.png`` (or ``.exr``). Named as Blender names its proxies (``proxy_50``).
PROXY_DIR = "preview_proxy"
#: The plate's proxy files: an 8-bit plate as 8-bit PNG (its bytes as they are), a float one as float EXR
#: (scene-linear, read as Non-Color).
PLATE_BYTE_EXT, PLATE_FLOAT_EXT = ".png", ".exr"
PLATE_EXTS = (PLATE_BYTE_EXT, PLATE_FLOAT_EXT)
#: The zlib level of the plate's proxy PNGs: the fastest (the file is read on every frame change; its size matters
#: less than the time to inflate it).
PNG_LEVEL = 1


def choice_id(percent: int) -> str:
    """The panel's identifier of a proxy size."""
    return f"PROXY_{percent}"


def items() -> list[tuple[str, str, str]]:
    """The panel's choices (EnumProperty items): Auto, then Blender's four sizes."""
    auto = (
        AUTO,
        "Auto",
        f"The largest proxy size within {AUTO_LONG_EDGE} pixels on the longer side: 100% up to 2K, 50% for UHD and "
        "4K, 25% for 6K",
    )
    sizes = [
        (choice_id(p), f"{p}%", f"The preview's plate and UV passes at {p}% of the plate's size (the render is full "
         "size)" if p < FULL else "The preview at the plate's full size")
        for p in PERCENTS
    ]  # fmt: skip
    return [auto, *sizes]


def proxy_size(resolution: tuple[int, int], percent: int) -> tuple[int, int]:
    """The proxy's size: each side ``side * percent // 100`` (Blender's rule for its proxies), at least 1."""
    w, h = resolution
    return max(1, w * percent // 100), max(1, h * percent // 100)


def auto_percent(resolution: tuple[int, int]) -> int:
    """The largest proxy size whose longer side is within ``AUTO_LONG_EDGE`` (25 % when none is)."""
    fits = [p for p in PERCENTS if max(proxy_size(resolution, p)) <= AUTO_LONG_EDGE]
    return max(fits) if fits else min(PERCENTS)


def proxy_percent(choice: str, resolution: tuple[int, int]) -> int:
    """The percent a panel choice (``items``) means for a plate of ``resolution``; an unknown choice is Auto."""
    for p in PERCENTS:
        if choice == choice_id(p):
            return p
    return auto_percent(resolution)


def centres(full: int, proxy: int) -> np.ndarray:
    """For each proxy pixel k along one side (counted from the bottom or the left edge, as Blender counts), the
    full-size pixel under its centre: ``floor((k + 0.5) * full / proxy)``, in integers (exact at any size). Where
    the centre falls on the line between two pixels (at exactly 50 %: between 2k and 2k + 1) it is the upper or
    right one, which is what Closest interpolation reads there."""
    k = np.arange(proxy, dtype=np.int64)
    return (2 * k + 1) * full // (2 * proxy)


def sampled(full: tuple[int, int], size: tuple[int, int], top_first: bool) -> tuple[np.ndarray, np.ndarray]:
    """(rows, columns) of the full-size image (``full``: width, height) that make the proxy of ``size``, for
    arrays whose rows run top-first (an EXR's) or bottom-up (``top_first`` False: Blender's ``pixels``)."""
    (w, h), (pw, ph) = full, size
    rows = centres(h, ph)
    if top_first:
        rows = (h - 1 - rows)[::-1]  # the same pixels, counted from the top
    return rows, centres(w, pw)


def downsample(plane: np.ndarray, size: tuple[int, int], top_first: bool = True) -> np.ndarray:
    """``plane`` ([H, W] or [H, W, C]) at ``size`` (width, height): the pixel under each proxy pixel's centre, its
    values unchanged (``centres``)."""
    rows, cols = sampled((plane.shape[1], plane.shape[0]), size, top_first)
    return np.ascontiguousarray(plane[rows][:, cols])


def folder(manifest_path: str, percent: int) -> str:
    """Where the files of one proxy size go, beside the manifest."""
    return os.path.join(os.path.dirname(os.path.abspath(manifest_path)), PROXY_DIR, f"proxy_{percent}")


def uv_file(manifest_path: str, layer: str, frame: int, percent: int) -> str:
    return os.path.join(folder(manifest_path, percent), layer, f"uv.{frame:05d}.exr")


def plate_stem(manifest_path: str, frame: int, percent: int) -> str:
    """The plate's proxy file at scene frame ``frame``, without its extension (``PLATE_EXTS``: which one depends
    on whether Blender reads the plate as 8-bit or float)."""
    return os.path.join(folder(manifest_path, percent), f"plate.{frame:05d}")


def is_fresh(made: str, source: str) -> bool:
    """Whether ``made`` exists and is at least as new as ``source`` (else it is written again)."""
    try:
        return os.path.getmtime(made) >= os.path.getmtime(source)
    except OSError:
        return False


def write_png_rgba8(path: str, rgba8: np.ndarray, level: int = PNG_LEVEL) -> None:
    """An 8-bit RGBA PNG of ``rgba8`` ([H, W, 4] uint8, rows top-first), no row filter, written beside ``path`` and
    renamed onto it."""
    h, w, _ = rgba8.shape
    rows = np.concatenate((np.zeros((h, 1), np.uint8), np.ascontiguousarray(rgba8, np.uint8).reshape(h, w * 4)), 1)

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 6, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(rows.tobytes(), level)) + chunk(b"IEND", b"")
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = f"{path}.na-tmp"
    with open(tmp, "wb") as f:
        f.write(png)
    os.replace(tmp, path)
