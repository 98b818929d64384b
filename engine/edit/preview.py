"""`preview`: what a person looks at to judge an export (paper Fig. 5-style checks).

* ``atlases.png`` — every layer's atlas texture over a grey checker (where it shows, coverage is high)
  and its coverage alpha below it;
* ``checkerboard.png/.mp4`` — a checkerboard painted on each foreground atlas, rendered onto the clip:
  if the mapping is good the squares stick to the object and do not swim;
* ``propagation.png/.mp4`` — horizontal stripes painted on the first frame, projected onto the atlases
  (``project-frame``) and rendered in every frame: stripes on the object must move with the object, and
  stripes on the background with the background.

Everything goes through the same code as ``render`` and ``project-frame``, so what the preview shows is
what the artist gets. Nothing here touches the run's edit layers. The sheets and movies appear together once
all are written, or none does.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import cv2
import numpy as np

from .. import contract as C
from ..errors import InputError
from ..export.manifest import Manifest
from ..io.atomic import DISK_ERRORS, as_disk_full, atomic_write
from ..io.images import cv2_write, read_image
from ..terms.cli import VERB_PREVIEW
from ..terms.paths import is_within
from .equations import edit_to_premultiplied
from .movie import MOVIE_SIZE_FIX, movie_size_problem, movie_writer
from .output_checks import check_output
from .project_frame import project_to_textures
from .render import plate_frames, render_frames, to_display_u8
from .staged_folder import StagedFolder

#: The export's own preview folder (``preview`` beside the manifest), the default output.
PREVIEW_DIR = "preview"
#: Width of one frame tile in the contact sheets, and of one atlas in the atlas sheet.
TILE_W = 320
ATLAS_TILE_W = 384
#: Cells of the grey checker behind an atlas, along each side.
ATLAS_CHECKER_CELLS = 24
#: Frame rate of the preview movies when the plate has none (an image sequence carries no rate).
PREVIEW_FPS = 12.0
#: Frames shown in a contact sheet.
SHEET_FRAMES = 4
#: Checker squares along the atlas's long side.
CHECKER_SQUARES = 16
CHECKER_ALPHA = 0.8
STRIPE_PERIOD = 12  # fraction of the frame height: 1/12 per stripe pair
STRIPE_ALPHA = 0.75
STRIPE_COLOURS = np.array([[1.0, 0.15, 0.1], [0.1, 0.4, 1.0]], np.float32)  # sRGB red / blue


def tile(img_u8: np.ndarray, width: int = TILE_W) -> np.ndarray:
    h, w = img_u8.shape[:2]
    height = max(1, round(h * width / w))
    return cv2.resize(img_u8, (width, height), interpolation=cv2.INTER_AREA if w > width else cv2.INTER_LINEAR)


def label(img: np.ndarray, text: str) -> np.ndarray:
    out = img.copy()
    cv2.putText(out, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(out, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def write_png_u8(path: Path, rgb_u8: np.ndarray) -> Path:
    """An 8-bit RGB PNG, atomically (a full disk is one line and leaves no partial file)."""

    def write(tmp: str) -> None:
        cv2_write(tmp, cv2.cvtColor(rgb_u8, cv2.COLOR_RGB2BGR))

    return atomic_write(path, write)


def grid(rows: list[list[np.ndarray]]) -> np.ndarray:
    width = max(sum(t.shape[1] for t in r) for r in rows)
    out_rows = []
    for r in rows:
        h = max(t.shape[0] for t in r)
        padded = [np.pad(t, ((0, h - t.shape[0]), (0, 0), (0, 0))) for t in r]
        row = np.concatenate(padded, 1)
        out_rows.append(np.pad(row, ((0, 0), (0, width - row.shape[1]), (0, 0))))
    return np.concatenate(out_rows, 0)


def atlas_sheet(manifest: Manifest) -> np.ndarray:
    """Each layer's atlas over a grey checker, its coverage below."""
    cols = []
    for layer in manifest.layers:
        pixels, _ = read_image(manifest.resolve(layer["atlas_png"]))
        rgb, a = pixels[..., :3], pixels[..., 3:4]
        h, w = a.shape[:2]
        yy, xx = np.mgrid[0:h, 0:w]
        cells = ATLAS_CHECKER_CELLS
        check = np.where(((yy // max(1, h // cells)) + (xx // max(1, w // cells))) % 2 == 0, 0.35, 0.55)
        over = rgb * a + check[..., None] * (1.0 - a)
        top = label(tile((np.clip(over, 0, 1) * 255).astype(np.uint8), ATLAS_TILE_W), f"{layer['name']} atlas")
        cov = label(tile((np.repeat(a, 3, -1) * 255).astype(np.uint8), ATLAS_TILE_W), "coverage")
        cols.append(np.concatenate((top, cov), 0))
    return grid([cols])


def checker_edit(size: tuple[int, int], squares: int = CHECKER_SQUARES) -> np.ndarray:
    """A checkerboard edit layer (premultiplied linear RGBA) with square cells."""
    w, h = size
    cell = max(1, max(w, h) // squares)
    yy, xx = np.mgrid[0:h, 0:w]
    on = ((yy // cell) + (xx // cell)) % 2 == 0
    srgb = np.where(on[..., None], np.full(3, 0.95, np.float32), np.full(3, 0.05, np.float32))
    rgba = np.concatenate((srgb, np.full((h, w, 1), CHECKER_ALPHA, np.float32)), -1)
    return edit_to_premultiplied(rgba, is_float=False)


def checker_edits(manifest: Manifest) -> list[np.ndarray | None]:
    """A checkerboard on every foreground atlas (on the background when it is the only layer)."""
    if len(manifest.layers) == 1:
        return [checker_edit(tuple(manifest.layers[0]["atlas_size"]))]
    return [None] + [checker_edit(tuple(layer["atlas_size"])) for layer in manifest.layers[1:]]


def stripes_frame_edit(size: tuple[int, int]) -> np.ndarray:
    """Horizontal stripes over a whole frame (premultiplied linear RGBA), every other band painted."""
    w, h = size
    band = max(1, h // (2 * STRIPE_PERIOD))
    rows = np.arange(h) // band
    idx = (rows // 2) % 2
    painted = (rows % 2 == 0)[:, None].repeat(w, 1)
    srgb = STRIPE_COLOURS[idx][:, None, :].repeat(w, 1)
    rgba = np.concatenate((srgb, (painted * STRIPE_ALPHA)[..., None].astype(np.float32)), -1)
    return edit_to_premultiplied(rgba, is_float=False)


def _sheet_frames(frames: list[int]) -> list[int]:
    n = len(frames)
    picks = sorted({round(i * (n - 1) / max(SHEET_FRAMES - 1, 1)) for i in range(min(SHEET_FRAMES, n))})
    return [frames[i] for i in picks]


def write_previews(manifest_path: str | Path, out_dir: str | Path | None = None, movies: bool = True) -> list[Path]:
    """Write the preview sheets (and movies) of an export; returns the paths written. They appear together once all
    are written, or none does (``StagedFolder``). The default folder is the export's ``preview/``, written under the
    run folder's lock; another ``--out`` must not be the plate's, a mask folder or inside the run folder."""
    manifest = Manifest(manifest_path)
    too_big = movie_size_problem(manifest.resolution) if movies else None
    if too_big is not None:
        raise InputError(manifest.path, too_big, MOVIE_SIZE_FIX)
    out = Path(out_dir) if out_dir else manifest.resolve_write(PREVIEW_DIR)
    check_output(manifest, out, "--out", allow=manifest.resolve(PREVIEW_DIR))
    in_run = is_within(str(out), str(manifest.run_root))
    lock = C.run_lock(manifest.run_root, VERB_PREVIEW) if in_run else contextlib.nullcontext()
    staged = StagedFolder(out, PREVIEW_DIR, "--out")
    try:
        with lock, staged:
            _write_previews_into(manifest, staged, movies)
            written = staged.commit()
    except DISK_ERRORS as exc:
        path = getattr(exc, "path", None) or getattr(exc, "filename", None)
        where = staged.out if path is None or staged.names_output(path) else Path(path)
        full = as_disk_full(exc, where, staged.discarded_bytes or None)
        if full is None:
            raise
        raise full from None
    return written  # the caller says them (the preview verb: once, on stdout)


def _write_previews_into(manifest: Manifest, staged: StagedFolder, movies: bool) -> None:
    """The atlas sheet, the checkerboard and propagation movies and the frame sheet, into the staging folder."""
    write_png_u8(staged.path("atlases.png"), atlas_sheet(manifest))
    checker = checker_edits(manifest)
    first = manifest.frames[0]
    stripes = project_to_textures(manifest, manifest.read_passes(first), stripes_frame_edit(manifest.resolution))

    picks = set(_sheet_frames(manifest.frames))
    rows: dict[str, list[np.ndarray]] = {"original": [], "checkerboard": [], "propagation": []}
    for name, edits in (("checkerboard", checker), ("propagation", stripes)):
        writer = movie_writer(manifest, staged.path(f"{name}.mp4"), PREVIEW_FPS) if movies else None
        try:
            for number, frame in render_frames(manifest, edits):
                u8 = to_display_u8(frame)
                if writer is not None:
                    writer.write(u8)
                if number in picks:
                    rows[name].append(label(tile(u8), f"{name} {number}"))
            if writer is not None:
                writer.close()
        except BaseException:
            if writer is not None:
                writer.abort()
            raise
    for number, plate in plate_frames(manifest, sorted(picks)):
        rows["original"].append(label(tile(to_display_u8(plate)), f"original {number}"))
    write_png_u8(staged.path("frames.png"), grid([rows["original"], rows["checkerboard"], rows["propagation"]]))


__all__ = [
    "atlas_sheet",
    "checker_edit",
    "checker_edits",
    "grid",
    "label",
    "stripes_frame_edit",
    "tile",
    "write_png_u8",
    "write_previews",
]
