"""A frame's pass file as an export writes it: its name (the plate's frame number, padded as the plate's files
are), the size of its channels, and the STMap copy of a layer's UV pass.

Torch-free, so an export made by hand (without a fit) names and fills its passes the same way.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .. import contract as C

if TYPE_CHECKING:
    from ..fit.run_folder import ClipRecord

#: A layer's pass channels (UV X, Y, Z, alpha and the STMap copy) and their bytes uncompressed: the disk-full
#: estimate of a frame of passes before any is written.
PASS_CHANNELS_PER_LAYER = len(C.UV_CHANNELS) + len(C.ALPHA_CHANNELS) + len(C.STMAP_CHANNELS)
PASS_BYTES_PER_CHANNEL = 4


def pass_padding(clip: ClipRecord) -> int:
    """The digits of the pass files' frame numbers: the plate's own padding (``contract.frame_padding``)."""
    return C.frame_padding(clip.frame_files, clip.frame_numbers)


def pass_file(dest: Path, number: int, clip: ClipRecord) -> Path:
    return dest / C.PASSES_DIR / C.pass_file_name(number, pass_padding(clip))


def stmap_values(chans: dict[str, np.ndarray], uv_pass: str) -> tuple[np.ndarray, ...]:
    """A layer's STMap copy (contract.STMAP_CHANNELS: R, G, B, A) from its UV pass: u, v, zeros and the coverage,
    the same float32 values (not half: on a 1000-texel atlas half floats round u, v by up to a quarter texel)."""
    u, v, z = (chans[C.channel_name(uv_pass, c)] for c in C.UV_CHANNELS)
    return u, v, np.zeros_like(u), z


__all__ = [
    "PASS_BYTES_PER_CHANNEL",
    "PASS_CHANNELS_PER_LAYER",
    "pass_file",
    "pass_padding",
    "stmap_values",
]
