"""One 4K frame (4096x2160) through the real engine's export, ``engine render`` and Blender's compositor (bpy 4.5 and
5.0): the production-size counterpart of ``test_preview_equals_render.py`` and ``test_end_to_end.py``, which do the
same at 40x24 and 64x48.

The plate is one 8-bit PNG frame at 4096x2160 (a smooth textured background, a textured ellipse) with its mask. The
engine fits it at a 128-px working size with tiny networks and a few dozen steps (the fit's quality is not what is
tested), then ``engine export`` evaluates the networks at every native pixel and writes the pass file as it always
does: the default channels and precision (compact), ZIP compressed. A patch with hard edges is painted on the
foreground atlas (left unsaved, as a brush leaves it; Render Edited Clip saves it), and the frame is rendered by
Render Edited Clip (the add-on's compositor tree) and by ``engine render``: they agree at every pixel, inside the
patch and where its edges are sampled across, to the small tests' tolerance. The engine runs in its own interpreter
(``helpers.engine_python``)."""

from __future__ import annotations

import resource
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

bpy = pytest.importorskip("bpy")

import fake_export as X  # noqa: E402
from helpers import engine_python  # noqa: E402
from neural_atlas.addon.core import tree_plan as P  # noqa: E402
from test_preview_equals_render import ENGINE_TOLERANCE, _brush  # noqa: E402

from engine import contract as C  # noqa: E402
from engine.terms.cli import VERB_RENDER  # noqa: E402
from engine.terms.export_names import (  # noqa: E402
    ALPHA_CHANNELS,
    PASS_PRECISION_COMPACT,
    UV_CHANNELS,
    alpha_pass,
    uv_pass,
)

ROOT = Path(__file__).resolve().parents[2]
TAG = f"[bpy {bpy.app.version_string}]"
W, H = 4096, 2160
FRAME = 1001  # a shot's own numbering: plate.1001.png -> atlas.1001.exr -> edit.1001.exr (engine render and Blender)
LAYERS = ("Background", "Foreground")
#: The cheapest real fit: 128 px working size, tiny networks, 40 steps at a high learning rate (the mask is learned:
#: alpha IoU about 0.98), a few seconds of training; the export still evaluates it at every one of the 8.8 M pixels.
FIT = {"steps": 40, "batch": 1000, "eval_every": 40, "eval_pixels": 500, "bootstrap_steps": 40,
       "global_rigidity_steps": 10, "long_edge": 128, "mapping_hidden": 8, "mapping_layers": 1, "decoder_hidden": 8,
       "atlas_levels": 2, "alpha_levels": 2, "warp_levels": 0, "lr": 0.01, "lr_grid": 0.05}  # fmt: skip
#: The patch painted on the foreground atlas (u0, v0, u1, v1) and its colour (straight sRGB, opaque): hard edges.
PATCH = (0.35, 0.3, 0.6, 0.7)
PATCH_RGBA = (0.0, 0.9, 1.0, 1.0)
#: The patch's pixels in the frame: inside (every bilinear tap on painted texels) and at its edges (the filter mixes
#: painted and unpainted texels: the coverage strictly between 0 and 1), where Blender and the engine would differ
#: first if their sampling differed. About 180,000 and 2,900 are there (a texel is about 1.6 pixels wide).
INSIDE_MIN_PIXELS, EDGE_MIN_PIXELS = 50_000, 1_000


def _write_plate(root: Path) -> np.ndarray:
    """``root/plate/plate.1001.png`` (8-bit sRGB RGBA, opaque) and its mask ``root/masks/plate.1001.png``; the plate's
    (H, W, 4) uint8, rows top-first."""
    y, x = np.mgrid[0:H, 0:W].astype(np.float32)
    rgb = np.stack(
        [0.5 + 0.3 * np.sin(x / 97) * np.cos(y / 61), 0.4 + 0.3 * x / W, 0.3 + 0.25 * np.cos((x + 2 * y) / 150)], -1
    )
    inside = ((x - 1700) / 700) ** 2 + ((y - 1000) / 450) ** 2 < 1
    rgb[inside] = np.stack([0.85 + 0.1 * np.sin(x / 40), 0.3 + 0.1 * np.cos(y / 33), np.full_like(x, 0.2)], -1)[inside]
    plate = np.full((H, W, 4), 255, np.uint8)
    plate[..., :3] = np.round(np.clip(rgb, 0, 1) * 255)
    X.write_png(root / "plate" / f"plate.{FRAME}.png", plate)
    mask = np.zeros((H, W, 4), np.uint8)
    mask[inside] = 255
    mask[..., 3] = 255
    X.write_png(root / "masks" / f"plate.{FRAME}.png", mask)
    return plate


def _engine(py: str, *args: str) -> tuple[str, float]:
    """``python -m engine ARGS`` quietly, in the engine's interpreter: its stdout, and its peak resident set (MB: its
    ``VmHWM``, read every half second while it runs; ``getrusage`` of a child started from this large process would
    report this one's peak)."""
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        argv = [py, "-m", "engine", *args, "--no-bar", "-q"]
        proc = subprocess.Popen(argv, cwd=ROOT, stdout=out, stderr=err, text=True)
        peak, end = 0.0, time.monotonic() + 900
        while proc.poll() is None and time.monotonic() < end:
            try:
                status = Path(f"/proc/{proc.pid}/status").read_text()
                peak = max(peak, int(status.split("VmHWM:")[1].split()[0]) / 1024)
            except (OSError, IndexError):
                pass
            time.sleep(0.5)
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        out.seek(0)
        err.seek(0)
        assert proc.returncode == 0, err.read()[-2000:]
        return out.read(), peak


def _one_frame(out: Path) -> np.ndarray:
    """The one frame a render wrote into ``out``, RGBA: ``edit.1001.exr``, padded as the plate's files are, the same
    name from ``engine render`` and from Render Edited Clip."""
    found = sorted(p.name for p in out.glob("edit.*"))
    assert found == [f"edit.{FRAME}.exr"], found
    return X.read_exr_rgba(out / found[0])


def _patch_coverage(u: np.ndarray, v: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """How much of the bilinear filter's weight falls on the painted texels at each pixel's UV (0..1): the texels
    ``_brush`` wrote for PATCH on an atlas of ``size`` (w, h), sampled as Map UV and ``engine render`` sample."""
    w, h = size
    u0, v0, u1, v1 = PATCH

    def along(t: np.ndarray, lo: int, hi: int) -> np.ndarray:
        t0 = np.floor(t)
        f = t - t0
        return ((t0 >= lo) & (t0 < hi)) * (1 - f) + ((t0 + 1 >= lo) & (t0 + 1 < hi)) * f

    return along(u * w - 0.5, int(u0 * w), int(u1 * w)) * along(v * h - 0.5, int(v0 * h), int(v1 * h))


def _stats(diff: np.ndarray, where: np.ndarray | None = None) -> tuple[float, float]:
    d = diff if where is None else diff[where]
    return float(d.max()), float(d.mean())


@pytest.mark.slow
def test_4k_frame_export_render_and_compositor_agree(blender, tmp_path):
    t0 = time.monotonic()
    py = engine_python(VERB_RENDER, "torch")
    plate8 = _write_plate(tmp_path)
    run = tmp_path / "run"
    sets = [a for k, v in FIT.items() for a in ("--set", f"{k}={v}")]
    masks = ("--mask", str(tmp_path / "masks"))
    _, peak_fit = _engine(py, "fit", str(tmp_path / "plate"), *masks, "--out", str(run), *sets)
    t_fit = time.monotonic()
    printed, peak_export = _engine(py, "export", str(run))
    manifest_path = Path(printed.strip().splitlines()[-1])
    t_export = time.monotonic()

    # the export is 4K: the manifest, the plate and the pass file, with the default channels at compact precision
    manifest = C.load_manifest(str(manifest_path))
    assert manifest["clip"]["resolution"] == manifest["passes"]["resolution"] == [W, H]
    assert manifest["clip"]["working_resolution"] == [128, 68]
    assert manifest["passes"]["frames"] == [FRAME]
    assert manifest["passes"]["precision"] == PASS_PRECISION_COMPACT
    assert [layer["name"] for layer in manifest["layers"]] == list(LAYERS)
    pass_file = manifest_path.parent / manifest["passes"]["dir"] / manifest["passes"]["pattern"].format(frame=FRAME)
    assert X.read_png_rgba8(tmp_path / "plate" / f"plate.{FRAME}.png").shape == (H, W, 4)
    with OpenEXR.File(str(pass_file)) as f:
        header = dict(f.header())  # a copy: the file's own is emptied when it closes
        channels = {k: np.asarray(c.pixels) for k, c in f.channels().items()}
    (x0, y0), (x1, y1) = header["dataWindow"]
    assert (x1 - x0 + 1, y1 - y0 + 1) == (W, H)
    assert header["compression"] == OpenEXR.ZIP_COMPRESSION
    names = set()  # the UV and alpha passes alone: no STMap copy unless asked (export --stmap)
    for layer in LAYERS:
        names |= {C.channel_name(uv_pass(layer), c) for c in UV_CHANNELS}
        names |= {C.channel_name(alpha_pass(layer), c) for c in ALPHA_CHANNELS}
    assert set(channels) == names
    assert all(c.dtype == np.float32 and c.shape[:2] == (H, W) for c in channels.values())
    n_values = sum(c.size for c in channels.values())  # 8 float32 channels
    on_disk = pass_file.stat().st_size
    assert n_values == 8 * W * H
    assert 2**20 < on_disk < 4 * n_values / 2, on_disk  # real pixels; compact + ZIP: under half the raw float32
    fg_uv = [channels[C.channel_name(uv_pass("Foreground"), c)] for c in UV_CHANNELS]
    fg_alpha = channels[C.channel_name(alpha_pass("Foreground"), ALPHA_CHANNELS[0])]
    del channels

    # Blender: import, a patch on the foreground atlas left unsaved, Render Edited Clip; then engine render
    assert blender.ops.neural_atlas.import_run("EXEC_DEFAULT", filepath=str(manifest_path)) == {"FINISHED"}
    scene = blender.context.scene
    assert (scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage) == (W, H, 100)
    props = scene.neural_atlas
    assert props.filter_type == P.FILTER_DEFAULT == "bilinear"
    fg_edit = blender.data.images[P.edit_image_name("Foreground")]
    atlas_size = tuple(fg_edit.size)
    _brush(fg_edit, PATCH_RGBA, PATCH)
    t_import = time.monotonic()
    out_b, out_e = tmp_path / "blender", tmp_path / "engine"
    assert blender.ops.neural_atlas.render("EXEC_DEFAULT", directory=str(out_b), file_format="exr") == {"FINISHED"}
    assert not fg_edit.is_dirty  # Render Edited Clip saved the paint first: engine render reads the same
    t_blender = time.monotonic()
    render_args = ("--out", str(out_e), "--format", "exr", "--filter", P.FILTER_DEFAULT)
    _, peak_render = _engine(py, VERB_RENDER, str(manifest_path), *render_args)
    t_engine = time.monotonic()
    rendered, engine = _one_frame(out_b), _one_frame(out_e)
    assert rendered.shape == engine.shape == (H, W, 4)

    # where the patch is: its bilinear coverage at each pixel's foreground UV, on the foreground (rows top-first)
    u, v, cover = fg_uv
    patch = _patch_coverage(u, v, atlas_size) * (cover > 0)
    inside, edges = patch >= 1.0, (patch > 0.0) & (patch < 1.0)
    diff = np.abs(rendered[..., :3] - engine[..., :3]).max(axis=-1)
    plate = X.srgb_to_linear(plate8[..., :3] / 255.0)
    painted = np.abs(engine[..., :3] - plate).max(axis=-1)
    stats = {"frame": _stats(diff), "inside": _stats(diff, inside), "edges": _stats(diff, edges)}
    print(
        f"{TAG} 4K frame: pass file {on_disk / 2**20:.1f} MB; {int(inside.sum())} pixels inside the patch, "
        f"{int(edges.sum())} at its edges; Blender vs engine render, max / mean: "
        + ", ".join(f"{k} {m:.1e} / {a:.1e}" for k, (m, a) in stats.items())
        + f"; the paint moves the plate by {painted[inside].mean():.2f} inside (mean); seconds: plate + fit "
        f"{t_fit - t0:.0f}, export {t_export - t_fit:.0f}, import + paint {t_import - t_export:.0f}, Blender render "
        f"{t_blender - t_import:.0f}, engine render {t_engine - t_blender:.0f}; peak RSS: this process "
        f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB, engine fit {peak_fit:.0f} MB, export "
        f"{peak_export:.0f} MB, render {peak_render:.0f} MB"
    )
    # the patch is really there, on the object, with edges the filter samples across
    assert float(fg_alpha[inside].min()) > 0.1 and painted[inside].mean() > 0.2
    assert inside.sum() >= INSIDE_MIN_PIXELS and edges.sum() >= EDGE_MIN_PIXELS
    for name, (worst, _) in stats.items():
        assert worst <= ENGINE_TOLERANCE, (name, stats)
