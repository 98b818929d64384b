"""The plate's colour space is never chosen from a config or a header that cannot be trusted: an ``$OCIO`` config
that does not parse (OpenImageIO would fall back to its own built-in config while the run records the broken
path), and a DPX sequence whose frames' headers declare different transfers (the first frame's would decide
for all, a log scan decoded with the sRGB curve). Both are one line naming the file and the fix."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from engine import contract as C
from engine.errors import InputError
from engine.io import colour
from engine.io.clip import open_clip, read_frames
from tests.media_files import write_dpx, write_image
from tests.stability.cases_input import BROKEN_OCIO_CONFIG

W, H = 8, 6
#: ``DPX_MID_GREY`` in a 10-bit DPX: its top 10 bits (code 512 of 1023).
TEN_BIT_GREY, TEN_BIT_TOP = 512, 1023
HALF_TEN_BIT_STEP = 0.5 / TEN_BIT_TOP
#: A config that parses: BROKEN_OCIO_CONFIG with its flow sequence closed, and the spaces it names.
GOOD_OCIO_CONFIG = BROKEN_OCIO_CONFIG.replace("[lin_rec709\n", "lin_rec709\n") + (
    "    isdata: false\n"
    "  - !<ColorSpace>\n"
    "    name: sRGB\n"
    "    isdata: false\n"
    "    from_scene_reference: !<ExponentWithLinearTransform> {gamma: 2.4, offset: 0.055, direction: inverse}\n"
    "  - !<ColorSpace>\n"
    "    name: Raw\n"
    "    isdata: true\n"
)


def _scan(folder: Path, transfers: list[str | None]) -> Path:
    folder.mkdir()
    for i, transfer in enumerate(transfers):
        write_dpx(folder / f"{i:05d}.dpx", (W, H), transfer)
    return folder


def _refusal(*args, **kwargs) -> str:
    with pytest.raises(InputError) as exc:
        open_clip(*args, **kwargs)
    return str(exc.value)


# --- $OCIO ----------------------------------------------------------------------------------------------


def test_ocio_config_with_a_yaml_error_is_refused_naming_its_line(tmp_path: Path, monkeypatch) -> None:
    """Before: the clip opened in OpenImageIO's minimal built-in config and clip.json recorded the broken path."""
    config = tmp_path / "studio.ocio"
    config.write_text(BROKEN_OCIO_CONFIG, encoding="utf-8")
    frames = tmp_path / "frames"
    frames.mkdir()
    write_image(frames / "00000.png", np.full((H, W, 3), 128, np.uint8))
    monkeypatch.setenv("OCIO", str(config))
    assert _refusal(frames) == (
        f"{config}: cannot load this OCIO config (yaml-cpp: error at line 5, column 12: end of sequence flow not "
        "found) — correct the config where the error says, point $OCIO at a valid one, or unset $OCIO to use the "
        "built-in ACES config"
    )


def test_the_same_config_corrected_loads_and_decides(tmp_path: Path, monkeypatch) -> None:
    """The check refuses what does not parse, not a config that does: the corrected one opens the clip in it."""
    config = tmp_path / "studio.ocio"
    config.write_text(GOOD_OCIO_CONFIG, encoding="utf-8")
    frames = tmp_path / "frames"
    frames.mkdir()
    write_image(frames / "00000.png", np.full((H, W, 3), 128, np.uint8))
    monkeypatch.setenv("OCIO", str(config))
    info = open_clip(frames)
    assert (info.colorspace, info.colour_config) == ("sRGB", str(config))


def test_the_built_in_config_loads_without_an_error() -> None:
    assert colour.load_config(colour.BUILTIN_CONFIG).getNumColorSpaces() > 8


# --- DPX transfers --------------------------------------------------------------------------------------


def test_log_scan_whose_first_frame_declares_no_transfer_is_refused(tmp_path: Path) -> None:
    """Before: frame 0's "Undefined" made the clip sRGB and the log frames after it were decoded as sRGB."""
    scan = _scan(tmp_path / "scan", [None, "Printing density", "Printing density"])
    assert _refusal(scan) == (
        f"{scan / '00001.dpx'}: 00001.dpx's header declares the transfer 'Printing density' (log) but 00000.dpx's "
        "declares 'Undefined' (sRGB); one clip has one encoding — re-export the plate with the same transfer in "
        "every frame's header, or name its colour space, e.g. --colorspace ACEScct"
    )


@pytest.mark.parametrize(
    ("transfers", "differs", "said"),
    [
        (["Printing density", "Printing density", None], "00002.dpx", "'Undefined' (sRGB)"),
        (["Linear", "Logarithmic", "Linear"], "00001.dpx", "'Logarithmic' (log)"),
        (["User defined", "Linear", "Linear"], "00001.dpx", "'Linear' (linear)"),
    ],
    ids=["log_then_undefined", "linear_then_log", "other_then_linear"],
)
def test_the_first_frame_whose_transfer_differs_is_named(tmp_path: Path, transfers, differs: str, said: str) -> None:
    message = _refusal(_scan(tmp_path / "scan", transfers))
    assert message.startswith(f"{tmp_path / 'scan' / differs}: {differs}'s header declares the transfer {said}")
    assert message.count("\n") == 0


def test_transfers_that_read_alike_are_one_encoding(tmp_path: Path) -> None:
    """ "Undefined" and "User defined" both read with the sRGB curve; "Printing density" and "Logarithmic" are both
    log (refused as such, naming the first frame, as a log scan always was)."""
    assert open_clip(_scan(tmp_path / "srgb", [None, "User defined", None])).colorspace == C.COLOUR_SRGB
    message = _refusal(_scan(tmp_path / "log", ["Printing density", "Logarithmic"]))
    assert message.startswith(f"{tmp_path / 'log' / '00000.dpx'}: this DPX declares a log transfer")


def test_a_named_colour_space_reads_a_mixed_scan(tmp_path: Path) -> None:
    """With --colorspace the headers decide nothing: the scan opens in the space named, every frame read."""
    scan = _scan(tmp_path / "scan", [None, "Printing density", "Printing density"])
    info = open_clip(scan, colorspace="ACEScct")
    assert info.colorspace == "ACEScct"
    frames = read_frames(info)
    assert frames.shape == (3, H, W, 3) and np.all(frames == frames[0, 0, 0, 0])  # each frame the same grey
    assert abs(frames[0, 0, 0, 0] - TEN_BIT_GREY / TEN_BIT_TOP) < HALF_TEN_BIT_STEP


def test_a_frame_range_past_the_odd_frame_is_the_log_scan_it_is(tmp_path: Path) -> None:
    """Only the selected frames' headers count: frames 1-2 are a plain log scan, refused as one."""
    scan = _scan(tmp_path / "scan", [None, "Printing density", "Printing density"])
    assert "00001.dpx: this DPX declares a log transfer (Printing density)" in _refusal(scan, (1, 2))
