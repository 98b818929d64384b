"""The image readers and writers (``engine.io.images``) with files that could break them: an EXR whose display
window asks for gigabytes around a few pixels of data, and files in a folder whose name is not UTF-8."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from engine import contract as C
from engine.errors import InputError
from engine.io.clip import open_clip
from engine.io.images import (
    MAX_DECODED_BYTES,
    display_path,
    image_header,
    native_path,
    read_exr,
    read_image,
    write_exr,
    write_png,
)
from tests.folders import non_utf8_folder
from tests.media_files import write_image

#: The display window of the hostile EXR: 30000 x 30000 RGB floats, 10.8 GB once placed into it.
HUGE_SIDE = 30000


def _exr_with_display_window(path: Path, side: int) -> Path:
    """A valid EXR of 4x2 black pixels whose display window is ``side`` x ``side``: the reader places the data into
    the display window, so decoding it would allocate the whole window."""
    header = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        "dataWindow": (np.array([0, 0], np.int32), np.array([3, 1], np.int32)),
        "displayWindow": (np.array([0, 0], np.int32), np.array([side - 1, side - 1], np.int32)),
    }
    channels = {name: np.zeros((2, 4), np.float32) for name in "RGB"}
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))
    return path


def test_exr_whose_display_window_is_huge_is_refused_before_decoding(tmp_path: Path) -> None:
    """A few hundred bytes that declare a 30000x30000 display window: the cap counts the larger of the data and
    display windows, so the frame is refused on its header, in one line naming it and the sizes."""
    folder = tmp_path / "frames"
    folder.mkdir()
    exr = _exr_with_display_window(folder / "00000.exr", HUGE_SIDE)
    assert exr.stat().st_size < 4096
    with pytest.raises(InputError) as exc:
        open_clip(folder)
    message = str(exc.value)
    assert "\n" not in message and "00000.exr" in message and f"{HUGE_SIDE}x{HUGE_SIDE}" in message
    assert "10.8 GB" in message and f"{MAX_DECODED_BYTES / 1e9:.1f} GB limit" in message


def test_an_exr_with_a_real_crop_window_still_reads(tmp_path: Path) -> None:
    """A render region (data window inside a 64x48 display window) is far under the cap and reads as before."""
    folder = tmp_path / "frames"
    folder.mkdir()
    _exr_with_display_window(folder / "00000.exr", 64)
    info = open_clip(folder)
    assert (info.width, info.height, info.colorspace) == (64, 64, C.COLOUR_SCENE_LINEAR)


@pytest.fixture
def latin1_folder(tmp_path: Path) -> Path:
    """A folder named with a Latin-1 byte (not UTF-8): Python holds it as a surrogate escape."""
    return non_utf8_folder(tmp_path, b"d\xe9j\xe0_vu")


def test_exr_and_png_read_and_write_in_a_folder_whose_name_is_not_utf8(latin1_folder: Path) -> None:
    """OpenImageIO and OpenEXR refuse such a name as text (a TypeError, a ValueError); the readers and writers hand
    them its bytes, so passes, atlases and edit layers work there like anywhere else."""
    rgb = np.random.default_rng(0).uniform(0, 1, (6, 8, 3)).astype(np.float32)
    exr = write_exr(latin1_folder / "pass.exr", {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2]})
    back = read_exr(exr)
    np.testing.assert_array_equal(np.stack([back[c] for c in "RGB"], -1), rgb)
    png = write_png(latin1_folder / "edit.png", rgb, bits=16)
    pixels, is_float = read_image(png)
    assert not is_float and np.abs(pixels - rgb).max() <= 0.5 / 65535 + 1e-7
    assert image_header(png) == (8, 6, 16)
    grey = write_image(latin1_folder / "grey.png", np.full((6, 8), 255, np.uint8))
    assert read_image(grey)[0].min() == 1.0


def test_native_and_display_path() -> None:
    odd = os.fsdecode(b"/plates/d\xe9j\xe0")
    assert native_path("/plates/déjà") == "/plates/déjà"  # valid UTF-8 stays text
    assert native_path(odd) == b"/plates/d\xe9j\xe0"
    assert display_path(odd) == "/plates/d\\xe9j\\xe0" and display_path("/plates/déjà") == "/plates/déjà"


class _Cancelled(Exception):
    pass


def test_a_cancel_between_open_and_write_waits_for_the_whole_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    """SIGTERM right after the PNG writer opened its file takes effect once the file is whole: the cancel is raised,
    the PNG that was being written is complete or absent, and libpng prints nothing ("No IDATs written into file"
    was what a render cancelled at that moment printed past its one-line message)."""
    import signal

    import OpenImageIO as oiio

    import engine.io.images as images

    real_create = oiio.ImageOutput.create

    class SignalAfterOpen:
        def __init__(self, out: oiio.ImageOutput) -> None:
            self._out = out

        def open(self, *args: object) -> bool:
            ok = self._out.open(*args)
            signal.raise_signal(signal.SIGTERM)
            return ok

        def __getattr__(self, name: str) -> object:
            return getattr(self._out, name)

    monkeypatch.setattr(images.oiio.ImageOutput, "create", lambda fmt: SignalAfterOpen(real_create(fmt)))

    def cancel(_signum: int, _frame: object) -> None:
        raise _Cancelled

    old = signal.signal(signal.SIGTERM, cancel)
    try:
        with pytest.raises(_Cancelled):
            write_png(tmp_path / "frame.png", np.full((6, 8, 3), 0.5, np.float32))
    finally:
        signal.signal(signal.SIGTERM, old)
    assert "IDAT" not in capfd.readouterr().err
    written = [p.name for p in tmp_path.iterdir()]
    assert written in ([], ["frame.png"]), written
    if written:
        assert np.allclose(read_image(tmp_path / "frame.png"), 128 / 255, atol=1e-6)
