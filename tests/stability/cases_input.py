"""Bad input a loader could take without a word, refused in one line (exit 2) before anything is written, by
``fit``, ``estimate`` and ``masks``: a sequence mixing float and integer frames, a DPX sequence whose frames declare
different transfers, a movie cut short or garbled in the middle, a frame whose header declares a gigantic image, an
``$OCIO`` config that does not parse, and a mask folder that already holds the masks. The loaders' own tests
(tests/engine/io/) cover more variants of each.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from engine import contract as C
from tests.media_files import garble_movie, textured_frames, write_blank_png, write_dpx, write_image, write_movie
from tests.stability.bad_inputs import TINY_FIT, Case

#: A movie long enough that damage to the middle of its bytes lands on frames in the middle.
MOVIE_FRAMES = 40
#: 30000 x 30000 RGB: 10.8 GB as float32, in a PNG of about 3 MB.
HUGE_SIDE = 30000
W, H, FRAMES = 32, 24, 3
#: Estimate runs that would not be refused stay short.
TINY_ESTIMATE = ["--calib-seconds", "0.01", "--presets", "draft", "--set", "batch=64"]


def _fit(clip: Path, d: Path, *extra: str) -> list[str]:
    return [str(clip), "--out", str(d / "run"), *TINY_FIT, *extra]


def _mixed_encodings(d: Path) -> list[str]:
    """Two 8-bit TIFF frames, then a float one: frame 0's colour space would have decoded it wrongly."""
    folder = d / "frames"
    folder.mkdir()
    for i in range(FRAMES):
        pixels = np.full((H, W, 3), 0.5, np.float32) if i == 2 else np.full((H, W, 3), 128, np.uint8)
        write_image(folder / f"{i:05d}.tif", pixels)
    return _fit(folder, d)


def _log_dpx_after_a_plain_first_frame(d: Path) -> list[str]:
    """A log scan whose first frame's header lost its transfer: that frame alone would make the clip sRGB."""
    folder = d / "scan"
    folder.mkdir()
    for i in range(FRAMES):
        write_dpx(folder / f"{i:05d}.dpx", (W, H), None if i == 0 else "Printing density")
    return _fit(folder, d)


#: A studio config with one typo (a flow sequence never closed): OpenImageIO would fall back to its own minimal
#: built-in config without a word.
BROKEN_OCIO_CONFIG = """ocio_profile_version: 2.1
roles:
  default: lin_rec709
  scene_linear: [lin_rec709
colorspaces:
  - !<ColorSpace>
    name: lin_rec709
"""


def _broken_ocio(d: Path) -> list[str]:
    (d / "studio.ocio").write_text(BROKEN_OCIO_CONFIG, encoding="utf-8")
    folder = d / "frames"
    folder.mkdir()
    for i in range(FRAMES):
        write_image(folder / f"{i:05d}.png", np.full((H, W, 3), 40 * i, np.uint8))
    return _fit(folder, d)


def _ocio_env(d: Path) -> dict[str, str]:
    return {"OCIO": str(d / "studio.ocio")}


def _damaged(d: Path, container: str, how: str) -> Path:
    whole = write_movie(d / f"whole.{container}", textured_frames(MOVIE_FRAMES))
    return garble_movie(whole, d / f"{how}.{container}", how)


def _fit_movie(container: str, how: str) -> Callable[[Path], list[str]]:
    def build(d: Path) -> list[str]:
        return _fit(_damaged(d, container, how), d)

    return build


def _huge_frame(d: Path) -> Path:
    folder = d / "frames"
    folder.mkdir()
    write_image(folder / "00000.png", np.full((H, W, 3), 128, np.uint8))
    write_blank_png(folder / "00001.png", HUGE_SIDE, HUGE_SIDE)
    return folder


def _fit_huge_frame(d: Path) -> list[str]:
    return _fit(_huge_frame(d), d)


def _estimate_huge_frame(d: Path) -> list[str]:
    return [str(_huge_frame(d)), "--work", str(d / "work"), *TINY_ESTIMATE]


def _estimate_cut_movie(d: Path) -> list[str]:
    return [str(_damaged(d, "mkv", "cut")), "--work", str(d / "work"), *TINY_ESTIMATE]


def _masks_cut_movie(d: Path) -> list[str]:
    return [str(_damaged(d, "mkv", "cut")), "--out", str(d / "masks")]


def _masks_huge_frame(d: Path) -> list[str]:
    return [str(_huge_frame(d)), "--out", str(d / "masks")]


def _masks_already_there(d: Path) -> list[str]:
    """A mask folder holding the artist's fixed mask for frame 1: never overwritten, the folder byte-identical."""
    folder = d / "frames"
    folder.mkdir()
    for i in range(FRAMES):
        write_image(folder / f"{i:05d}.png", np.full((H, W, 3), 40 * i, np.uint8))
    (d / "masks").mkdir()
    write_image(d / "masks" / "00001.png", np.full((H, W), 255, np.uint8))
    return [str(folder), "--out", str(d / "masks")]


def _work(d: Path) -> Path:
    return d / "work"


CASES: tuple[Case, ...] = (
    Case(
        "mixed_float_and_integer_frames",
        "a float TIFF among 8-bit ones",
        _mixed_encodings,
        ("00002.tif", "float (scene-linear)", "00000.tif is integer", "one format"),
    ),
    Case(
        "dpx_log_after_a_plain_first_frame",
        "a DPX scan whose first frame's header has no transfer, the rest printing density",
        _log_dpx_after_a_plain_first_frame,
        ("00001.dpx", "'Printing density' (log)", "00000.dpx's declares 'Undefined' (sRGB)", "--colorspace"),
    ),
    Case(
        "ocio_config_does_not_parse",
        "$OCIO names a config with a YAML error",
        _broken_ocio,
        ("studio.ocio", "line 5", "$OCIO"),
        env=_ocio_env,
    ),
    Case("movie_cut_short", "an .mkv cut at half its bytes", _fit_movie("mkv", "cut"), ("cut.mkv", "truncated")),
    Case(
        "movie_zeroed_in_the_middle",
        "an .mkv whose middle third is zeros",
        _fit_movie("mkv", "zeroed"),
        ("zeroed.mkv", "only 21 frames", "span 40"),
    ),
    Case(
        "movie_frames_dropped_by_the_decoder",
        "an .avi whose middle third is zeros",
        _fit_movie("avi", "zeroed"),
        ("zeroed.avi", "dropped"),
    ),
    Case(
        "frame_declaring_a_huge_image",
        "a 3 MB PNG declaring 30000x30000",
        _fit_huge_frame,
        ("00001.png", "30000x30000", "10.8 GB", "limit"),
    ),
    Case(
        "estimate_frame_declaring_a_huge_image",
        "estimate: a PNG declaring 30000x30000",
        _estimate_huge_frame,
        ("00001.png", "10.8 GB"),
        verb=C.VERB_ESTIMATE,
        watch=_work,
    ),
    Case(
        "estimate_movie_cut_short",
        "estimate: an .mkv cut at half its bytes",
        _estimate_cut_movie,
        ("cut.mkv", "truncated"),
        verb=C.VERB_ESTIMATE,
        watch=_work,
    ),
    Case(
        "masks_movie_cut_short",
        "masks: an .mkv cut at half its bytes",
        _masks_cut_movie,
        ("cut.mkv", "truncated"),
        verb=C.VERB_MASKS,
    ),
    Case(
        "masks_frame_declaring_a_huge_image",
        "masks: a PNG declaring 30000x30000",
        _masks_huge_frame,
        ("00001.png", "10.8 GB"),
        verb=C.VERB_MASKS,
    ),
    Case(
        "masks_never_overwritten",
        "masks: --out already holds a mask of the clip",
        _masks_already_there,
        ("masks", "already holds 00001.png", "never overwritten"),
        verb=C.VERB_MASKS,
    ),
)
