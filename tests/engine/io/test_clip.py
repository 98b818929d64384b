"""Clip loading: sequences and movies read with the right values, and every bad input is a one-line
InputError naming the file, so the user can fix it without a traceback. Inputs a loader could take without a word
are refused here with real files: a sequence mixing float and integer frames, a movie cut short or garbled
in the middle, a frame whose header declares a gigantic image; a folder whose name is not UTF-8 reads like any
other."""

from __future__ import annotations

import resource
from pathlib import Path

import numpy as np
import pytest

from engine import contract as C
from engine.errors import InputError
from engine.io.clip import (
    IMAGE_EXTENSIONS,
    MOVIE_EXTENSIONS,
    ClipInfo,
    open_clip,
    read_frames,
    read_masks,
    working_size,
)
from engine.io.images import MAX_DECODED_BYTES, display_path, read_image, write_png
from tests.folders import non_utf8_folder
from tests.media_files import (
    garble_movie,
    textured_frames,
    write_audio_only_movie,
    write_blank_png,
    write_image,
)
from tests.media_files import write_movie as write_movie_frames
from tests.paths import CLIPS

SHARED = CLIPS / "blackswan"


# --- helpers ---------------------------------------------------------------------------------------------


def const(height: int, width: int, value, dtype=np.uint8) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, dtype=dtype), (height, width, len(value))).copy()


def make_sequence(folder: Path, count: int = 3, ext: str = "png", start: int = 0, size=(8, 6)) -> Path:
    """Frames 00000.png.. with frame i a constant colour (10*i, 100, 200-10*i)."""
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(count):
        write_image(folder / f"{start + i:05d}.{ext}", const(size[1], size[0], (10 * i, 100, 200 - 10 * i)))
    return folder


def make_masks(folder: Path, names: list[str], size=(8, 6)) -> list[np.ndarray]:
    """Masks with a different random pattern each, returned as the expected bools."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(len(names))
    expected = []
    for name in names:
        fg = rng.random((size[1], size[0])) > 0.5
        write_image(folder / name, (fg * 255).astype(np.uint8))
        expected.append(fg)
    return expected


def write_movie(path: Path, colours: list[tuple[int, int, int]], size=(64, 48), rate: int = 24) -> Path:
    return write_movie_frames(path, [const(size[1], size[0], colour) for colour in colours], rate)


def assert_one_line(exc: pytest.ExceptionInfo[InputError], *names: str) -> str:
    message = str(exc.value)
    assert "\n" not in message
    for name in names:
        assert name in message, f"{name!r} not in {message!r}"
    return message


# --- sequences -------------------------------------------------------------------------------------------


def test_png_8bit_sequence(tmp_path: Path) -> None:
    folder = make_sequence(tmp_path / "frames", count=3)
    info = open_clip(folder)
    assert info == ClipInfo(
        source=str(folder),
        kind="sequence",
        frame_files=tuple(str(folder / f"{i:05d}.png") for i in range(3)),
        frame_numbers=(0, 1, 2),
        width=8,
        height=6,
        fps=None,
        colorspace=C.COLOUR_SRGB,
        channels=3,
    )
    assert info.num_frames == 3
    frames = read_frames(info)
    assert frames.shape == (3, 6, 8, 3) and frames.dtype == np.float32
    for i in range(3):
        np.testing.assert_allclose(
            frames[i], np.broadcast_to([10 * i / 255, 100 / 255, (200 - 10 * i) / 255], (6, 8, 3)), atol=1e-6
        )


def test_png_16bit(tmp_path: Path) -> None:
    folder = tmp_path / "f"
    folder.mkdir()
    write_image(folder / "1.png", const(4, 5, (0, 30000, 65535), np.uint16))
    info = open_clip(folder)
    assert info.colorspace == C.COLOUR_SRGB
    np.testing.assert_allclose(read_frames(info)[0, 2, 3], [0, 30000 / 65535, 1.0], atol=1e-6)


def test_jpg(tmp_path: Path) -> None:
    folder = make_sequence(tmp_path / "frames", count=2, ext="jpg", size=(16, 16))
    info = open_clip(folder)
    assert (info.width, info.height, info.colorspace, info.num_frames) == (16, 16, C.COLOUR_SRGB, 2)
    np.testing.assert_allclose(
        read_frames(info)[1], np.broadcast_to([10 / 255, 100 / 255, 190 / 255], (16, 16, 3)), atol=3 / 255
    )


def test_float_exr_keeps_raw_values(tmp_path: Path) -> None:
    folder = tmp_path / "plates"
    folder.mkdir()
    pixels = const(3, 4, (2.5, -0.25, 0.1), np.float32)
    pixels[0, 0, 0] = np.nan
    write_image(folder / "shot_v2.0001.exr", pixels, "half")
    write_image(folder / "shot_v2.0002.exr", pixels, "float")
    info = open_clip(folder)
    assert info.colorspace == C.COLOUR_SCENE_LINEAR and info.frame_numbers == (1, 2)
    frames = read_frames(info)
    assert np.isnan(frames[:, 0, 0, 0]).all()
    np.testing.assert_allclose(frames[:, 1, 1], [[2.5, -0.25, 0.1]] * 2, rtol=1e-3)


def test_float_tiff_is_linear_and_int_tiff_is_srgb(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    write_image(tmp_path / "a" / "0.tif", const(2, 2, (0.5, 1.5, 0.0), np.float32))
    write_image(tmp_path / "b" / "0.tif", const(2, 2, (0, 128, 255)))
    assert open_clip(tmp_path / "a").colorspace == C.COLOUR_SCENE_LINEAR
    assert open_clip(tmp_path / "b").colorspace == C.COLOUR_SRGB


def test_greyscale_is_replicated(tmp_path: Path) -> None:
    folder = tmp_path / "grey"
    folder.mkdir()
    write_image(folder / "0.png", np.full((4, 4), 51, np.uint8))
    info = open_clip(folder)
    assert info.channels == 1
    frames = read_frames(info)
    assert frames.shape == (1, 4, 4, 3)
    np.testing.assert_allclose(frames, 0.2, atol=1e-6)


def test_rgba_drops_alpha_without_premultiplying(tmp_path: Path) -> None:
    folder = tmp_path / "rgba"
    folder.mkdir()
    write_image(folder / "0.png", const(4, 4, (204, 102, 0, 51)))
    info = open_clip(folder)
    assert info.channels == 4
    np.testing.assert_allclose(read_frames(info)[0, 0, 0], [0.8, 0.4, 0.0], atol=1e-6)


def test_sequence_sorted_by_last_number_naturally(tmp_path: Path) -> None:
    folder = tmp_path / "seq"
    folder.mkdir()
    for n in (10, 8, 11, 9):
        write_image(folder / f"shot_v2.{n}.png", const(2, 2, (n, 0, 0)))
    info = open_clip(folder)
    assert info.frame_numbers == (8, 9, 10, 11)
    assert [Path(f).name for f in info.frame_files] == [f"shot_v2.{n}.png" for n in (8, 9, 10, 11)]
    np.testing.assert_allclose(read_frames(info)[:, 0, 0, 0] * 255, [8, 9, 10, 11], atol=1e-4)


def test_unnumbered_sequence_uses_natural_order_and_positions(tmp_path: Path) -> None:
    folder = tmp_path / "seq"
    folder.mkdir()
    for name in ("b.png", "a.png", "C.png"):
        write_image(folder / name, const(2, 2, (1, 2, 3)))
    info = open_clip(folder, (1, 2))
    assert [Path(f).name for f in info.frame_files] == ["b.png", "C.png"]
    assert info.frame_numbers == (1, 2)


def test_hidden_and_other_files_are_ignored(tmp_path: Path) -> None:
    folder = make_sequence(tmp_path / "frames", count=2)
    (folder / "notes.txt").write_text("hi")
    (folder / ".00005.png").write_bytes(b"junk")
    (folder / "sub.png").mkdir()
    assert open_clip(folder).num_frames == 2


def test_uppercase_extension(tmp_path: Path) -> None:
    folder = tmp_path / "f"
    folder.mkdir()
    write_image(folder / "0001.PNG", const(2, 2, (1, 2, 3)))
    assert open_clip(folder).frame_numbers == (1,)


def test_frame_range_selects_positions(tmp_path: Path) -> None:
    folder = make_sequence(tmp_path / "frames", count=5, start=100)
    info = open_clip(folder, (1, 3))
    assert info.frame_numbers == (101, 102, 103)
    assert [Path(f).name for f in info.frame_files] == ["00101.png", "00102.png", "00103.png"]
    np.testing.assert_allclose(read_frames(info)[:, 0, 0, 0] * 255, [10, 20, 30], atol=1e-4)
    assert open_clip(folder, (4, 4)).frame_numbers == (104,)


@pytest.mark.parametrize(
    ("size", "long_edge", "expected"),
    [
        ((854, 480), 768, (768, 432)),
        ((480, 854), 768, (432, 768)),
        ((16, 16), 768, (16, 16)),
        ((768, 400), 768, (768, 400)),
        ((1920, 1080), 512, (512, 288)),
        ((4000, 3), 100, (100, 1)),
    ],
)
def test_working_size(size: tuple[int, int], long_edge: int, expected: tuple[int, int]) -> None:
    assert working_size(*size, long_edge=long_edge) == expected


def test_read_frames_resize_keeps_constant_images_constant(tmp_path: Path) -> None:
    folder = make_sequence(tmp_path / "frames", count=2, size=(40, 30))
    info = open_clip(folder)
    small = read_frames(info, size=(20, 15))
    big = read_frames(info, size=(57, 41))
    assert small.shape == (2, 15, 20, 3) and big.shape == (2, 41, 57, 3)
    for frames in (small, big):
        np.testing.assert_allclose(
            frames[1], np.broadcast_to([10 / 255, 100 / 255, 190 / 255], frames.shape[1:]), atol=1e-6
        )


def test_read_frames_shrink_averages(tmp_path: Path) -> None:
    folder = tmp_path / "f"
    folder.mkdir()
    pixels = np.zeros((4, 4, 3), np.uint8)
    pixels[:, ::2] = 255  # stripes average to grey with INTER_AREA
    write_image(folder / "0.png", pixels)
    np.testing.assert_allclose(read_frames(open_clip(folder), size=(2, 2)), 0.5, atol=1e-6)


# --- movies ----------------------------------------------------------------------------------------------


def test_movie(tmp_path: Path) -> None:
    colours = [(200, 30, 90), (20, 180, 60), (90, 90, 220), (250, 250, 250), (10, 10, 10)]
    path = write_movie(tmp_path / "clip.mp4", colours)
    info = open_clip(path)
    assert info.kind == "movie" and info.source == str(path) and info.frame_files == ()
    assert (info.num_frames, info.width, info.height, info.colorspace) == (5, 64, 48, C.COLOUR_SRGB)
    assert info.fps == pytest.approx(24.0)
    assert info.frame_numbers == (0, 1, 2, 3, 4)
    frames = read_frames(info)
    assert frames.shape == (5, 48, 64, 3) and frames.dtype == np.float32
    centre = frames[:, 24, 32] * 255
    np.testing.assert_allclose(centre, colours, atol=12)

    part = open_clip(path, (2, 3))
    assert part.frame_numbers == (2, 3)
    small = read_frames(part, size=(32, 24))
    assert small.shape == (2, 24, 32, 3)
    np.testing.assert_allclose(small[:, 12, 16] * 255, colours[2:4], atol=12)


def test_movie_without_frame_count_in_header(tmp_path: Path) -> None:
    path = write_movie(tmp_path / "clip.mkv", [(0, 0, 0), (255, 255, 255), (0, 0, 0)], size=(16, 16))
    info = open_clip(path)
    assert info.num_frames == 3
    np.testing.assert_allclose(read_frames(info)[:, 8, 8].mean(axis=1) * 255, [0, 255, 0], atol=12)


def test_movie_masks_by_position(tmp_path: Path) -> None:
    path = write_movie(tmp_path / "clip.mp4", [(0, 0, 0)] * 4, size=(16, 12))
    expected = make_masks(tmp_path / "masks", [f"m{i}.png" for i in range(4)], size=(16, 12))
    masks = read_masks(tmp_path / "masks", open_clip(path, (1, 2)), (16, 12))
    np.testing.assert_array_equal(masks, expected[1:3])


#: A movie long enough that damage to the middle of its bytes lands on frames in the middle.
DAMAGED_MOVIE_FRAMES = 40


@pytest.mark.parametrize("container", ["mp4", "mkv", "avi"])
def test_whole_movies_of_every_container_read_every_frame(tmp_path: Path, container: str) -> None:
    """The checks below refuse nothing that is whole: every frame, in every container the tests damage."""
    path = write_movie_frames(tmp_path / f"clip.{container}", textured_frames(DAMAGED_MOVIE_FRAMES))
    assert read_frames(open_clip(path)).shape == (DAMAGED_MOVIE_FRAMES, 48, 64, 3)
    assert read_frames(open_clip(path, (3, 5))).shape == (3, 48, 64, 3)


@pytest.mark.parametrize("how", ["cut", "zeroed"])
@pytest.mark.parametrize("container", ["mp4", "mkv", "avi"])
def test_damaged_movie_is_refused_naming_the_file(tmp_path: Path, container: str, how: str) -> None:
    """A movie cut short or zeroed in the middle: an mkv's demuxer resynchronises past the damage and
    yields 21 of its 40 frames without an error. Now the frames it holds are checked against what it declares
    (its header's count, or its duration and the span of its timestamps) and against what its decoder gives,
    and whatever the container, opening or reading it is one line naming the file."""
    whole = write_movie_frames(tmp_path / f"whole.{container}", textured_frames(DAMAGED_MOVIE_FRAMES))
    damaged = garble_movie(whole, tmp_path / f"damaged.{container}", how)
    with pytest.raises(InputError) as exc:
        read_frames(open_clip(damaged))
    message = assert_one_line(exc, f"damaged.{container}", "re-encode the movie")
    assert any(word in message for word in ("truncated", "corrupt", "cannot", "dropped")), message


def test_damaged_movie_is_refused_even_for_frames_before_the_damage(tmp_path: Path) -> None:
    """The decoder may drop a damaged frame and carry on; every frame is decoded (only the selected ones are
    converted), so frames 0..3 of a movie damaged in the middle are refused too: which frame was dropped cannot be
    told, and a fit of the wrong frames is worse than none."""
    whole = write_movie_frames(tmp_path / "whole.avi", textured_frames(DAMAGED_MOVIE_FRAMES))
    damaged = garble_movie(whole, tmp_path / "damaged.avi", "zeroed")
    with pytest.raises(InputError) as exc:
        read_frames(open_clip(damaged, (0, 3)))
    assert_one_line(exc, "damaged.avi", "dropped")


# --- one encoding per clip ------------------------------------------------------------------------------


@pytest.mark.parametrize("float_first", [False, True], ids=["integer_then_float", "float_then_integer"])
def test_sequence_mixing_float_and_integer_frames_is_refused(tmp_path: Path, float_first: bool) -> None:
    """Frame 0's encoding decides the clip's colour space: a float (scene-linear) TIFF among 8-bit
    (display-encoded) ones would be decoded with the wrong curve. Refused at open, naming the first frame that
    differs and both encodings."""
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(4):
        is_float = (i >= 2) != float_first
        pixels = const(6, 8, (0.25, 0.5, 0.75), np.float32) if is_float else const(6, 8, (64, 128, 192))
        write_image(folder / f"{i:05d}.tif", pixels)
    with pytest.raises(InputError) as exc:
        open_clip(folder)
    differs, first = ("integer", "float") if float_first else ("float", "integer")
    problem = assert_one_line(exc, "00002.tif", "00000.tif", "one format").split("00002.tif: ", 1)[1]
    assert problem.startswith(f"00002.tif is {differs}") and f"00000.tif is {first}" in problem, problem


def test_frame_replaced_by_another_encoding_after_open_is_refused_at_read(tmp_path: Path) -> None:
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(3):
        write_image(folder / f"{i:05d}.tif", const(6, 8, (64, 128, 192)))
    info = open_clip(folder)
    write_image(folder / "00001.tif", const(6, 8, (0.25, 0.5, 0.75), np.float32))
    with pytest.raises(InputError) as exc:
        read_frames(info)
    assert_one_line(exc, "00001.tif", "float")


# --- declared size -----------------------------------------------------------------------------------------

#: 30000 x 30000 RGB: 10.8 GB as float32, in a PNG of about 3 MB.
HUGE_SIDE = 30000
#: Peak memory growth a refusal may cost (bytes): far below what the header asks for.
REFUSAL_MEMORY_BOUND = 512 * 1024 * 1024


def _peak_rss_bytes() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux reports kilobytes


@pytest.mark.parametrize("position", ["00000.png", "00001.png"], ids=["first_frame", "later_frame"])
def test_png_declaring_a_huge_image_is_refused_before_decoding(tmp_path: Path, position: str) -> None:
    """A valid 3 MB PNG that declares 30000x30000 pixels would be decoded into 10.8 GB of float32. The header is
    checked against ``MAX_DECODED_BYTES`` before any pixel is read: one line naming the file, its declared size
    and the cap, and the process's peak memory does not grow by more than ``REFUSAL_MEMORY_BOUND``."""
    folder = make_sequence(tmp_path / "frames", count=2)
    huge = write_blank_png(folder / position, HUGE_SIDE, HUGE_SIDE)
    assert huge.stat().st_size < 4_000_000
    before = _peak_rss_bytes()
    with pytest.raises(InputError) as exc:
        open_clip(folder)
    assert _peak_rss_bytes() - before < REFUSAL_MEMORY_BOUND
    assert_one_line(exc, position, f"{HUGE_SIDE}x{HUGE_SIDE}", "10.8 GB", f"{MAX_DECODED_BYTES / 1e9:.1f} GB")
    with pytest.raises(InputError) as exc:  # the export's and the editors' reader: the same cap
        read_image(huge)
    assert_one_line(exc, position, "10.8 GB")


def test_huge_mask_is_refused_before_decoding(tmp_path: Path) -> None:
    info = open_clip(make_sequence(tmp_path / "frames", count=1))
    (tmp_path / "masks").mkdir()
    write_blank_png(tmp_path / "masks" / "00000.png", HUGE_SIDE, HUGE_SIDE, channels=2)  # grey + alpha
    with pytest.raises(InputError) as exc:
        read_masks(tmp_path / "masks", info, (8, 6))
    assert_one_line(exc, "00000.png", "mask declares", "7.2 GB")


def test_blank_png_builder_writes_a_readable_png(tmp_path: Path) -> None:
    """The huge PNG above is real: the same builder's small image decodes to black."""
    pixels, is_float = read_image(write_blank_png(tmp_path / "blank.png", 64, 48))
    assert pixels.shape == (48, 64, 3) and not is_float and pixels.max() == 0.0


# --- paths that are not UTF-8 --------------------------------------------------------------------------------


def test_clip_masks_and_images_in_a_folder_whose_name_is_not_utf8(tmp_path: Path) -> None:
    """Such a name reaches Python as surrogate escapes, which OpenImageIO's and OpenEXR's text conversion refuse
    (a TypeError). The readers and writers hand them the bytes, so it reads like any other; messages show
    the odd byte as ``\\xe9``."""
    folder = non_utf8_folder(tmp_path, b"plate_\xe9t\xe9")
    frames = make_sequence(folder / "frames", count=3)
    expected = make_masks(folder / "masks", ["00000.png", "00001.png", "00002.png"])
    info = open_clip(frames)
    assert info.source == str(frames) and read_frames(info).shape == (3, 6, 8, 3)
    np.testing.assert_array_equal(read_masks(folder / "masks", info, (8, 6)), expected)
    written = write_png(folder / "out.png", np.full((6, 8, 1), 1.0, np.float32))
    assert read_image(written)[0].min() == 1.0
    movie = write_movie(folder / "clip.mp4", [(0, 0, 0)] * 3, size=(16, 16))
    assert read_frames(open_clip(movie)).shape == (3, 16, 16, 3)
    assert display_path(frames).endswith("plate_\\xe9t\\xe9/frames")
    with pytest.raises(InputError) as exc:
        read_masks(folder / "no_masks", info, (8, 6))
    assert "\n" not in str(exc.value) and "no_masks" in str(exc.value)


# --- masks -----------------------------------------------------------------------------------------------


def test_masks_matched_by_number(tmp_path: Path) -> None:
    frames = make_sequence(tmp_path / "frames", count=3, start=12)
    # one extra mask on each side: matching must go by number, not position
    expected = make_masks(tmp_path / "masks", [f"{n:05d}.png" for n in range(11, 16)])
    info = open_clip(frames)
    masks = read_masks(tmp_path / "masks", info, (8, 6))
    assert masks.shape == (3, 6, 8) and masks.dtype == bool
    np.testing.assert_array_equal(masks, expected[1:4])
    np.testing.assert_array_equal(read_masks(tmp_path / "masks", open_clip(frames, (2, 2)), (8, 6)), expected[3:4])


def test_masks_matched_by_position(tmp_path: Path) -> None:
    frames = make_sequence(tmp_path / "frames", count=3, start=12)
    expected = make_masks(tmp_path / "masks", ["mask_a.png", "mask_b.png", "mask_c.png"])
    np.testing.assert_array_equal(read_masks(tmp_path / "masks", open_clip(frames), (8, 6)), expected)


def test_masks_for_full_clip_with_a_frame_range(tmp_path: Path) -> None:
    frames = make_sequence(tmp_path / "frames", count=5, start=12)
    expected = make_masks(tmp_path / "masks", [f"m{i}.png" for i in range(5)])  # numbers do not match
    masks = read_masks(tmp_path / "masks", open_clip(frames, (1, 3)), (8, 6))
    np.testing.assert_array_equal(masks, expected[1:4])
    # exactly one mask per selected frame also works
    subset = make_masks(tmp_path / "subset", ["a.png", "b.png", "c.png"])
    np.testing.assert_array_equal(read_masks(tmp_path / "subset", open_clip(frames, (1, 3)), (8, 6)), subset)


@pytest.mark.parametrize(
    ("name", "pixels", "fmt", "expected"),
    [
        # above half of full scale is foreground (contract.MASK_THRESHOLD), in 8 and in 16 bits
        ("0.png", np.array([[128, 127]], np.uint8), None, [True, False]),
        ("0.png", np.array([[32768, 32767, 65535]], np.uint16), None, [True, False, True]),
        # floats are taken raw; NaN is background
        ("0.exr", np.array([[0.6, 0.4, np.nan, 3.0]], np.float32), "half", [True, False, False, True]),
        # RGBA whose alpha is constant: the colour is the matte
        ("0.png", np.array([[[255, 255, 255, 255], [0, 0, 0, 255]]], np.uint8), None, [True, False]),
    ],
    ids=["threshold_8bit", "threshold_16bit", "float_exr", "rgba_constant_alpha_uses_colour"],
)
def test_mask_values(tmp_path: Path, name: str, pixels: np.ndarray, fmt: str | None, expected: list[bool]) -> None:
    width = pixels.shape[1]
    frames = make_sequence(tmp_path / "frames", count=1, size=(width, 1))
    (tmp_path / "masks").mkdir()
    write_image(tmp_path / "masks" / name, pixels, fmt)
    np.testing.assert_array_equal(read_masks(tmp_path / "masks", open_clip(frames), (width, 1)), [[expected]])


def test_mask_threshold_is_the_contracts() -> None:
    assert 127 / 255 < C.MASK_THRESHOLD < 128 / 255 and 32767 / 65535 < C.MASK_THRESHOLD < 32768 / 65535


def test_mask_channels(tmp_path: Path) -> None:
    frames = make_sequence(tmp_path / "frames", count=2, size=(2, 1))
    (tmp_path / "masks").mkdir()
    # RGB: any colour channel counts (max); RGBA with varying alpha: the alpha is the matte
    write_image(tmp_path / "masks" / "0.png", np.array([[[0, 0, 255], [0, 0, 0]]], np.uint8))
    write_image(tmp_path / "masks" / "1.png", np.array([[[255, 255, 255, 0], [0, 0, 0, 255]]], np.uint8))
    masks = read_masks(tmp_path / "masks", open_clip(frames), (2, 1))
    np.testing.assert_array_equal(masks, [[[True, False]], [[False, True]]])


def test_coarse_mask_stays_coarse(tmp_path: Path) -> None:
    frames = make_sequence(tmp_path / "frames", count=1, size=(16, 8))
    (tmp_path / "masks").mkdir()
    # a 4x2 mask (left half of the top row fg) at the clip's aspect, enlarged to 8x4: blocks, not blobs
    write_image(tmp_path / "masks" / "0.png", np.array([[255, 255, 0, 0], [0, 0, 0, 0]], np.uint8))
    masks = read_masks(tmp_path / "masks", open_clip(frames), (8, 4))
    expected = np.zeros((4, 8), bool)
    expected[:2, :4] = True
    np.testing.assert_array_equal(masks[0], expected)
    # shrinking averages first, then thresholds: a 1-pixel speck in a 2x2 block disappears
    write_image(tmp_path / "masks" / "0.png", np.pad(np.full((1, 1), 255, np.uint8), ((0, 7), (0, 15))))
    assert not read_masks(tmp_path / "masks", open_clip(frames), (8, 4)).any()


def test_mask_other_resolution_same_aspect_is_resized(tmp_path: Path) -> None:
    frames = make_sequence(tmp_path / "frames", count=1, size=(8, 6))
    (tmp_path / "masks").mkdir()
    write_image(tmp_path / "masks" / "0.png", np.full((12, 16), 255, np.uint8))
    assert read_masks(tmp_path / "masks", open_clip(frames), (4, 3)).all()


# --- bad input ------------------------------------------------------------------------------------------


def test_missing_path(tmp_path: Path) -> None:
    with pytest.raises(InputError) as exc:
        open_clip(tmp_path / "nope")
    assert_one_line(exc, "nope")


def test_folder_without_images_lists_extensions(tmp_path: Path) -> None:
    folder = tmp_path / "empty_shot"
    folder.mkdir()
    (folder / "readme.txt").write_text("x")
    with pytest.raises(InputError) as exc:
        open_clip(folder)
    assert_one_line(exc, "empty_shot", *IMAGE_EXTENSIONS)


def test_unknown_file_type(tmp_path: Path) -> None:
    path = tmp_path / "clip.gif"
    path.write_bytes(b"GIF89a")
    with pytest.raises(InputError) as exc:
        open_clip(path)
    assert_one_line(exc, "clip.gif", *MOVIE_EXTENSIONS)


def test_single_image_file_points_to_its_folder(tmp_path: Path) -> None:
    folder = make_sequence(tmp_path / "frames", count=2)
    with pytest.raises(InputError) as exc:
        open_clip(folder / "00000.png")
    assert_one_line(exc, "00000.png", str(folder))


def test_gap_in_numbering(tmp_path: Path) -> None:
    folder = tmp_path / "frames"
    folder.mkdir()
    for n in (4, 5, 6, 8, 9):
        write_image(folder / f"{n:05d}.png", const(2, 2, (1, 2, 3)))
    with pytest.raises(InputError) as exc:
        open_clip(folder)
    message = assert_one_line(exc, "frame 00007 is missing between 00006.png and 00008.png", "frame range")
    assert "render or copy" in message
    # a range that avoids the gap is fine
    assert open_clip(folder, (0, 2)).frame_numbers == (4, 5, 6)
    assert open_clip(folder, (3, 4)).frame_numbers == (8, 9)


@pytest.mark.parametrize(
    ("count", "name", "height", "names"),
    [
        (3, "00002.png", 5, ("00002.png", "8x5", "8x6")),  # a frame of another size
        (3, "00003.jpg", 6, ("00003.jpg", ".png", ".jpg")),
        (2, "thumbnail.png", 6, ("thumbnail.png",)),
        (2, "1.png", 6, ("00001.png", "1.png")),
    ],
    ids=["frames_of_different_sizes", "mixed_extensions", "unnumbered_mixed_with_numbered", "duplicate_numbers"],
)
def test_an_image_that_does_not_belong_to_the_sequence(
    tmp_path: Path, count: int, name: str, height: int, names: tuple[str, ...]
) -> None:
    folder = make_sequence(tmp_path / "frames", count=count, size=(8, 6))
    write_image(folder / name, const(height, 8, (1, 2, 3)))
    with pytest.raises(InputError) as exc:
        open_clip(folder)
    assert_one_line(exc, *names)


@pytest.mark.parametrize(
    ("count", "name", "data", "names"),
    [
        (2, "00000.png", b"not a png at all", ("00000.png", "re-export")),  # the first frame is decoded
        (3, "00002.png", b"", ("00002.png",)),  # later frames: their headers are read
    ],
    ids=["corrupt_first_frame", "unreadable_later_frame_header"],
)
def test_unreadable_frame_detected_at_open(tmp_path: Path, count: int, name: str, data: bytes, names: tuple) -> None:
    folder = make_sequence(tmp_path / "frames", count=count)
    (folder / name).write_bytes(data)
    with pytest.raises(InputError) as exc:
        open_clip(folder)
    assert_one_line(exc, *names)


def truncate(path: Path) -> None:
    """Replace a 64x64 frame by the first half of a noisy PNG: its header intact, its pixels cut off."""
    noisy = (np.random.default_rng(0).random((64, 64, 3)) * 255).astype(np.uint8)
    data = write_image(path, noisy).read_bytes()
    path.write_bytes(data[: len(data) // 2])


def test_truncated_first_frame_detected_at_open(tmp_path: Path) -> None:
    folder = make_sequence(tmp_path / "frames", count=2, size=(64, 64))
    truncate(folder / "00000.png")
    with pytest.raises(InputError) as exc:
        open_clip(folder)
    assert_one_line(exc, "00000.png", "re-export")


def test_truncated_later_frame_detected_at_read(tmp_path: Path) -> None:
    folder = make_sequence(tmp_path / "frames", count=3, size=(64, 64))
    truncate(folder / "00001.png")
    info = open_clip(folder)  # headers are intact
    with pytest.raises(InputError) as exc:
        read_frames(info)
    assert_one_line(exc, "00001.png", "re-export")


@pytest.mark.parametrize("frame_range", [(0, 3), (2, 1), (-1, 1), (3, 3)])
def test_frame_range_out_of_bounds(tmp_path: Path, frame_range: tuple[int, int]) -> None:
    folder = make_sequence(tmp_path / "frames", count=3)
    with pytest.raises(InputError) as exc:
        open_clip(folder, frame_range)
    assert_one_line(exc, "frames", "0..2")


def test_movie_frame_range_out_of_bounds(tmp_path: Path) -> None:
    path = write_movie(tmp_path / "clip.mp4", [(0, 0, 0)] * 3, size=(16, 16))
    with pytest.raises(InputError) as exc:
        open_clip(path, (1, 5))
    assert_one_line(exc, "clip.mp4", "0..2")


def test_movie_without_video_stream(tmp_path: Path) -> None:
    path = write_audio_only_movie(tmp_path / "sound.mp4")
    with pytest.raises(InputError) as exc:
        open_clip(path)
    assert_one_line(exc, "sound.mp4", "video stream")


def test_movie_pyav_cannot_open(tmp_path: Path) -> None:
    path = tmp_path / "broken.mov"
    path.write_bytes(b"\x00\x01garbage" * 20)
    with pytest.raises(InputError) as exc:
        open_clip(path)
    assert_one_line(exc, "broken.mov")


def test_mask_folder_missing_or_empty(tmp_path: Path) -> None:
    info = open_clip(make_sequence(tmp_path / "frames", count=2))
    with pytest.raises(InputError) as exc:
        read_masks(tmp_path / "no_masks", info, (8, 6))
    assert_one_line(exc, "no_masks")
    (tmp_path / "empty_masks").mkdir()
    with pytest.raises(InputError) as exc:
        read_masks(tmp_path / "empty_masks", info, (8, 6))
    assert_one_line(exc, "empty_masks", ".png")


def test_mask_count_mismatch(tmp_path: Path) -> None:
    info = open_clip(make_sequence(tmp_path / "frames", count=4), (1, 2))
    make_masks(tmp_path / "fg_masks", ["a.png", "b.png", "c.png"])
    with pytest.raises(InputError) as exc:
        read_masks(tmp_path / "fg_masks", info, (8, 6))
    message = assert_one_line(exc, "fg_masks", "3 mask files", "2 selected frames", "4 in the full clip")
    assert "one mask per frame" in message


def test_mask_aspect_mismatch(tmp_path: Path) -> None:
    info = open_clip(make_sequence(tmp_path / "frames", count=1, size=(8, 6)))
    (tmp_path / "masks").mkdir()
    write_image(tmp_path / "masks" / "00000.png", np.zeros((6, 9), np.uint8))
    with pytest.raises(InputError) as exc:
        read_masks(tmp_path / "masks", info, (8, 6))
    assert_one_line(exc, "00000.png", "9x6", "8x6")


def test_unreadable_mask(tmp_path: Path) -> None:
    info = open_clip(make_sequence(tmp_path / "frames", count=2))
    make_masks(tmp_path / "masks", ["00000.png", "00001.png"])
    (tmp_path / "masks" / "00001.png").write_bytes(b"broken")
    with pytest.raises(InputError) as exc:
        read_masks(tmp_path / "masks", info, (8, 6))
    assert_one_line(exc, "00001.png", "re-export")


# --- the real clip ----------------------------------------------------------------------------------------


@pytest.mark.shared_data
def test_blackswan() -> None:
    if not (SHARED / "frames").is_dir() or not (SHARED / "masks").is_dir():
        pytest.skip(f"{SHARED} is not available")
    info = open_clip(SHARED / "frames")
    assert (info.num_frames, info.width, info.height, info.colorspace) == (50, 854, 480, C.COLOUR_SRGB)
    size = working_size(info.width, info.height)
    masks = read_masks(SHARED / "masks", info, size)
    assert masks.shape == (50, 432, 768) and masks.dtype == bool
    assert 0.05 < masks.mean() < 0.2
