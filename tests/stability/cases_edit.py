"""Bad input to the verbs that write from an export: render, preview, project-frame and export. Each is refused in
one line, exit 2, before anything is written: the watched folder (the plate, a mask folder, the run folder, or
where a refused output would have gone) stays byte-identical or is not created.

The exports are hand-made (``tests.engine.fake_export``: plate, passes, edit layers and manifest, no fit), with
paths relative to the manifest as ``export`` writes them.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from engine import contract as C
from engine.io.images import write_exr, write_png
from engine.terms.cli import VERB_PREVIEW, VERB_RENDER
from engine.terms.export_names import EDITS_DIR, PASSES_DIR, pass_file_name
from tests.engine.fake_export import make_fake_export
from tests.media_files import write_movie
from tests.stability.bad_inputs import Case

W, H, FRAMES = 32, 24, 3


def _identity(t: int, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return xs / W, 1.0 - ys / H, np.ones(xs.shape)


def _plate() -> np.ndarray:
    return np.random.default_rng(0).uniform(0.1, 0.9, (FRAMES, H, W, 3)).astype(np.float32)


def _export(d: Path) -> Path:
    """A one-layer export in ``d`` (``d/clip`` the plate, ``d/run`` the run folder); its manifest, paths relative."""
    manifest = make_fake_export(d, _plate(), [(_identity, (W, H))])
    return _edit_manifest(manifest, _relative_paths)


def _edit_manifest(manifest: Path, change: Callable[[dict[str, Any], Path], None]) -> Path:
    data = json.loads(manifest.read_text())
    change(data, manifest.parent)
    manifest.write_text(json.dumps(data))
    return manifest


def _relative_paths(data: dict[str, Any], folder: Path) -> None:
    clip = data["clip"]
    clip["source"] = os.path.relpath(clip["source"], folder)
    clip["frame_files"] = [os.path.relpath(f, folder) for f in clip["frame_files"]]


def _plate_named_like_the_render(d: Path) -> Path:
    """An export whose plate is a linear EXR sequence named exactly like render's output (edit.00000.exr ...)."""
    manifest = _export(d)
    plate = d / "plate"
    for t, rgb in enumerate(_plate()):
        write_exr(plate / f"edit.{t:05d}.exr", {c: rgb[..., i] for i, c in enumerate("RGB")})

    def point_at_it(data: dict[str, Any], folder: Path) -> None:
        data["clip"].update(source=os.path.relpath(plate, folder), colorspace="linear")
        data["clip"]["frame_files"] = [os.path.relpath(plate / f"edit.{t:05d}.exr", folder) for t in range(FRAMES)]

    return _edit_manifest(manifest, point_at_it)


def _movie_plate(d: Path) -> Path:
    """An export whose plate is a movie, ``d/footage/plate.mp4``."""
    manifest = _export(d)
    movie = d / "footage" / "plate.mp4"
    movie.parent.mkdir()
    write_movie(movie, [np.full((H, W, 3), 100, np.uint8)] * FRAMES)

    def point_at_it(data: dict[str, Any], folder: Path) -> None:
        data["clip"].update(source=os.path.relpath(movie, folder), kind="movie", frame_files=[])

    return _edit_manifest(manifest, point_at_it)


def _with_masks(d: Path) -> Path:
    manifest = _export(d)
    (d / "masks").mkdir()
    for t in range(FRAMES):
        write_png(d / "masks" / f"{t:05d}.png", np.ones((H, W, 1), np.float32), 8)
    return _edit_manifest(
        manifest, lambda data, folder: data["clip"].update(masks=[os.path.relpath(d / "masks", folder)])
    )


def _render(
    out: Callable[[Path], Path], build: Callable[[Path], Path] = _export, *extra: str
) -> Callable[[Path], list[str]]:
    def argv(d: Path) -> list[str]:
        manifest = build(d)
        return [str(manifest), "--out", str(out(d)), "--no-bar", *extra]

    return argv


def _render_movie(
    movie: Callable[[Path], Path], build: Callable[[Path], Path] = _export
) -> Callable[[Path], list[str]]:
    def argv(d: Path) -> list[str]:
        manifest = build(d)
        return [str(manifest), "--out", str(d / "edited"), "--movie", str(movie(d)), "--no-bar"]

    return argv


def _missing_pass(d: Path) -> list[str]:
    manifest = _export(d)
    (manifest.parent / PASSES_DIR / pass_file_name(1)).unlink()
    return [str(manifest), "--out", str(d / "edited"), "--no-bar"]


def _plate_gone(d: Path) -> list[str]:
    """The plate was moved away after the export (the manifest's relative path finds nothing)."""
    manifest = _export(d)
    (d / "clip").rename(d / "clip_moved")
    return [str(manifest), "--out", str(d / "edited"), "--no-bar"]


def _manifest_changed(
    change: Callable[[dict[str, Any]], None], verb_args: Callable[[Path, Path], list[str]] | None = None
) -> Callable[[Path], list[str]]:
    def argv(d: Path) -> list[str]:
        manifest = _edit_manifest(_export(d), lambda data, folder: change(data))
        if verb_args is not None:
            return verb_args(d, manifest)
        return [str(manifest), "--out", str(d / "edited"), "--no-bar"]

    return argv


def _paint(d: Path) -> Path:
    paint = np.zeros((H, W, 4), np.float32)
    paint[4:12, 4:12] = (1.0, 0.0, 0.0, 1.0)
    return write_png(d / "paint.png", paint, 8)


def _project(*extra: str, change: Callable[[dict[str, Any], Path], None] | None = None) -> Callable[[Path], list[str]]:
    def argv(d: Path) -> list[str]:
        manifest = _export(d)
        if change is not None:
            _edit_manifest(manifest, lambda data, folder: change(data, d))
        return [str(manifest), "--frame", "1", "--edit", str(_paint(d)), *extra]

    return argv


def _set_edit_layer(path: Callable[[Path], str]) -> Callable[[dict[str, Any], Path], None]:
    def change(data: dict[str, Any], d: Path) -> None:
        data["layers"][0]["edit_layer"] = path(d)

    return change


def _history_linked_out(d: Path) -> list[str]:
    """The run's ``edits/history`` is a link to a folder outside the run folder."""
    argv = _project()(d)
    (d / "elsewhere").mkdir()
    (d / "run" / EDITS_DIR / "history").symlink_to(d / "elsewhere", target_is_directory=True)
    return argv


def _preview(out: Callable[[Path], Path], build: Callable[[Path], Path] = _export) -> Callable[[Path], list[str]]:
    def argv(d: Path) -> list[str]:
        manifest = build(d)
        return [str(manifest), "--out", str(out(d)), "--no-movies"]

    return argv


def _a_file(d: Path) -> Path:
    (d / "a_file").write_text("not a folder")
    return d / "a_file"


def _everything(d: Path) -> Path:
    """The case's whole folder: plate, run folder and where the refused output would have gone."""
    return d


def _clip(d: Path) -> Path:
    return d / "clip"


def _run(d: Path) -> Path:
    return d / "run"


def _plate_folder(d: Path) -> Path:
    return d / "plate"


def _elsewhere(d: Path) -> Path:
    return d / "elsewhere"


CASES: tuple[Case, ...] = (
    Case("render_out_is_the_plate_folder", "render --out the plate's folder (frames named edit.00000.exr ...)",
         _render(_plate_folder, _plate_named_like_the_render),
         ("plate", "folder of the plate's frames", "another --out"), verb=VERB_RENDER, watch=_plate_folder),
    Case("render_out_is_the_run_folder", "render --out RUN_DIR", _render(_run), ("run", "inside the run folder"),
         verb=VERB_RENDER, watch=_run),
    Case("render_out_inside_an_export", "render --out RUN_DIR/exports/v001/passes",
         _render(lambda d: d / "run" / C.EXPORTS_DIR / "v001" / PASSES_DIR), ("passes", "inside the run folder"),
         verb=VERB_RENDER, watch=_run),
    Case("render_out_is_a_mask_folder", "render --out one of the fit's mask folders", _render(lambda d: d / "masks",
         _with_masks), ("masks", "mask folder"), verb=VERB_RENDER, watch=lambda d: d / "masks"),
    Case("render_out_is_a_file", "render --out a regular file", _render(_a_file), ("a_file", "is a file"),
         verb=VERB_RENDER, watch=_everything),
    Case("render_movie_is_the_plate_movie", "render --movie the plate movie", _render_movie(lambda d: d / "footage" /
         "plate.mp4", _movie_plate), ("plate.mp4", "is the plate movie"), verb=VERB_RENDER,
         watch=lambda d: d / "footage"),
    Case("render_movie_in_the_plate_folder", "render --movie a file among the plate's frames",
         _render_movie(lambda d: d / "clip" / "edited.mp4"), ("clip", "folder of the plate's frames"),
         verb=VERB_RENDER, watch=_clip),
    Case("render_movie_not_writable", "render --movie below a regular file",
         _render_movie(lambda d: _a_file(d) / "edited.mp4"), ("edited.mp4", "cannot write the movie here"),
         verb=VERB_RENDER, watch=lambda d: d / "edited"),
    Case("render_missing_pass_file", "a pass file of the export is gone", _missing_pass,
         ("atlas.00001.exr", "does not exist", "export the run again"), verb=VERB_RENDER, watch=_everything),
    Case("render_plate_moved_away", "the plate is no longer where the manifest says", _plate_gone,
         ("clip", "plate folder does not exist", "put the plate back"), verb=VERB_RENDER, watch=_everything),
    Case("render_manifest_frames_not_ints", "manifest passes.frames are strings",
         _manifest_changed(lambda m: m["passes"].update(frames=["0", "1"])), ("'frames'", "int list"),
         verb=VERB_RENDER, watch=_everything),
    Case("render_manifest_unknown_frames", "manifest passes.frames names frames the clip does not have",
         _manifest_changed(lambda m: m["passes"].update(frames=[0, 1, 7])), ("[7]", "not distinct frames of the clip"),
         verb=VERB_RENDER, watch=_everything),
    Case("render_manifest_bad_resolution", "manifest clip.resolution is not two positive ints",
         _manifest_changed(lambda m: m["clip"].update(resolution=[W, -H])), ("resolution", "two sides"),
         verb=VERB_RENDER, watch=_everything),
    Case("render_manifest_duplicate_layer_names", "two layers with one name",
         _manifest_changed(lambda m: m["layers"].append({**m["layers"][0], "index": 1, "role": "foreground"})),
         ("layer names", "not unique"), verb=VERB_RENDER, watch=_everything),
    Case("project_frame_unknown_layer", "project-frame --layer Nope", _project("--layer", "Nope"),
         ("no layer called 'Nope'", "Background"), verb=C.VERB_PROJECT_FRAME, watch=_run),
    Case("project_frame_absolute_edit_path", "a manifest whose edit layer is an absolute path outside the run",
         _project(change=_set_edit_layer(lambda d: str(d / "elsewhere" / "evil.png"))),
         ("evil.png", "is absolute and outside the run folder"), verb=C.VERB_PROJECT_FRAME, watch=_elsewhere),
    Case("project_frame_edit_path_leaves_the_run", "a manifest whose edit layer climbs out of the run folder",
         _project(change=_set_edit_layer(lambda d: "../../../elsewhere/evil.png")),
         ("evil.png", "leaves the run folder"), verb=C.VERB_PROJECT_FRAME, watch=_elsewhere),
    Case("project_frame_edit_path_onto_the_checkpoint", "a manifest whose edit layer is the run's checkpoint",
         _project(change=_set_edit_layer(lambda d: f"../../{C.RUN_CHECKPOINT}")), (C.RUN_CHECKPOINT, "leaves"),
         verb=C.VERB_PROJECT_FRAME, watch=_run),
    Case("project_frame_history_linked_out", "edits/history is a link out of the run folder", _history_linked_out,
         ("history", "leaves the run folder"), verb=C.VERB_PROJECT_FRAME, watch=_elsewhere),
    Case("preview_out_is_a_file", "preview --out a regular file", _preview(_a_file), ("a_file", "is a file"),
         verb=VERB_PREVIEW, watch=_everything),
    Case("preview_out_is_the_plate_folder", "preview --out the plate's folder", _preview(_clip),
         ("clip", "folder of the plate's frames"), verb=VERB_PREVIEW, watch=_clip),
    Case("preview_out_inside_the_run", "preview --out RUN_DIR/edits", _preview(lambda d: d / "run" / EDITS_DIR),
         ("edits", "inside the run folder"), verb=VERB_PREVIEW, watch=_run),
    Case("export_atlas_size_out_of_range", "export --atlas-size 3", lambda d: [str(d / "run"), "--atlas-size", "3"],
         ("--atlas-size 3", "8..16384"), verb=C.VERB_EXPORT, watch=_run),
)  # fmt: skip
