"""`render`: the edited clip from an export, by the paper's edit equations (see ``engine.edit.equations``).

Reads only the export (manifest, passes, edit layers) and the original plate, so its output is exactly
what the Blender compositor tree built from the same manifest must produce. Frames are written as float
EXR (scene-linear, what Blender writes) or PNG (sRGB); optionally an H.264 movie through PyAV.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from tqdm import tqdm

from engine import contract as C
from engine.edit.equations import composite_edits, edit_is_empty, load_edit
from engine.errors import InputError
from engine.export.manifest import Manifest
from engine.io.clip import iter_frames, open_clip
from engine.io.colour import linear_to_srgb, to_linear
from engine.io.images import write_png, write_rgba_exr

FORMATS = ("exr", "png")
OUTPUT_PREFIX = "edit."
#: Frames per second of the movie when the plate has no rate (image sequences).
DEFAULT_FPS = 25.0
#: H.264 constant rate factor of the movies: visually lossless, so the movie judges the edit, not the codec.
MOVIE_CRF = 18


def parse_edit_args(items: list[str]) -> dict[str, str]:
    """``["Foreground=paint.png"]`` -> {"Foreground": "paint.png"}; a malformed item is a one-line error."""
    out: dict[str, str] = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            raise InputError(None, f"--edit {item!r} is not LAYER=IMAGE", "write e.g. --edit Foreground=paint.png")
        out[name.strip()] = path.strip()
    return out


def load_edits(manifest: Manifest, overrides: dict[str, str] | None = None) -> list[np.ndarray | None]:
    """Each layer's edit as premultiplied linear RGBA; the export's edit layer unless overridden."""
    overrides = dict(overrides or {})
    for name in overrides:
        manifest.layer(name)  # unknown names are a one-line error listing the layers
    edits: list[np.ndarray | None] = []
    for layer in manifest.layers:
        if layer["name"] in overrides:
            path = Path(overrides[layer["name"]])
        else:  # the float edit layer <Layer>.exr wins over the export's PNG when both exist (contract)
            path = Path(C.edit_layer_file(str(manifest.edit_path(layer))))
        if not path.exists():
            if layer["name"] in overrides:
                raise InputError(path, "edit image does not exist", "check the path given to --edit")
            edits.append(None)  # a deleted edit layer is simply no edit
            continue
        edit = load_edit(path)
        edits.append(None if edit_is_empty(edit) else edit)
    return edits


def plate_frames(manifest: Manifest, frames: list[int]) -> Iterator[tuple[int, np.ndarray]]:
    """(frame number, linear float32 [H, W, 3]) of the original plate for the given frame numbers."""
    clip = manifest.clip
    numbers = list(clip["frame_numbers"])
    positions = [numbers.index(f) for f in frames]
    first_pos = _source_position(manifest)
    lo, hi = min(positions), max(positions)
    info = open_clip(clip["source"], (first_pos + lo, first_pos + hi))
    if (info.width, info.height) != tuple(clip["resolution"]):
        raise InputError(
            clip["source"],
            f"plate is now {info.width}x{info.height}, the export was made from {clip['resolution']}",
            "render from an export of this plate (export the run again)",
        )
    wanted = set(frames)
    for k, rgb in enumerate(iter_frames(info)):
        number = numbers[lo + k]
        if number in wanted:
            lin = to_linear(rgb, clip["colorspace"])
            bad = ~np.isfinite(lin)
            if bad.any():
                print(f"warning: NaN/Inf pixels in plate frame {number} set to 0", file=sys.stderr)
                lin = np.where(bad, 0.0, lin).astype(np.float32)
            yield number, lin


def _source_position(manifest: Manifest) -> int:
    """Position of the manifest's first clip frame in its source (what `open_clip` ranges count)."""
    clip = manifest.clip
    if clip["kind"] != "sequence":
        return int(clip["frame_numbers"][0])
    info = open_clip(clip["source"])
    try:
        return list(info.frame_files).index(clip["frame_files"][0])
    except ValueError:
        raise InputError(
            clip["source"], "the plate's frames changed since the export", "export the run again"
        ) from None


def render_frames(
    manifest: Manifest, edits: list[np.ndarray | None], frames: list[int] | None = None, filter: str = "bilinear"
) -> Iterator[tuple[int, np.ndarray]]:
    """(frame number, edited linear frame [H, W, 3]) for ``frames`` (default: every exported frame)."""
    frames = manifest.frames if frames is None else frames
    for f in frames:
        manifest.check_frame(f)
    for number, plate in plate_frames(manifest, frames):
        yield number, composite_edits(plate, manifest.read_passes(number), edits, filter)


def to_display_u8(frame_linear: np.ndarray) -> np.ndarray:
    """sRGB-encoded 8-bit [H, W, 3] for PNG previews and movies."""
    return np.rint(np.clip(linear_to_srgb(frame_linear), 0.0, 1.0) * 255.0).astype(np.uint8)


class MovieWriter:
    """H.264 (yuv420p) through PyAV; odd sizes are padded by one pixel (the codec needs even sides)."""

    def __init__(self, path: Path, fps: float, size: tuple[int, int]) -> None:
        import av

        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self.tmp = path.with_name(f".{path.stem}.tmp{path.suffix}")
        self.container = av.open(str(self.tmp), mode="w")
        self.stream = self.container.add_stream("libx264", rate=round(fps or DEFAULT_FPS))
        w, h = size
        self.size = (w + w % 2, h + h % 2)
        self.stream.width, self.stream.height = self.size
        self.stream.pix_fmt = "yuv420p"
        self.stream.options = {"crf": str(MOVIE_CRF)}

    def write(self, rgb_u8: np.ndarray) -> None:
        import av

        h, w = rgb_u8.shape[:2]
        if (w, h) != self.size:
            rgb_u8 = np.pad(rgb_u8, ((0, self.size[1] - h), (0, self.size[0] - w), (0, 0)), mode="edge")
        frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb_u8), format="rgb24")
        for packet in self.stream.encode(frame):
            self.container.mux(packet)

    def close(self) -> Path:
        for packet in self.stream.encode():
            self.container.mux(packet)
        self.container.close()
        self.tmp.replace(self.path)
        return self.path


def render_manifest(
    manifest_path: str | Path,
    out_dir: str | Path,
    edit_overrides: dict[str, str] | None = None,
    fmt: str = "exr",
    filter: str = "bilinear",
    movie: str | Path | None = None,
    progress_bar: bool = True,
) -> Path:
    """Render every exported frame with the edits into ``out_dir``; returns the folder (or the movie)."""
    if fmt not in FORMATS:
        raise InputError(None, f"unknown --format {fmt!r}", f"use one of {', '.join(FORMATS)}")
    manifest = Manifest(manifest_path)
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(out, f"cannot create the output folder ({exc.strerror})", "choose a writable --out") from None
    edits = load_edits(manifest, edit_overrides)
    writer = None
    if movie is not None:
        fps = manifest.clip.get("fps") or DEFAULT_FPS
        writer = MovieWriter(Path(movie), float(fps), manifest.resolution)
    bar = tqdm(total=len(manifest.frames), disable=not progress_bar, file=sys.stderr, unit="frame")
    for number, frame in render_frames(manifest, edits, filter=filter):
        name = f"{OUTPUT_PREFIX}{number:05d}.{fmt}"
        if fmt == "exr":
            rgba = np.concatenate((frame, np.ones((*frame.shape[:2], 1), np.float32)), -1)
            write_rgba_exr(out / name, rgba)
        else:
            write_png(out / name, np.clip(linear_to_srgb(frame), 0.0, 1.0), 8)
        if writer is not None:
            writer.write(to_display_u8(frame))
        bar.update(1)
    bar.close()
    if writer is not None:
        return writer.close()
    return out


__all__ = ["FORMATS", "load_edits", "parse_edit_args", "render_frames", "render_manifest", "to_display_u8"]
