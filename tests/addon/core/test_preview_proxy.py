"""The live preview at a proxy size (``core.preview_proxy``), without Blender: Blender's proxy sizes and the Auto
choice, the sampling (each proxy pixel is the full-size pixel under its centre, its u, v and Z unchanged, so an
outline never mixes two sides' UVs and the proxy preview is the full-size preview at those pixels), the plan's
files, and the proxy files' writers."""

from __future__ import annotations

import json
import os
from fractions import Fraction
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from fake_export import FRAMES, decode_png, make_export, read_exr_rgba, sample
from neural_atlas.addon.core import exr_passes
from neural_atlas.addon.core import preview_plan as V
from neural_atlas.addon.core import preview_proxy as X
from neural_atlas.addon.core import tree_plan as P

from engine import contract as C


def test_proxy_sizes_are_blenders():
    """25/50/75/100 %, each side ``side * percent // 100`` as Blender sizes its proxies; the panel offers them
    after Auto, which is the default."""
    assert X.PERCENTS == (25, 50, 75, 100)
    assert X.proxy_size((4096, 2160), 50) == (2048, 1080)
    assert X.proxy_size((4096, 2160), 25) == (1024, 540)
    assert X.proxy_size((4096, 2160), 75) == (3072, 1620)
    assert X.proxy_size((1921, 1081), 50) == (960, 540)  # Blender's integer rule: floor
    assert X.proxy_size((3, 2), 25) == (1, 1)  # never empty
    assert [i[0] for i in X.items()] == [X.AUTO, "PROXY_25", "PROXY_50", "PROXY_75", "PROXY_100"]
    assert [i[1] for i in X.items()] == ["Auto", "25%", "50%", "75%", "100%"]


@pytest.mark.parametrize(
    ("resolution", "want"),
    [
        ((40, 24), 100),
        ((1920, 1080), 100),
        ((2048, 1080), 100),  # 2K: every pixel
        ((2048, 2048), 100),
        ((2560, 1440), 75),  # 1920x1080
        ((3840, 2160), 50),  # UHD: 1920x1080
        ((4096, 2160), 50),  # 4K: 2048x1080
        ((1080, 4096), 50),  # portrait: the longer side counts
        ((6144, 3160), 25),  # 6K: 1536x790
        ((12288, 6480), 25),  # none within 2K: the smallest
    ],
)
def test_auto_is_the_largest_size_within_2k(resolution, want):
    assert X.auto_percent(resolution) == want
    assert X.proxy_percent(X.AUTO, resolution) == want
    assert X.proxy_percent("nonsense", resolution) == want  # an unknown choice (an older file) is Auto
    for p in X.PERCENTS:
        assert X.proxy_percent(X.choice_id(p), resolution) == p  # a choice is kept whatever the plate


@pytest.mark.parametrize(
    ("full", "proxy"), [(4096, 2048), (2160, 1080), (4096, 1024), (4096, 3072), (1921, 960), (7, 5)]
)
def test_each_proxy_pixel_is_the_full_pixel_under_its_centre(full, proxy):
    """The proxy pixel k's centre (k + 0.5) * full / proxy lies in the full-size pixel chosen (on the line between
    two pixels: the upper one, as Closest interpolation reads it), exactly, at any size."""
    got = X.centres(full, proxy)
    assert got.shape == (proxy,) and got.min() >= 0 and got.max() < full
    for k, c in enumerate(got.tolist()):
        centre = (k + Fraction(1, 2)) * full / proxy
        assert c <= centre < c + 1, (k, c, centre)
    assert np.all(np.diff(got) > 0)  # in order, never the same pixel twice
    if full == 2 * proxy:
        assert got.tolist() == list(range(1, full, 2))  # at 50 %: the upper/right of each pair


def _passes(h: int, w: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Two layers' UV passes (rows top-first) over a plate: a foreground disc (Z 1 inside, 0 outside, with u, v
    outside it from another part of its atlas, as a network leaves them) over a background (Z 1 - fg), and a seam
    in the background's atlas along a column (u jumps by 0.5)."""
    y, x = np.mgrid[0:h, 0:w] + 0.5
    inside = np.hypot(x - w * 0.4, y - h * 0.5) < h * 0.3
    fg_u = np.where(inside, 0.1 + 0.3 * x / w, 0.9 - 0.05 * x / w).astype(np.float32)
    fg_v = np.where(inside, 0.2 + 0.5 * y / h, 0.05 + rng.random((h, w)) * 0.01).astype(np.float32)
    bg_u = (x / w * 0.4 + np.where(x > w * 0.7 + 1, 0.5, 0.0)).astype(np.float32)  # seam inside a 2x2 block
    bg_v = (1 - y / h).astype(np.float32)
    fg_z = inside.astype(np.float32)
    return {"fu": fg_u, "fv": fg_v, "fz": fg_z, "bu": bg_u, "bv": bg_v, "bz": 1 - fg_z}


@pytest.mark.parametrize("percent", [25, 50, 75])
def test_resampling_keeps_u_v_z_of_the_sampled_pixel_exactly(percent):
    """Every proxy pixel's u, v and Z are those of one full-size pixel, the one under its centre, bit for bit, and
    the same pixel for all three (a solid pixel stays solid, its UV unchanged)."""
    h, w = 108, 192
    full = _passes(h, w, np.random.default_rng(0))
    size = X.proxy_size((w, h), percent)
    small = {k: X.downsample(v, size) for k, v in full.items()}
    rows_up, cols = X.centres(h, size[1]), X.centres(w, size[0])
    for j_top in range(size[1]):
        row = h - 1 - rows_up[size[1] - 1 - j_top]  # the proxy row from the top, its full-size row from the top
        for i, col in enumerate(cols.tolist()):
            for k in full:
                assert small[k][j_top, i] == full[k][row, col], (k, j_top, i)
    # rows top-first (an EXR) and bottom-up (Blender's pixels) pick the same pixels
    stacked = np.stack(list(full.values()), -1)
    assert np.array_equal(X.downsample(stacked, size), X.downsample(stacked[::-1], size, top_first=False)[::-1])
    assert set(np.unique(small["fz"]).tolist()) <= {0.0, 1.0}  # a hard matte stays hard: no half-covered pixel


def test_an_outline_does_not_mix_two_sides_uvs():
    """At 50 % each proxy pixel covers a 2x2 block; where the block straddles the foreground's outline or the
    background's atlas seam, its u, v, Z are still those of one pixel of the block, exactly. An average (what a box
    or bilinear downsample does) there gives a UV of neither side, far from every pixel of the block: paint from an
    unrelated part of the atlas would show along every edge."""
    h, w = 108, 192
    full = _passes(h, w, np.random.default_rng(1))
    size = X.proxy_size((w, h), 50)
    straddling = 0
    for layer in "fb":
        uvz = np.stack([full[f"{layer}{c}"] for c in "uvz"], -1)
        blocks = uvz.reshape(size[1], 2, size[0], 2, 3).transpose(0, 2, 1, 3, 4).reshape(size[1], size[0], 4, 3)
        small = X.downsample(uvz, size)
        assert (blocks == small[:, :, None, :]).all(-1).any(-1).all()  # one pixel of its block, all three values
        box = blocks.mean(2)
        gap = np.abs(blocks[..., :2] - box[:, :, None, :2]).max(-1).min(-1)  # box UV to the block's nearest UV
        far = (gap > 0.05) & (box[..., 2] > 0)  # shown, with a UV of neither side
        straddling += int(far.sum())
        assert far.sum() > 0, layer  # the outline (foreground) and the seam (background) do mix under an average
    assert straddling > 10


def test_the_proxy_preview_is_the_full_preview_at_the_sampled_pixels():
    """The render equation on the proxy's plate and passes equals the full-size one at the sampled pixels: paint
    lands where it lands at full size, and the plate under it is the same pixel."""
    h, w = 108, 192
    rng = np.random.default_rng(2)
    full = _passes(h, w, rng)
    plate = rng.random((h, w, 3))
    edits = {layer: rng.random((32, 32, 4)) for layer in "fb"}

    def render(plate, p):
        out, alpha = np.zeros_like(plate), np.zeros(plate.shape[:2])
        for layer in "fb":
            s = sample(edits[layer], p[f"{layer}u"], p[f"{layer}v"], "bilinear") * p[f"{layer}z"][..., None]
            out, alpha = out + s[..., :3], alpha + s[..., 3]
        return plate * (1 - alpha[..., None]) + out

    size = X.proxy_size((w, h), 50)
    small = render(X.downsample(plate, size), {k: X.downsample(v, size) for k, v in full.items()})
    assert np.array_equal(small, X.downsample(render(plate, full), size))


def _plan(tmp_path, percent, **kw):
    mp = make_export(tmp_path, **kw)
    manifest = C.load_manifest(str(mp))
    tree = P.plan_tree(manifest, str(mp), P.FILTER_BILINEAR)
    return mp, V.plan_preview(tree, manifest, str(mp), P.FILTER_BILINEAR, False, percent)


def test_the_plan_writes_the_proxy_files_in_their_own_folder(tmp_path):
    """At 50 %: each layer's UV files in ``preview_proxy/proxy_50/<Layer>/``, at the proxy size; the plate's frames
    (all of the plate's, each scene frame its own file) to ``preview_proxy/proxy_50/plate.#####``; the material and
    the camera as at 100 %. At 100 %: the files and images as they always were."""
    mp, full = _plan(tmp_path / "a", X.FULL, plate_name="shot_v2.{frame:04d}.png")
    _, half = _plan(tmp_path / "a", 50, plate_name="shot_v2.{frame:04d}.png")
    folder = mp.parent / X.PROXY_DIR / "proxy_50"
    assert (full.percent, full.size, full.plate_proxy, half.percent, half.size) == (100, (40, 24), None, 50, (20, 12))
    assert all(s.size is None for s in full.splits) and all(s.size == (20, 12) for s in half.splits)
    assert [Path(f[1]) for f in full.splits[1].files] == [
        mp.parent / V.PREVIEW_UV_DIR / "Foreground" / f"uv.{f:05d}.exr" for f in FRAMES
    ]
    assert [Path(f[1]) for f in half.splits[1].files] == [folder / "Foreground" / f"uv.{f:05d}.exr" for f in FRAMES]
    assert [f[0] for f in half.splits[1].files] == [f[0] for f in full.splits[1].files]  # the same passes read
    proxy = half.plate_proxy
    assert proxy is not None and proxy.size == (20, 12) and proxy.colorspace == full.images[0].colorspace
    assert [Path(src).name for src, _ in proxy.files] == [f"shot_v2.{f:04d}.png" for f in FRAMES]
    assert [Path(stem) for _, stem in proxy.files] == [folder / f"plate.{f:05d}" for f in FRAMES]
    assert proxy.user == V.SequenceUser(FRAMES[0], FRAMES[0] - 1, len(FRAMES))  # scene frame F: file F
    image = V.proxy_plate_image(proxy, is_float=False)
    assert (image.filepath, image.colorspace, image.source) == (
        str(folder / f"plate.{FRAMES[0]:05d}.png"),
        proxy.colorspace,
        "SEQUENCE",
    )
    assert V.proxy_plate_image(proxy, is_float=True).colorspace == "Non-Color"  # scene-linear values, as they are
    assert (half.nodes, half.links, half.framing, half.mirrors) == (full.nodes, full.links, full.framing, full.mirrors)
    assert half.resolution == full.resolution == (40, 24)
    with pytest.raises(P.PlanError, match="unknown proxy size 60%"):
        _plan(tmp_path / "b", 60)


def test_a_movie_plate_is_shown_as_it_is_and_the_passes_proxied(tmp_path):
    mp = make_export(tmp_path)
    data = json.loads(mp.read_text())
    movie = tmp_path / "plate.mov"
    movie.write_bytes(b"\0")  # the plan only checks that the file is there
    data["clip"].update(kind="movie", source=str(movie), frame_files=[], start_frame=FRAMES[0])
    mp.write_text(json.dumps(data))
    manifest = C.load_manifest(str(mp))
    tree = P.plan_tree(manifest, str(mp), P.FILTER_BILINEAR)
    plan = V.plan_preview(tree, manifest, str(mp), P.FILTER_BILINEAR, False, 25)
    assert plan.plate_proxy is None and plan.images[0].source == "MOVIE"
    assert all(s.size == (10, 6) for s in plan.splits)


def test_sequence_files_are_numbered_as_blender_numbers_them():
    assert V.sequence_file("/p/plate.1001.png", 1005) == "/p/plate.1005.png"
    assert V.sequence_file("/p/v2_shot_0007.exr", 12) == "/p/v2_shot_0012.exr"  # the last run of digits
    assert V.sequence_file("/p/f99.png", 100) == "/p/f100.png"
    assert V.sequence_file("/p/still.png", 3) == "/p/still.png"


def test_the_proxy_writers_write_what_is_read_back(tmp_path):
    """An uncompressed float EXR (what the proxies use: loaded several times faster than ZIP) as OpenEXR and this
    module's reader read it, and an 8-bit PNG of exactly the bytes given."""
    rng = np.random.default_rng(3)
    planes = [rng.random((12, 20), dtype=np.float32) for _ in range(3)]
    path = str(tmp_path / "uv.exr")
    exr_passes.write_rgb(path, *planes, compression=exr_passes.NO_COMPRESSION)
    with OpenEXR.File(path) as f:
        assert f.header()["compression"] == OpenEXR.NO_COMPRESSION
    got = read_exr_rgba(Path(path))
    assert all(np.array_equal(got[..., i], planes[i]) for i in range(3))
    assert np.array_equal(exr_passes.read_channels(path)["G"], planes[1])
    with pytest.raises(ValueError, match="ZIP or NONE"):
        exr_passes.write_rgb(path, *planes, compression=exr_passes.ZIPS_COMPRESSION)
    rgba8 = rng.integers(0, 256, (7, 5, 4), dtype=np.uint8)
    X.write_png_rgba8(str(tmp_path / "p" / "plate.png"), rgba8)
    assert np.array_equal(decode_png((tmp_path / "p" / "plate.png").read_bytes()), rgba8)
    assert not list((tmp_path / "p").glob("*.na-tmp"))


def test_a_proxy_file_is_written_again_only_when_its_source_is_newer(tmp_path):
    src, made = tmp_path / "pass.exr", tmp_path / "uv.exr"
    src.write_bytes(b"x")
    assert not X.is_fresh(str(made), str(src))
    made.write_bytes(b"y")
    os.utime(src, (1000, 1000))
    os.utime(made, (2000, 2000))
    assert X.is_fresh(str(made), str(src))
    os.utime(src, (3000, 3000))
    assert not X.is_fresh(str(made), str(src))
