"""A tiny export written by the tests themselves (manifest + EXR passes + PNGs), and the render equation
in numpy, so compositor tests need no fit. Files follow ``engine/contract.py`` exactly."""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import numpy as np
import OpenEXR

from engine import contract as C
from engine.terms.export_names import (
    ALPHA_CHANNELS,
    ATLASES_DIR,
    EDIT_LAYER_EXT,
    EDITS_DIR,
    EXPORT_VERSION_FORMAT,
    EXR_LAYER,
    LEGACY_UV_CHANNELS,
    PASS_FILE_EXT,
    PASS_FILE_PREFIX,
    PASSES_DIR,
    ROLE_BACKGROUND,
    alpha_pass,
    frame_padding,
    layer_name,
    pass_file_name,
    uv_pass,
)
from engine.terms.manifest import MANIFEST_TAG, MANIFEST_VERSION
from engine.terms.versions import ENGINE_VERSION

W, H = 40, 24
FRAMES = (3, 4, 5)  # plate frame numbers: not starting at 0 or 1, so frame mapping is tested
ATLAS_SIZES = {"Background": (32, 32), "Foreground": (16, 16)}
#: Atlas sizes of the extra layers of a multi-foreground export (Foreground1, Foreground2, ...).
EXTRA_ATLAS_SIZE = (24, 16)


def write_png(path: Path, rgba8: np.ndarray) -> None:
    """8-bit RGBA PNG, rows top-first (stdlib only: both test venvs can write it)."""
    h, w, _ = rgba8.shape
    raw = b"".join(b"\x00" + rgba8[r].astype(np.uint8).tobytes() for r in range(h))

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 6, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(png)


def write_exr(path: Path, channels: dict[str, np.ndarray]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {k: np.ascontiguousarray(v, np.float32) for k, v in channels.items()}).write(str(path))


def read_exr_rgba(path: Path) -> np.ndarray:
    """(H, W, 4) float32, rows top-first."""
    with OpenEXR.File(str(path)) as f:
        ch = f.channels()
        if "RGBA" in ch:
            return np.asarray(ch["RGBA"].pixels, np.float32)
        if "RGB" in ch:  # no alpha: opaque
            rgb = np.asarray(ch["RGB"].pixels, np.float32)
            return np.concatenate((rgb, np.ones((*rgb.shape[:2], 1), np.float32)), -1)
        return np.stack([np.asarray(ch[c].pixels, np.float32) for c in "RGBA"], axis=-1)


def _uv_grid(
    t: int, layer: int, size: tuple[int, int], plate: tuple[int, int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """UVs on texel centres plus an offset below 0.3 texel: nearest sampling has no ties."""
    aw, ah = size
    W, H = plate or plate_size()
    y, x = np.mgrid[0:H, 0:W]  # y counted from the top row
    y_up = H - 1 - y
    rng = np.random.default_rng(100 * t + layer)
    i = np.clip(((x + 0.5) / W * 0.7 + 0.15 + 0.03 * t) * aw, 0, aw - 1).astype(int)
    j = np.clip(((y_up + 0.5) / H * 0.7 + 0.1 + 0.02 * t * layer) * ah, 0, ah - 1).astype(int)
    u = (i + 0.5 + rng.uniform(-0.3, 0.3, (H, W))) / aw
    v = (j + 0.5 + rng.uniform(-0.3, 0.3, (H, W))) / ah
    return u.astype(np.float32), v.astype(np.float32)


def _alphas(t: int, foregrounds: int = 1, plate: tuple[int, int] | None = None) -> list[np.ndarray]:
    """[bg, fg1, fg2, ...]: discs crossing each other; each later disc is behind the earlier ones (on a ``plate``
    size given, the 40x24 picture scaled by its width)."""
    W, H = plate or plate_size()
    s = W / 40 if plate else 1.0
    y, x = (np.mgrid[0:H, 0:W] + 0.5) / s
    fgs: list[np.ndarray] = []
    left = np.ones((H, W), np.float32)
    for k in range(foregrounds):
        d = np.hypot(x - (14 + 4 * t) - 10 * k, y - 12 + 3 * k)
        fg = (np.clip((9.0 - d) / 3.0, 0, 1) * left).astype(np.float32)
        left = left - fg
        fgs.append(fg)
    bg = (0.85 * left).astype(np.float32)  # below 1 - sum(fg): the plate shows through, as the equation allows
    return [bg, *fgs]


def plate_size() -> tuple[int, int]:
    """The module's plate size (``W``, ``H``), read when called: a test may set them for its own export."""
    return W, H


def layer_names(foregrounds: int = 1) -> list[str]:
    return [layer_name(i, foregrounds + 1) for i in range(foregrounds + 1)]


def make_export(
    root: Path,
    seed: int = 0,
    foregrounds: int = 1,
    frames: tuple[int, ...] = FRAMES,
    clip_fields: dict | None = None,
    plate_name: str = "{frame:05d}.png",
    size: tuple[int, int] | None = None,
) -> Path:
    """Write plate, passes, atlases and edit layers; returns the manifest path. ``frames``: the plate's frame
    numbers; ``clip_fields``: more fields of the manifest's clip (its timing: rate, pixel_aspect, timecode);
    ``plate_name``: the plate files' name (``plate.{frame}.png``: a shot's own numbering); ``size``: the plate's
    (width, height), the module's ``W`` x ``H`` unless told."""
    W, H = size or plate_size()
    rng = np.random.default_rng(seed)
    run = root / "run"
    exp = run / C.EXPORTS_DIR / EXPORT_VERSION_FORMAT.format(1)
    plate_dir = root / "plate"
    frame_files = []
    for t in frames:
        path = plate_dir / plate_name.format(frame=t)
        img = rng.integers(0, 256, (H, W, 4), dtype=np.uint8)
        img[..., 3] = 255
        write_png(path, img)
        frame_files.append(str(path))
    layers = []
    names = layer_names(foregrounds)
    for idx, name in enumerate(names):
        aw, ah = ATLAS_SIZES.get(name, EXTRA_ATLAS_SIZE)
        edit = rng.integers(0, 256, (ah, aw, 4), dtype=np.uint8)
        edit[..., 3][rng.random((ah, aw)) < 0.2] = 0
        edit[..., 3][rng.random((ah, aw)) < 0.2] = 255
        write_png(run / EDITS_DIR / f"{name}{EDIT_LAYER_EXT}", edit)
        write_png(exp / ATLASES_DIR / f"{name}.png", rng.integers(0, 256, (ah, aw, 4), dtype=np.uint8))
        layers.append(
            {
                "name": name,
                "index": idx,
                "role": ROLE_BACKGROUND if idx == 0 else C.ROLE_FOREGROUND,
                "uv_pass": uv_pass(name),
                "alpha_pass": alpha_pass(name),
                "uv_channels": list(LEGACY_UV_CHANNELS),  # the X, Y, Z naming of older exports: still read
                "alpha_channels": list(ALPHA_CHANNELS),
                "atlas_exr": f"{ATLASES_DIR}/{name}.exr",
                "atlas_png": f"{ATLASES_DIR}/{name}.png",
                "atlas_size": [aw, ah],
                "edit_layer": str(run / EDITS_DIR / f"{name}{EDIT_LAYER_EXT}"),
                "atlas_box": [0.0, 0.0, 1.0, 1.0],
            }
        )
    for t in frames:
        ch = {}
        for idx, (name, z) in enumerate(zip(names, _alphas(t, foregrounds, size), strict=True)):
            u, v = _uv_grid(t, idx, ATLAS_SIZES.get(name, EXTRA_ATLAS_SIZE), (W, H))
            ch[C.channel_name(uv_pass(name), "X")] = u
            ch[C.channel_name(uv_pass(name), "Y")] = v
            ch[C.channel_name(uv_pass(name), "Z")] = z
            ch[C.channel_name(alpha_pass(name), "V")] = z
        write_exr(exp / PASSES_DIR / pass_file_name(t), ch)
    manifest = {
        MANIFEST_TAG: MANIFEST_VERSION,
        "engine_version": ENGINE_VERSION,
        "run_dir": str(run),
        "created": "2026-01-01T00:00:00Z",
        "clip": {
            "source": str(plate_dir),
            "kind": "sequence",
            "frame_files": frame_files,
            "frame_numbers": list(frames),
            "first_frame": frames[0],
            "last_frame": frames[-1],
            "fps": 25.0,
            "resolution": [W, H],
            "working_resolution": [W, H],
            "colorspace": "sRGB",
            **(clip_fields or {}),
        },
        "passes": {
            "dir": PASSES_DIR,
            "pattern": PASS_FILE_PREFIX + "{frame:05d}" + PASS_FILE_EXT,
            "blender_pattern": PASS_FILE_PREFIX + "#####" + PASS_FILE_EXT,
            "frames": list(frames),
            "exr_layer": EXR_LAYER,
            "resolution": [W, H],
        },
        "layers": layers,
        "fit": {"preset": "draft", "model": "fast", "steps": 0, "train_seconds": 0.0, "psnr": None},
    }
    path = exp / C.MANIFEST_NAME
    path.write_text(json.dumps(manifest, indent=2))
    return path


# --- the render equation in numpy ------------------------------------------------------------------------
def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


#: PNG colour types the decoder reads: RGB and RGBA, 8 bits per channel.
PNG_CHANNELS = {2: 3, 6: 4}


def decode_png(data: bytes) -> np.ndarray:
    """(h, w, 3 or 4) uint8, rows top-first, of an 8-bit RGB or RGBA PNG (any row filters: Blender's writer
    uses them)."""
    pos, idat, w, h, channels = 8, b"", 0, 0, 0
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos : pos + 4])
        tag, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + n]
        if tag == b"IHDR":
            w, h = struct.unpack(">II", body[:8])
            assert body[8] == 8, "8 bits per channel"
            channels = PNG_CHANNELS[body[9]]
        elif tag == b"IDAT":
            idat += body
        pos += 12 + n
    stride = channels * w
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, 1 + stride)
    out = np.zeros((h, stride), np.int32)
    for r in range(h):  # undo the PNG row filters
        kind, line = raw[r, 0], raw[r, 1:].astype(np.int32)
        prev = out[r - 1] if r else np.zeros(stride, np.int32)
        if kind == 0:
            out[r] = line
        elif kind == 2:
            out[r] = (line + prev) % 256
        else:
            cur = np.zeros(stride, np.int32)
            for i in range(stride):
                a = cur[i - channels] if i >= channels else 0
                c = prev[i - channels] if i >= channels else 0
                b = prev[i]
                if kind == 1:
                    pred = a
                elif kind == 3:
                    pred = (a + b) // 2
                else:
                    p = a + b - c
                    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                    pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                cur[i] = (line[i] + pred) % 256
            out[r] = cur
    return out.reshape(h, w, channels).astype(np.uint8)


def read_png_rgba8(path: Path) -> np.ndarray:
    """(h, w, 4) uint8 of an RGBA PNG (what ``write_png`` and Blender write), rows top-first."""
    rgba = decode_png(Path(path).read_bytes())
    assert rgba.shape[2] == 4, f"{path} is not RGBA"
    return rgba


def sample(tex: np.ndarray, u: np.ndarray, v: np.ndarray, filt: str) -> np.ndarray:
    """Sample a (h, w, 4) texture (rows top-first) at UVs (origin bottom-left); outside -> 0 (Clip)."""
    h, w, _ = tex.shape
    up = tex[::-1]  # rows bottom-first, like UV space
    if filt == "nearest":
        i, j = np.floor(u * w).astype(int), np.floor(v * h).astype(int)
        ok = (i >= 0) & (i < w) & (j >= 0) & (j < h)
        out = up[np.clip(j, 0, h - 1), np.clip(i, 0, w - 1)]
        return np.where(ok[..., None], out, 0.0)
    x, y = u * w - 0.5, v * h - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]

    def tap(ii: np.ndarray, jj: np.ndarray) -> np.ndarray:
        ok = (ii >= 0) & (ii < w) & (jj >= 0) & (jj < h)
        return np.where(ok[..., None], up[np.clip(jj, 0, h - 1), np.clip(ii, 0, w - 1)], 0.0)

    return (
        tap(x0, y0) * (1 - fx) * (1 - fy)
        + tap(x0 + 1, y0) * fx * (1 - fy)
        + tap(x0, y0 + 1) * (1 - fx) * fy
        + tap(x0 + 1, y0 + 1) * fx * fy
    )


def _resolve(manifest_path: Path, path: str) -> Path:
    return Path(C.resolve_manifest_path(str(manifest_path), path))


def reference_frame(
    manifest_path: Path, frame: int, filt: str, decode=srgb_to_linear, read_rgba8=read_png_rgba8
) -> np.ndarray:
    """out = plate * (1 - sum A_i) + sum rgb_i, (H, W, 3) float64, rows top-first."""
    m = json.loads(Path(manifest_path).read_text())
    plate_path = _resolve(manifest_path, m["clip"]["frame_files"][m["clip"]["frame_numbers"].index(frame)])
    if plate_path.suffix == ".exr":  # a linear float plate: read raw
        plate = read_exr_rgba(plate_path)[..., :3].astype(np.float64)
    else:
        plate = decode(read_rgba8(plate_path)[..., :3] / 255.0)
    with OpenEXR.File(
        str(Path(manifest_path).parent / m["passes"]["dir"] / m["passes"]["pattern"].format(frame=frame))
    ) as f:
        ch = {k: np.asarray(v.pixels, np.float64) for k, v in f.channels().items()}
    alpha_sum = np.zeros(plate.shape[:2])
    rgb_sum = np.zeros(plate.shape)
    for layer in m["layers"]:
        edit_path = Path(C.edit_layer_file(str(_resolve(manifest_path, layer["edit_layer"]))))  # .exr wins
        if edit_path.suffix == ".exr":  # linear float, premultiplied: used as is
            premult = read_exr_rgba(edit_path).astype(np.float64)
        else:
            edit8 = read_rgba8(edit_path)
            a = edit8[..., 3:4] / 255.0
            premult = np.concatenate([decode(edit8[..., :3] / 255.0) * a, a], axis=-1)
        uvp = layer["uv_pass"]
        u, v, z = (ch[C.channel_name(uvp, c)] for c in layer["uv_channels"])  # u, v, coverage: either naming
        s = sample(premult, u, v, filt) * z[..., None]
        rgb_sum += s[..., :3]
        alpha_sum += s[..., 3]
    return plate * (1 - alpha_sum[..., None]) + rgb_sum


def edit_file(manifest_path: Path | str, frame: int, ext: str = ".exr") -> str:
    """The name ``engine render`` gives plate frame ``frame`` of the export by default, and Render Edited Clip too:
    ``edit.`` and the number padded as the plate's files are (``frame_padding`` of the manifest's clip record:
    ``edit.00003.exr`` for this module's ``00003.png`` plates, ``edit.1011.exr`` for ``plate.1011.png``)."""
    clip = json.loads(Path(manifest_path).read_text())["clip"]
    padding = frame_padding(clip["frame_files"], clip["frame_numbers"])
    return f"edit.{frame:0{padding}d}{ext}"


def edit_names(out_dir: Path | str) -> list[str]:
    """The frame files a render wrote into ``out_dir`` (``edit.*``), sorted."""
    return sorted(p.name for p in Path(out_dir).glob("edit.*"))


def render_error(out_dir: Path, manifest_path: Path, filt: str, decode=srgb_to_linear, frames=FRAMES) -> float:
    """The largest difference, over ``frames``, between a render's frames ``out_dir/edit.<frame>.exr`` (RGB, named as
    ``edit_file``) and the render equation of the export (``filt``: the engine's filter, nearest or bilinear)."""
    return max(
        float(
            np.abs(
                read_exr_rgba(out_dir / edit_file(manifest_path, f))[..., :3]
                - reference_frame(manifest_path, f, filt, decode)
            ).max()
        )
        for f in frames
    )


def blender_srgb_lut(bpy, folder: Path) -> np.ndarray:
    """Blender's own decode of the 256 sRGB byte values to linear, measured through a compositor render."""
    from neural_atlas.addon import compat, compositor

    ramp = np.zeros((4, 256, 4), np.uint8)  # 4 rows: Blender's smallest render height
    ramp[..., :3] = np.arange(256, dtype=np.uint8)[None, :, None]
    ramp[..., 3] = 255
    write_png(folder / "ramp.png", ramp)
    scene = bpy.data.scenes.new("NA_test_lut")  # its own scene: any scene's compositor stays as it is
    tree = compat.scene_tree(scene)
    img = bpy.data.images.load(str(folder / "ramp.png"))
    img.colorspace_settings.name = "sRGB"
    n_img = tree.nodes.new("CompositorNodeImage")
    n_img.image = img
    compositor.add_output(tree, n_img.outputs["Image"])
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = 256, 4, 100
    scene.frame_start = scene.frame_end = 1
    out = compositor.render(scene, str(folder / "lut"), "exr")
    lut = read_exr_rgba(Path(out[0]))[0, :, 0].astype(np.float64)
    assert (np.diff(lut) > 0).all(), "the ramp did not render"
    bpy.data.scenes.remove(scene)
    bpy.data.images.remove(img)
    return lut


def lut_decoder(lut: np.ndarray):
    return lambda c: lut[np.round(np.asarray(c) * 255).astype(int)]


def blender_read_rgba8(bpy):
    """A file reader through Blender: a byte image's ``pixels`` are its stored 8-bit values (no colour
    management), rows bottom-up; returned as (h, w, 4) uint8 rows top-first."""

    def read(path: Path) -> np.ndarray:
        img = bpy.data.images.load(str(path), check_existing=False)
        w, h = img.size
        px = np.zeros(w * h * 4, np.float32)
        img.pixels.foreach_get(px)
        bpy.data.images.remove(img)
        return np.round(px.reshape(h, w, 4)[::-1] * 255).astype(np.uint8)

    return read
