"""Plate frame numbers and timing end to end, on a tiny fit: an EXR plate ``plate.1001.exr`` ... at 24000/1001 with
2:1 pixels and timecode, beside a second sequence in its folder, fitted by pattern with ``--frames`` in plate
numbers; the run records them, the passes, the manifest, the rendered frames and the movie carry them."""

from __future__ import annotations

import json
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import OpenImageIO as oiio
import pytest

from engine import contract as C
from engine.data.synthetic import make_scene
from engine.io.images import exr_timing, write_exr
from engine.terms.export_names import PASSES_DIR, pass_file_name
from engine.terms.manifest import MANIFEST_OPTIONAL_FIELDS
from engine.terms.run_folder import RUN_CLIP
from tests.engine.export.tiny_run import SPEC, TINY
from tests.engine_cli import run_cli
from tests.folders import visible_names

FIRST = 1001
RATE = (24000, 1001)


def _spec_of(path: Path) -> oiio.ImageSpec:
    inp = oiio.ImageInput.open(str(path))
    try:
        return inp.spec()
    finally:
        inp.close()


def _timing(path: Path) -> tuple[object, float, str]:
    spec = _spec_of(path)
    return (
        spec.getattribute("FramesPerSecond"),
        spec.getattribute("PixelAspectRatio"),
        spec.get_string_attribute("smpte:TimeCode"),
    )


@pytest.fixture(scope="module")
def plate_run(tmp_path_factory):
    """The plate (frames 1001..1004, a slap comp 1..4 in the same folder), its masks and a tiny fit of 1001-1003."""
    root = tmp_path_factory.mktemp("plate_frames")
    scene = make_scene(SPEC)
    plates, masks = root / "plates", root / "masks"
    for t, frame in enumerate(scene.frames):
        rgb = {c: np.ascontiguousarray(frame[..., i], np.float32) for i, c in enumerate("RGB")}
        write_exr(plates / f"plate.{FIRST + t}.exr", rgb, attributes=exr_timing(RATE, 2.0, "01:00:00:00", t))
        write_exr(plates / f"slap.{t + 1:04d}.exr", rgb)
        write_exr(masks / f"plate_mask.{FIRST + t}.exr", {"Y": scene.masks[t].astype(np.float32)})
    run = root / "run"
    sets = [arg for key, value in TINY.items() for arg in ("--set", f"{key}={value}")]
    code, lines = run_cli("fit", plates / "plate.####.exr", "--mask", masks, "--frames", "1001-1003", "--out", run,
                          "--preset", "draft", *sets, "--device", "cpu", "--no-bar")  # fmt: skip
    assert code == C.EXIT_OK, lines
    return root, plates, masks, run


def test_a_folder_of_two_sequences_is_refused_in_one_line(plate_run, tmp_path):
    _, plates, masks, _ = plate_run
    code, lines = run_cli("fit", plates, "--mask", masks, "--out", tmp_path / "run", "--no-bar")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1
    assert "holds 2 image sequences: plate.####.exr (1001..1004), slap.####.exr (1..4)" in lines[0]
    assert f"pass one of them as a pattern, e.g. {plates}/plate.####.exr" in lines[0]
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize(
    ("frames", "needle"),
    [
        ("0-2", "frame 0 is not in the plate (its frames are 1001..1004)"),
        ("1003-1005", "frame 1005 is not in the plate (its frames are 1001..1004)"),
    ],
)
def test_frames_outside_the_plate_are_one_line_naming_its_range(plate_run, tmp_path, frames, needle):
    _, plates, masks, _ = plate_run
    code, lines = run_cli("fit", plates / "plate.####.exr", "--mask", masks, "--frames", frames,
                          "--out", tmp_path / "run", "--no-bar")  # fmt: skip
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1 and needle in lines[0], lines
    assert "choose --frames FIRST-LAST with plate frame numbers within 1001..1004" in lines[0]


def test_the_run_records_positions_plate_numbers_and_timing(plate_run):
    _, plates, _, run = plate_run
    record = json.loads((run / RUN_CLIP).read_text())
    assert record["source"] == str(plates / "plate.####.exr")
    assert record["frame_range"] == [0, 2] and record["frame_numbers"] == [1001, 1002, 1003]
    assert record["frame_files"] == [str(plates / f"plate.{n}.exr") for n in (1001, 1002, 1003)]
    assert record["rate"] == [24000, 1001] and record["fps"] == pytest.approx(24000 / 1001, rel=1e-12)
    assert record["pixel_aspect"] == 2.0 and record["timecode"] == "01:00:00:00" and record["start_frame"] == 0


@pytest.fixture(scope="module")
def exported(plate_run):
    _, _, _, run = plate_run
    code, lines = run_cli("export", run, "--atlas-size", "32", "--frames", "1002-1003", "--no-bar")
    assert code == C.EXIT_OK, lines
    return run / C.EXPORTS_DIR / "v001" / C.MANIFEST_NAME


def test_export_frames_outside_the_fit_are_one_line(plate_run):
    code, lines = run_cli("export", plate_run[3], "--frames", "1003-1004", "--no-bar")
    assert code == C.EXIT_BAD_INPUT and len(lines) == 1
    assert "--frames 1003-1004 is outside the fitted frames 1001-1003" in lines[0]


def test_passes_and_manifest_carry_plate_numbers_rate_aspect_and_timecode(exported):
    manifest = C.load_manifest(str(exported))
    clip, passes = manifest["clip"], manifest["passes"]
    assert clip["frame_numbers"] == [1001, 1002, 1003] and passes["frames"] == [1002, 1003]
    assert (clip["first_frame"], clip["last_frame"]) == (1001, 1003)
    assert clip["rate"] == [24000, 1001] and C.clip_rate(clip) == RATE
    assert clip["pixel_aspect"] == 2.0 and clip["timecode"] == "01:00:00:00" and clip["start_frame"] == 0
    # padded as the plate's frames are (slap.1001.exr: four digits)
    assert (passes["pattern"], passes["blender_pattern"]) == ("atlas.{frame:04d}.exr", "atlas.####.exr")
    assert sorted(p.name for p in (exported.parent / PASSES_DIR).iterdir()) == ["atlas.1002.exr", "atlas.1003.exr"]
    for number, timecode in ((1002, "01:00:00:01"), (1003, "01:00:00:02")):
        assert _timing(exported.parent / PASSES_DIR / pass_file_name(number, 4)) == (RATE, 2.0, timecode)


def test_render_frames_and_movie_carry_them_too(exported, tmp_path):
    out, movie = tmp_path / "render", tmp_path / "edited.mov"
    code, lines = run_cli("render", exported, "--out", out, "--movie", movie, "--no-bar")
    assert code == C.EXIT_OK, lines
    assert visible_names(out) == ["edit.1002.exr", "edit.1003.exr"]
    assert _timing(out / "edit.1002.exr") == (RATE, 2.0, "01:00:00:01")
    assert _timing(out / "edit.1003.exr") == (RATE, 2.0, "01:00:00:02")
    with av.open(str(movie)) as container:
        stream = container.streams.video[0]
        assert stream.average_rate == Fraction(24000, 1001) and stream.sample_aspect_ratio == Fraction(2)
        assert stream.metadata["timecode"] == "01:00:00:01"
        stamps = [frame.pts * stream.time_base for frame in container.decode(stream)]
        assert len(stamps) == 2 and stamps[1] - stamps[0] == Fraction(1001, 24000)  # each frame lasts 1001/24000 s


def test_a_manifest_without_timing_still_renders_at_the_default_rate(exported, tmp_path):
    """A manifest written before the plate's timing was kept (no rate, aspect, timecode): read, rendered at
    ``render.DEFAULT_FPS`` with square pixels and no timecode."""
    from engine.edit import render

    data = json.loads(exported.read_text())
    for key in MANIFEST_OPTIONAL_FIELDS["clip"]:
        if key in ("rate", "pixel_aspect", "timecode", "start_frame"):
            data["clip"].pop(key)
    data["clip"]["fps"] = None
    old = exported.parent / "old_manifest.json"
    old.write_text(json.dumps(data))
    try:
        out, movie = tmp_path / "render", tmp_path / "old.mp4"
        render.render_manifest(old, out, movie=movie, progress_bar=False)
        spec = _spec_of(out / "edit.1002.exr")
        assert spec.getattribute("FramesPerSecond") is None and spec.getattribute("smpte:TimeCode") is None
        with av.open(str(movie)) as container:
            stream = container.streams.video[0]
            assert stream.average_rate == Fraction(render.DEFAULT_FPS) and "timecode" not in stream.metadata
    finally:
        old.unlink()


def test_a_movie_numbered_from_its_start_frame_renders_its_own_frames(tmp_path):
    """``fit --start-frame 1001 --frames 1002-1003`` of a movie: the render reads movie frames 1 and 2 (not the
    1002nd) and writes them as edit.01002 and edit.01003 (a movie has no padding of its own: five digits); an empty
    edit gives back those frames of the movie."""
    from tests.media_files import textured_frames, write_movie

    movie = write_movie(tmp_path / "plate.mp4", textured_frames(4, (48, 32)))
    run = tmp_path / "run"
    sets = [arg for key, value in TINY.items() for arg in ("--set", f"{key}={value}")]
    code, lines = run_cli("fit", movie, "--start-frame", "1001", "--frames", "1002-1003", "--out", run,
                          "--preset", "draft", *sets, "--device", "cpu", "--no-bar")  # fmt: skip
    assert code == C.EXIT_OK, lines
    code, lines = run_cli("export", run, "--atlas-size", "32", "--no-bar")
    assert code == C.EXIT_OK, lines
    out = tmp_path / "render"
    (manifest,) = run.glob("exports/*/manifest.json")
    code, lines = run_cli("render", manifest, "--out", out, "--format", "png", "--no-bar")
    assert code == C.EXIT_OK, lines
    assert visible_names(out) == ["edit.01002.png", "edit.01003.png"]
    with av.open(str(movie)) as container:
        decoded = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    for number in (1002, 1003):
        got = oiio.ImageBuf(str(out / f"edit.{number:05d}.png")).get_pixels(oiio.UINT8)
        assert np.abs(got.astype(int) - decoded[number - 1001].astype(int)).max() <= 1
