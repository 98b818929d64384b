"""`render`: the edited clip from an export, by the paper's edit equations (see ``engine.edit.equations``).

Reads only the export (manifest, passes, edit layers) and the original plate, so its output is exactly
what the Blender compositor tree built from the same manifest must produce. The edits are composited in
scene-linear Rec.709 (Blender's compositing space) and the result is converted back to the plate's colour space by
OCIO; a pixel no edit covers is the plate's own value, so an empty edit gives the plate back bit for bit. Frames
are written as float EXR (in the plate's colour space when it is scene-linear, e.g. ACEScg, else in scene-linear
Rec.709, tagged with its chromaticities), PNG (sRGB) or ``plate`` (the plate's file type, bit depth and colour
space); optionally an H.264 movie through PyAV, tagged BT.709 (``engine.edit.movie``, docs/colour.md).

What it writes can never destroy what it reads: an output folder that is (or directly holds) the plate's frames
or a mask folder, or lies inside the run folder, is refused before anything is written (``output_checks``). The
frames are rendered into a hidden staging folder inside ``--out`` and moved into place together once every one is
written (``staged_folder``); a failure, a full disk or a cancel removes the staging (and ``--out`` when the render
created it), so no partial frame set is ever left and earlier files in ``--out`` are untouched. Chunks of one
render share ``--out``; a chunk of another export, other paint or other settings is refused there
(``render_record``).
"""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import OpenEXR
import OpenImageIO as oiio
from tqdm import tqdm

from .. import contract as C
from ..errors import DiskFullError, InputError
from ..export.manifest import Manifest
from ..io.atomic import DISK_ERRORS, as_disk_full, atomic_write, signals_held
from ..io.clip import iter_frames, open_clip
from ..io.colour import (
    SCENE_LINEAR,
    SRGB,
    chromaticities,
    from_linear,
    is_linear,
    linear_to_srgb,
    recorded_space,
    role_space,
    to_linear,
)
from ..io.images import exr_timing, native_path, read_spec, write_like, write_png, write_rgba_exr
from ..io.write_ahead import FRAMES_AHEAD, WriteAhead
from ..terms.colour import EXR_COLORSPACE_ATTRIBUTE
from ..terms.export_names import RENDER_FRAME_PREFIX, frame_padding
from .equations import FILTERS, composite_edits, composite_touched, edit_is_empty, load_edit
from .movie import DEFAULT_FPS, MovieWriter, movie_writer
from .output_checks import check_movie, check_output
from .render_record import RECORD_NAME, claim_folder, render_record, write_record
from .staged_folder import StagedFolder

FORMATS = ("exr", "png", "plate")
#: ``--name``'s frame token: one run of ``#`` (one per digit, as Blender and Nuke write it) or printf ``%0Nd``/``%d``.
NAME_TOKEN = re.compile(r"#+|%0?(\d*)d")
NAME_ARG = "--name"
#: ``--name``'s longest padding (a frame number of 10 digits) and longest file name in bytes (most file systems'
#: NAME_MAX): a name past either would be refused by the disk after the first frame was rendered.
MAX_NAME_DIGITS = 10
MAX_NAME_BYTES = 255
#: ``--depth``: the bits of each channel of an EXR frame: 16 (half float) or 32 (float). Default: the plate's own
#: when it is an EXR (a half plate gives half frames), else 32.
EXR_DEPTHS = ("16", "32")
DEPTH_ARG = "--depth"
#: Bytes per pixel of a rendered frame before compression (the disk-full estimate before any frame is written):
#: float32 RGBA for EXR, 8-bit RGB for PNG.
FRAME_BYTES_PER_PIXEL = {"exr": 16, "png": 3, "plate": 16}
#: The plate's file types that ``--format plate`` writes as they are; any other (JPEG, a movie) is written as PNG.
PLATE_FORMATS = (".exr", ".dpx", ".png", ".tif", ".tiff")


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
    manifest.check_layers(list(overrides))  # unknown names are a one-line error listing the layers
    edits: list[np.ndarray | None] = []
    for layer in manifest.layers:
        # the float edit layer <Layer>.exr wins over the export's PNG when both exist (contract)
        path = Path(overrides[layer["name"]]) if layer["name"] in overrides else manifest.edit_file(layer)
        if not path.exists():
            if layer["name"] in overrides:
                raise InputError(path, "edit image does not exist", "check the path given to --edit")
            edits.append(None)  # a deleted edit layer is simply no edit
            continue
        edit = load_edit(path)
        edits.append(None if edit_is_empty(edit) else edit)
    return edits


def plate_colour(manifest: Manifest) -> tuple[str, str]:
    """(colour space, OCIO config) of the manifest's plate; older manifests' "sRGB"/"linear" are mapped."""
    return recorded_space(manifest.clip["colorspace"], manifest.clip.get("colour_config"))


def plate_frames(manifest: Manifest, frames: list[int]) -> Iterator[tuple[int, np.ndarray]]:
    """(frame number, scene-linear Rec.709 float32 [H, W, 3]) of the original plate for the given frame numbers."""
    for number, _, lin in plate_pixels(manifest, frames):
        yield number, lin


def plate_pixels(manifest: Manifest, frames: list[int]) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """(frame number, the plate's own values [H, W, 3], the same as scene-linear Rec.709) for ``frames``."""
    clip = manifest.clip
    space, config = plate_colour(manifest)
    numbers = list(clip["frame_numbers"])
    positions = [numbers.index(f) for f in frames]
    first_pos = _source_position(manifest)
    lo, hi = min(positions), max(positions)
    info = open_clip(manifest.plate_source(), (first_pos + lo, first_pos + hi), space, config)
    if [info.width, info.height] != list(clip["resolution"]):
        raise InputError(
            info.source,
            f"plate is now {info.width}x{info.height}, the export was made from {clip['resolution']}",
            "render from an export of this plate (export the run again)",
        )
    wanted = set(frames)
    for k, rgb in enumerate(iter_frames(info)):
        number = numbers[lo + k]
        if number in wanted:
            lin = to_linear(rgb, space, config)
            bad = ~np.isfinite(lin)
            if bad.any():
                print(f"warning: NaN/Inf pixels in plate frame {number} set to 0", file=sys.stderr)
                lin = np.where(bad, 0.0, lin).astype(np.float32)
            yield number, rgb, lin


def _source_position(manifest: Manifest) -> int:
    """Position of the manifest's first clip frame in its source (what `open_clip` ranges count)."""
    clip = manifest.clip
    if clip["kind"] != C.CLIP_KINDS[0]:  # a movie's frames are numbered from its start frame (fit --start-frame)
        return int(clip["frame_numbers"][0]) - int(clip.get("start_frame", 0))
    info = open_clip(manifest.plate_source(), None, *plate_colour(manifest))
    first = os.path.realpath(manifest.plate_frame_file(0))
    for position, path in enumerate(info.frame_files):
        if os.path.realpath(path) == first:
            return position
    raise InputError(info.source, "the plate's frames changed since the export", "export the run again")


def render_frames(
    manifest: Manifest, edits: list[np.ndarray | None], frames: list[int] | None = None, filter: str = "bilinear"
) -> Iterator[tuple[int, np.ndarray]]:
    """(frame number, edited linear frame [H, W, 3]) for ``frames`` (default: every exported frame)."""
    frames = manifest.frames if frames is None else frames
    for f in frames:
        manifest.check_frame(f)
    for number, plate in plate_frames(manifest, frames):
        yield number, composite_edits(plate, manifest.read_passes(number), edits, filter)


def render_plate_frames(
    manifest: Manifest, edits: list[np.ndarray | None], frames: list[int] | None = None, filter: str = "bilinear"
) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """(frame number, edited frame in the plate's colour space, the same in scene-linear Rec.709). Pixels that no
    edit covers (zero coverage and zero colour added) are the plate's own values, copied: converting them to
    linear and back would cost the last bits of a float and could move an integer code value."""
    space, config = plate_colour(manifest)
    frames = manifest.frames if frames is None else frames
    for f in frames:
        manifest.check_frame(f)
    for number, raw, lin in plate_pixels(manifest, frames):
        out_lin, touched = composite_touched(lin, manifest.read_passes(number), edits, filter)
        out = from_linear(out_lin, space, config) if touched.any() else raw
        yield number, np.where(touched[..., None], out, raw).astype(np.float32), out_lin


def _plate_file(manifest: Manifest) -> tuple[oiio.ImageSpec | None, str]:
    """(the header of a plate frame to write like, its extension) for ``--format plate``: the plate's own file type
    when it is one that holds its values exactly; else (a movie, JPEG) (None, ".png"): sRGB PNG. Read once per
    render, not per frame."""
    clip = manifest.clip
    if clip["kind"] == C.CLIP_KINDS[0]:
        first = str(manifest.plate_frame_file(0))
        ext = os.path.splitext(first)[1].lower()
        if ext in PLATE_FORMATS:
            return read_spec(first), ext
    return None, ".png"


def frame_name_pattern(name: str | None, ext: str, padding: int) -> str:
    """The frames' file name as a format pattern (``shot_v001.{frame:04d}.exr``) from ``--name``
    (``shot_v001.####.exr``, ``shot_v001.%04d.exr``), or by default ``edit.`` + ``padding`` digits + ``ext``. A name
    that is a path, holds no frame token or two, or ends in another extension than the frames' ``ext`` is one line."""
    if name is None:
        return f"{RENDER_FRAME_PREFIX}{{frame:0{padding}d}}{ext}"
    example = f"e.g. {NAME_ARG} shot_v001.{'#' * padding}{ext}"
    tokens = list(NAME_TOKEN.finditer(name))
    if "/" in name or "\\" in name or name.startswith(".") or not name.isprintable():
        raise InputError(
            None, f"{NAME_ARG} {name!r} is not a plain file name", f"give the folder to --out and {example}"
        )
    if len(tokens) != 1:
        problem = "has no frame number token" if not tokens else "has more than one frame number token"
        raise InputError(None, f"{NAME_ARG} {name!r} {problem} (#### or %04d)", example)
    if os.path.splitext(name)[1].lower() != ext:
        raise InputError(None, f"{NAME_ARG} {name!r} does not end in {ext}, the extension of these frames", example)
    token = tokens[0]
    digits = len(token.group()) if token.group().startswith("#") else int(token.group(1) or 1)
    rest = name[: token.start()] + name[token.end() :]
    if "%" in rest or not token.group().startswith(("#", "%0", "%d")):
        problem = "pads its frame number with spaces" if "%" not in rest else "holds a % that is not its frame token"
        raise InputError(None, f"{NAME_ARG} {name!r} {problem}", example)
    if digits > MAX_NAME_DIGITS or len(os.fsencode(rest)) + max(digits, 10) > MAX_NAME_BYTES:
        raise InputError(
            None,
            f"{NAME_ARG} {name[:40]!r}... is longer than a file name may be, or pads to more than {MAX_NAME_DIGITS} "
            "digits",
            example,
        )
    head, tail = (part.replace("{", "{{").replace("}", "}}") for part in (name[: token.start()], name[token.end() :]))
    return f"{head}{{frame:0{digits}d}}{tail}"


def exr_half(manifest: Manifest, depth: str | None) -> bool:
    """Whether EXR frames are written as half floats: ``--depth 16``, or by default when every channel of the
    plate's first frame is half (a half EXR plate gives half frames, as the plate's own bit depth)."""
    if depth is not None:
        return depth == EXR_DEPTHS[0]
    clip = manifest.clip
    if clip["kind"] != C.CLIP_KINDS[0] or os.path.splitext(clip["frame_files"][0])[1].lower() != ".exr":
        return False
    manifest.plate_source()  # a plate that is not there: the one line naming it, as the render itself would give
    spec = read_spec(str(manifest.plate_frame_file(0)))
    formats = list(spec.channelformats) or [spec.format]
    return all(f == oiio.HALF for f in formats)


def write_half_rgba_exr(
    path: Path, rgba: np.ndarray, chromaticities: tuple[float, ...] | None, colorspace: str, attributes: dict[str, Any]
) -> Path:
    """``write_rgba_exr``'s file with half-float channels (what a half plate's frames are): the same header, ZIP
    compression, written atomically. Values beyond half's range become infinite, as in any half EXR writer."""
    header: dict[str, Any] = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if chromaticities is not None:
        header["chromaticities"] = tuple(float(v) for v in chromaticities)
    header[EXR_COLORSPACE_ATTRIBUTE] = colorspace
    header.update(attributes)
    with np.errstate(over="ignore"):  # beyond half's range: infinite, without a warning past the one-line output
        data = {c: np.ascontiguousarray(rgba[..., i], dtype=np.float16) for i, c in enumerate("RGBA"[: rgba.shape[2]])}

    def write(tmp: str) -> None:
        with OpenEXR.File(header, data) as f:
            f.write(native_path(tmp))

    return atomic_write(path, write)


def to_display_u8(frame_linear: np.ndarray) -> np.ndarray:
    """sRGB-encoded 8-bit [H, W, 3] for PNG previews and movies."""
    return np.rint(np.clip(linear_to_srgb(frame_linear), 0.0, 1.0) * 255.0).astype(np.uint8)


def chunk_frames(manifest: Manifest, frames: tuple[int, int]) -> list[int]:
    """The exported frames of the inclusive range ``frames`` (plate frame numbers); a range that is not inside the
    exported frames is one line."""
    first, last = frames
    done = manifest.frames
    if first > last or first not in done or last not in done:
        raise InputError(
            manifest.path,
            f"--frames {first}-{last} is not inside the exported frames {done[0]}-{done[-1]}",
            f"choose a range inside {done[0]}-{done[-1]} (the plate's frame numbers)",
        )
    return [f for f in done if first <= f <= last]


class _Sizes:
    """What an output has written so far, to say how much space the whole of it needs when the disk fills up."""

    def __init__(self, total: int, bytes_per_frame: int) -> None:
        self.total = total
        self.estimate = bytes_per_frame
        self.frames = 0
        self.frame_bytes = 0
        self.movie_bytes = 0

    def need(self) -> int:
        """Bytes the whole output needs: the frames written so far scaled to every frame (the uncompressed size
        before any is written), plus the movie likewise."""
        per_frame = self.frame_bytes // self.frames if self.frames else self.estimate
        movie = self.movie_bytes * self.total // self.frames if self.frames else 0
        return per_frame * self.total + movie


def _disk_full_needing(exc: BaseException, staged: StagedFolder, need: int) -> DiskFullError | None:
    """The disk-full line once the staging is gone: naming ``--out`` (not the hidden staging folder) and what the
    whole output needs; None when ``exc`` is not a full disk."""
    if not isinstance(exc, DISK_ERRORS):
        return None
    path = getattr(exc, "path", None) or getattr(exc, "filename", None)
    where = staged.out if path is None or staged.names_output(path) else Path(path)
    return as_disk_full(exc, where, need)


@dataclass(frozen=True)
class RenderSettings:
    """How each rendered frame is made and written: ``fmt`` (``FORMATS``: float EXR, 8-bit PNG, or the plate's own
    format and header), the atlas read through ``filter`` (``equations.FILTERS``), ``name`` the frames' file name
    with a frame token (``shot.####.exr``; None: ``edit.`` and the number padded as the plate's frames) and
    ``depth`` (EXR only): "16" or "32" bits a channel (None: the plate's, when it is an EXR; else 32). A value that
    is none of these is one line when the settings are made, before anything is read."""

    fmt: str = "exr"
    filter: str = "bilinear"
    name: str | None = None
    depth: str | None = None

    def __post_init__(self) -> None:
        fmt, depth = self.fmt, self.depth
        if fmt not in FORMATS:
            raise InputError(None, f"unknown --format {fmt!r}", f"use one of {', '.join(FORMATS)}")
        if self.filter not in FILTERS:
            raise InputError(None, f"unknown --filter {self.filter!r}", f"use one of {', '.join(FILTERS)}")
        if depth is not None and (depth not in EXR_DEPTHS or fmt != FORMATS[0]):
            problem = f"{DEPTH_ARG} {depth!r} is not one of {', '.join(EXR_DEPTHS)}"
            if depth in EXR_DEPTHS:
                problem = (
                    f"{DEPTH_ARG} is for --format exr, not {fmt} (png is 8-bit, plate keeps the plate's own depth)"
                )
            raise InputError(
                None, problem, f"use {DEPTH_ARG} {' or '.join(EXR_DEPTHS)} with --format exr, or leave it out"
            )


def render_manifest(
    manifest_path: str | Path,
    out_dir: str | Path,
    edit_overrides: dict[str, str] | None = None,
    settings: RenderSettings | None = None,
    movie: str | Path | None = None,
    progress_bar: bool = True,
    frames: tuple[int, int] | None = None,
) -> Path:
    """Render every exported frame (``frames``: those of that inclusive range of plate frame numbers) with the
    edits into ``out_dir`` as ``settings`` say (default: float EXR, bilinear); returns the folder (or the movie).
    All frames (and the movie) appear together, or none does. A render of a range is one chunk of a render several
    processes share: its frames join those the others committed into ``out_dir`` (the same files one whole render
    writes), and run again it writes the same files again; its movie is of that range."""
    settings = settings or RenderSettings()
    fmt = settings.fmt
    manifest = Manifest(manifest_path)
    chosen = manifest.frames if frames is None else chunk_frames(manifest, frames)
    out = Path(out_dir)
    like, ext = _plate_file(manifest) if fmt == "plate" else (None, f".{fmt}")
    clip = manifest.clip
    padding = frame_padding(clip["frame_files"], clip["frame_numbers"])
    output = _Output(like, frame_name_pattern(settings.name, ext, padding),
                     fmt == FORMATS[0] and exr_half(manifest, settings.depth), settings.filter)  # fmt: skip
    check_output(manifest, out, "--out", writes=output.pattern)
    movie_path = None if movie is None else Path(movie)
    if movie_path is not None:
        check_movie(manifest, movie_path)
    edits = load_edits(manifest, edit_overrides)
    w, h = manifest.resolution
    sizes = _Sizes(len(chosen), w * h * FRAME_BYTES_PER_PIXEL[fmt])
    stem = RENDER_FRAME_PREFIX.rstrip(".")
    what = stem if frames is None else f"{stem}-{frames[0]}-{frames[1]}"
    staged = StagedFolder(out, what, "--out", shared=frames is not None)
    record = render_record(manifest.path, edits, {"format": fmt, "names": output.pattern, "filter": output.filter,
                                                  "half": output.half})  # fmt: skip
    try:
        with staged:
            if frames is None:  # every frame: its record replaces the folder's with them
                write_record(staged.path(RECORD_NAME), record)
            else:  # a chunk: the folder's frames must be of this render
                claim_folder(out, record)
            _render_into(manifest, staged, edits, output, movie_path, progress_bar, sizes, chosen)
    except DISK_ERRORS as exc:
        full = _disk_full_needing(exc, staged, sizes.need())
        if full is None:
            raise
        raise full from None
    return movie_path if movie_path is not None else out


@dataclass(frozen=True)
class _Output:
    """How each frame is written: like a plate frame's header (``--format plate``; None: EXR or PNG), named by
    ``pattern`` (a format pattern of ``frame``), EXR channels as half floats (``half``) or float32, the atlases read
    through ``filter``."""

    like: oiio.ImageSpec | None
    pattern: str
    half: bool
    filter: str

    @property
    def png(self) -> bool:
        return self.like is None and self.pattern.lower().endswith(".png")


#: Frames written by a second thread while the next is rendered (``io.write_ahead``); 0: one after another.
RENDER_WRITE_AHEAD = FRAMES_AHEAD


def _render_into(
    manifest: Manifest,
    staged: StagedFolder,
    edits: list[np.ndarray | None],
    output: _Output,
    movie: Path | None,
    progress_bar: bool,
    sizes: _Sizes,
    frames: list[int],
) -> None:
    """Every frame of ``frames`` into the staging folder (and the movie into its temporary file), then both into
    place."""
    writer: MovieWriter | None = None
    try:
        if movie is not None:
            writer = movie_writer(manifest, movie, first_frame=frames[0])
        bar = tqdm(total=len(frames), disable=not progress_bar, file=sys.stderr, unit="frame")
        space, config = plate_colour(manifest)
        plate_is_srgb = space == role_space(SRGB, config)
        exr_space = space if is_linear(space, config) else role_space(SCENE_LINEAR, config)
        clip = manifest.clip

        def written(_number: int, path: Path) -> None:
            sizes.frames += 1
            sizes.frame_bytes += path.stat().st_size
            bar.update(1)

        with WriteAhead[Path](RENDER_WRITE_AHEAD, written, "frames") as files:
            for number, in_plate, frame in render_plate_frames(manifest, edits, frames, filter=output.filter):
                path = staged.path(output.pattern.format(frame=number))
                if output.like is not None:
                    files.submit(number, write_like, path, in_plate, output.like)
                elif not output.png:
                    timing = exr_timing(C.clip_rate(clip), clip.get("pixel_aspect", 1.0), clip.get("timecode"),
                                        number - clip["first_frame"])  # fmt: skip
                    rgb = in_plate if exr_space == space else frame
                    rgba = np.concatenate((rgb, np.ones((*frame.shape[:2], 1), np.float32)), -1)
                    write = write_half_rgba_exr if output.half else write_rgba_exr
                    files.submit(number, write, path, rgba, chromaticities(exr_space, config), exr_space,
                                 attributes=timing)  # fmt: skip
                else:
                    srgb = np.clip(in_plate if plate_is_srgb else linear_to_srgb(frame), 0.0, 1.0)
                    files.submit(number, write_png, path, srgb, 8)
                if writer is not None:
                    writer.write(to_display_u8(frame))
                    sizes.movie_bytes = writer.written_bytes()
        bar.close()
        if writer is not None:
            writer.finish()
        with signals_held():
            staged.commit()
            if writer is not None:
                writer.publish()
    except BaseException:
        if writer is not None:
            writer.abort()
        raise


__all__ = [
    "DEFAULT_FPS",
    "EXR_DEPTHS",
    "FORMATS",
    "RenderSettings",
    "chunk_frames",
    "exr_half",
    "frame_name_pattern",
    "load_edits",
    "parse_edit_args",
    "render_frames",
    "render_manifest",
    "to_display_u8",
    "write_half_rgba_exr",
]
