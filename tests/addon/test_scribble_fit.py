"""Fit Atlas with "Split with Scribbles" (paper Sec. 4.4) inside Blender, with the fake engine: the clip's
annotation strokes are rasterized into the run's scribble folder (exact pixels), the fit gets exactly one
--mask and --scribbles, the refusals are clear and start no engine, and the three-layer import shows every
layer.

Real strokes: the Annotate operator, run in a Movie Clip Editor area with a ``stroke`` list, draws a real
stroke (right point count, on the scene's current frame) on 4.5 and 5.0; headless its points are NaN (the
editor's stabilisation matrix is only computed when it draws), so the test then writes each point's ``co``
(writable on both). The other tests use a stand-in annotation shaped like the RNA (patched
``scribbles.clip_annotation``), which is quicker to vary.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from types import SimpleNamespace as NS

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from fake_export import FRAMES, H, W, decode_png, make_export, write_png  # noqa: E402
from helpers import RecordingLayout, fake_python  # noqa: E402
from neural_atlas.addon import compat, scribbles  # noqa: E402
from neural_atlas.addon.core import running  # noqa: E402
from neural_atlas.addon.core import scribble_math as S  # noqa: E402

from engine import contract as C  # noqa: E402
from engine.terms.run_folder import FIT_AUTO_PARTS_FLAG  # noqa: E402

RED, GREEN, WHITE = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (1.0, 1.0, 1.0)


def _layer(colour, thickness, strokes_by_frame, hide=False):
    frames = [
        NS(frame_number=f, strokes=[NS(points=[NS(co=p) for p in s]) for s in strokes])
        for f, strokes in strokes_by_frame.items()
    ]
    return NS(color=colour, thickness=thickness, annotation_hide=hide, frames=frames)


@pytest.fixture
def plain_scene(blender, tmp_path, monkeypatch):
    """The fake export's plate (files 00003..00005 = scene frames 1..3), one mask folder, the fake engine."""
    make_export(tmp_path / "src")
    clip = bpy.data.movieclips.load(str(tmp_path / "src" / "plate" / f"{FRAMES[0]:05d}.png"))
    mask_dir = tmp_path / "object_masks"
    for f in FRAMES:
        write_png(mask_dir / f"{f:05d}.png", np.full((H, W, 4), 255, np.uint8))
    monkeypatch.setenv("NEURAL_ATLAS_ENGINE_PYTHON", fake_python(tmp_path))
    props = blender.context.scene.neural_atlas
    props.clip = clip
    layer = props.layers.add()
    layer.source = "FOLDER"
    layer.folder = str(mask_dir)
    props.run_dir = str(tmp_path / "run")
    props.use_scribbles = True
    return props


@pytest.fixture
def scribble_scene(plain_scene, monkeypatch):
    """``plain_scene`` whose clip's annotation is a stand-in (set its ``layers``)."""
    props = plain_scene
    clip = props.clip
    annotation = NS(layers=[])
    monkeypatch.setattr(scribbles, "clip_annotation", lambda c: annotation if c == clip else None)
    return props, annotation


def _expected(points, radius, width=W, height=H) -> np.ndarray:
    """Pixel centres within ``radius`` of the polyline (frame-normalised points), rows top-first: the oracle."""
    px = np.array([(x * width, y * height) for x, y in points], np.float64)
    yy, xx = np.mgrid[0:height, 0:width]
    cx, cy = xx + 0.5, (height - 1 - yy) + 0.5  # row 0 is the top; pixel rows count bottom-up in the clip
    best = np.full((height, width), np.inf)
    for a, b in itertools.pairwise(px):
        d = b - a
        s = np.clip(((cx - a[0]) * d[0] + (cy - a[1]) * d[1]) / max(float(d @ d), 1e-12), 0.0, 1.0)
        best = np.minimum(best, np.hypot(cx - a[0] - s * d[0], cy - a[1] - s * d[1]))
    return best <= radius


def _labels(path: Path) -> np.ndarray:
    px = decode_png(path.read_bytes())
    assert px.shape == (H, W, 3)
    colours = {(0, 0, 0): -1, **{tuple(c): k for k, c in enumerate(C.SCRIBBLE_COLOURS)}}
    return np.array([[colours[tuple(p)] for p in row] for row in px])


def test_scribble_fit_rasterizes_passes_the_folder_and_imports_three_layers(scribble_scene, tmp_path):
    props, annotation = scribble_scene
    red_stroke = [(0.1, 0.5), (0.45, 0.5)]
    green_stroke = [(0.6, 0.2), (0.9, 0.8)]
    annotation.layers = [
        _layer(RED, 4, {1: [red_stroke]}),  # scene frame 1 = plate file 00003
        _layer(GREEN, 6, {1: [green_stroke], 3: [green_stroke], 40: [green_stroke]}),  # 40: outside the clip
        _layer(WHITE, 3, {2: [red_stroke]}),  # a note in another colour: no scribble
    ]
    folder = tmp_path / "run.scribbles"
    folder.mkdir()
    (folder / "00004.png").write_bytes(b"stale")  # a previous fit's scribble whose strokes were since erased

    assert bpy.ops.neural_atlas.fit("EXEC_DEFAULT") == {"FINISHED"}, props.status
    argv = Path(props.log_path).read_text().splitlines()[0].split(" ")
    assert argv.count("--mask") == 1 and argv[argv.index("--mask") + 1] == str(tmp_path / "object_masks")
    assert argv[argv.index(C.SCRIBBLE_ARG) + 1] == str(folder)
    assert argv[argv.index("--frames") + 1] == "3:5"  # the plate's frame numbers (00003.png ...)

    # one file per scribbled frame of the fitted range, named like the plate's files; the stale one is gone
    assert sorted(p.name for p in folder.iterdir()) == ["00003.png", "00005.png"]
    first = _labels(folder / "00003.png")
    red = _expected(red_stroke, 2.0)  # radius = thickness / 2
    green = _expected(green_stroke, 3.0)
    assert np.array_equal(first == 1, green)  # green is drawn after red, so it wins where they cross
    assert np.array_equal(first == 0, red & ~green)
    assert np.array_equal(first == -1, ~(red | green))
    assert red.sum() > 20 and green.sum() > 20
    last = _labels(folder / "00005.png")
    assert np.array_equal(last == 1, green) and not (last == 0).any()

    # the fake engine exports Background + Foreground1 + Foreground2 for a scribble fit: all three imported
    assert props.imported_layers == "Background, Foreground1, Foreground2"
    assert props.status.startswith("done: 3 layers")
    tree = compat.scene_tree(bpy.context.scene, create=False)
    assert {"NA_MapUV_Background", "NA_MapUV_Foreground1", "NA_MapUV_Foreground2", "NA_Over"} <= set(tree.nodes.keys())
    assert {"NA_Edit_Foreground1", "NA_Edit_Foreground2"} <= set(bpy.data.images.keys())


@pytest.mark.parametrize(
    ("case", "match"),
    [
        ("two_layers", "splits one object: keep exactly one foreground layer .* not 2"),
        ("nothing", "has no annotation strokes in the scribble colours on frames 1-3: .* part 1 in red"),
        ("outside", "has no annotation strokes in the scribble colours on frames 1-3"),
        ("only_red", "only red strokes, so nothing is split: scribble the other part in green"),
        ("hidden_green", "only red strokes"),
    ],
)
def test_scribble_fit_refusals_are_clear_and_start_no_engine(scribble_scene, case, match):
    props, annotation = scribble_scene
    stroke = [(0.2, 0.2), (0.3, 0.3)]
    layers = {
        "two_layers": [_layer(RED, 2, {1: [stroke]}), _layer(GREEN, 2, {2: [stroke]})],
        "nothing": [_layer(WHITE, 2, {1: [stroke]})],
        "outside": [_layer(RED, 2, {9: [stroke]}), _layer(GREEN, 2, {9: [stroke]})],
        "only_red": [_layer(RED, 2, {1: [stroke], 2: [stroke]})],
        "hidden_green": [_layer(RED, 2, {1: [stroke]}), _layer(GREEN, 2, {2: [stroke]}, hide=True)],
    }[case]
    annotation.layers = layers
    if case == "two_layers":
        props.layers.add().source = "FOLDER"
    with pytest.raises(RuntimeError, match=match):
        bpy.ops.neural_atlas.fit("EXEC_DEFAULT")
    assert match.split(" ")[0] in props.status
    assert not Path(props.run_dir + ".blender.log").exists()  # refused before any engine started
    assert not props.running and running.jobs() == {}


def test_scribbles_off_or_estimate_pass_no_scribbles(scribble_scene):
    props, annotation = scribble_scene
    annotation.layers = [_layer(RED, 2, {1: [[(0.2, 0.2)]]}), _layer(GREEN, 2, {1: [[(0.7, 0.7)]]})]
    assert bpy.ops.neural_atlas.estimate("EXEC_DEFAULT") == {"FINISHED"}  # the estimate verb takes no scribbles
    assert C.SCRIBBLE_ARG not in Path(props.run_dir + ".estimate.log").read_text().splitlines()[0]
    props.use_scribbles = False
    assert bpy.ops.neural_atlas.fit("EXEC_DEFAULT") == {"FINISHED"}
    assert C.SCRIBBLE_ARG not in Path(props.log_path).read_text().splitlines()[0]
    assert props.imported_layers == "Background, Foreground"


def _panel(context) -> list[tuple[str, tuple, dict]]:
    from neural_atlas.addon import ui

    return RecordingLayout().draw(ui.NEURALATLAS_PT_fit, context)


def _panel_labels(context) -> list[tuple[str, str]]:
    return [(kw.get("text", ""), kw.get("icon", "")) for name, _, kw in _panel(context) if name == "label"]


def test_panel_says_which_colour_marks_which_part(scribble_scene):
    props, annotation = scribble_scene
    labels = _panel_labels(bpy.context)
    assert ("Red: part 1 (Foreground1)", "COLORSET_01_VEC") in labels
    assert ("Green: part 2 (Foreground2)", "COLORSET_03_VEC") in labels
    assert ("Blue: part 3 (Foreground3)", "COLORSET_04_VEC") in labels
    assert ("No strokes in these colours yet", "INFO") in labels
    ops = [a[0] for name, a, _ in _panel(bpy.context) if name == "operator"]
    assert "neural_atlas.find_masks" in ops
    annotation.layers = [_layer(RED, 2, {1: [[(0.2, 0.2)]]}), _layer(GREEN, 2, {3: [[(0.7, 0.7)]]})]
    assert ("red, green on frame(s) 1, 3", "CHECKMARK") in _panel_labels(bpy.context)
    props.layers.add()
    assert ("Keep exactly one foreground layer: the whole object", "ERROR") in _panel_labels(bpy.context)


def _draw_real_stroke(clip, layer_name: str, frame: int, points: list[tuple[float, float]]) -> None:
    """A real annotation stroke on ``layer_name`` at scene ``frame`` (the Annotate operator in a clip editor),
    then its points placed at ``points`` (frame-normalised; the operator leaves NaN headless)."""
    scene = bpy.context.scene
    scene.frame_set(frame)
    window = bpy.context.window_manager.windows[0]
    area = window.screen.areas[0]
    area.type = "CLIP_EDITOR"
    space = area.spaces.active
    space.clip = clip
    region = next(r for r in area.regions if r.type == "WINDOW")
    scribbles.clip_annotation(clip).layers.active_note = layer_name
    stroke = [
        {"name": "", "location": (0, 0, 0), "mouse": (10.0 + 10 * i, 10.0), "mouse_event": (0, 0), "is_start": i == 0}
        | {"pressure": 1.0, "size": 1.0, "time": float(i), "x_tilt": 0.0, "y_tilt": 0.0}
        for i in range(len(points))
    ]
    with bpy.context.temp_override(window=window, area=area, region=region, space_data=space):
        assert bpy.ops.gpencil.annotate(mode="DRAW", wait_for_input=False, stroke=stroke) == {"FINISHED"}
    layer = next(lyr for lyr in scribbles.clip_annotation(clip).layers if lyr.info == layer_name)
    gp_frame = next(f for f in layer.frames if f.frame_number == frame)
    real = gp_frame.strokes[len(gp_frame.strokes) - 1]
    assert len(real.points) == len(points)
    for p, (x, y) in zip(real.points, points, strict=True):
        p.co = (x, y, 0.0)


def test_real_annotation_strokes_from_the_scribble_layers(plain_scene, tmp_path):
    props = plain_scene
    clip = props.clip
    assert bpy.ops.neural_atlas.scribble_layers("EXEC_DEFAULT", parts=2) == {"FINISHED"}
    annotation = scribbles.clip_annotation(clip)
    assert [(lyr.info, S.layer_label(tuple(lyr.color)), lyr.thickness) for lyr in annotation.layers] == [
        ("Part 1 (red)", 0, scribbles.SCRIBBLE_THICKNESS),
        ("Part 2 (green)", 1, scribbles.SCRIBBLE_THICKNESS),
    ]
    assert annotation.layers.active_note == "Part 1 (red)"
    assert bpy.ops.neural_atlas.scribble_layers("EXEC_DEFAULT", parts=3) == {"FINISHED"}  # adds blue, keeps both
    assert sorted(lyr.info for lyr in annotation.layers) == ["Part 1 (red)", "Part 2 (green)", "Part 3 (blue)"]
    annotation.layers.remove(next(lyr for lyr in annotation.layers if lyr.info == "Part 3 (blue)"))

    red_stroke = [(0.1, 0.3), (0.3, 0.4), (0.45, 0.4)]
    green_stroke = [(0.55, 0.7), (0.9, 0.75)]
    _draw_real_stroke(clip, "Part 1 (red)", 2, red_stroke)
    _draw_real_stroke(clip, "Part 2 (green)", 2, green_stroke)
    assert scribbles.scribbled_frames(annotation) == [2]
    assert bpy.ops.neural_atlas.fit("EXEC_DEFAULT") == {"FINISHED"}, props.status
    folder = tmp_path / "run.scribbles"
    assert sorted(p.name for p in folder.iterdir()) == ["00004.png"]  # scene frame 2 = plate file 00004
    labels = _labels(folder / "00004.png")
    radius = scribbles.SCRIBBLE_THICKNESS / 2
    red, green = _expected(red_stroke, radius), _expected(green_stroke, radius)
    assert not (red & green).any()
    assert np.array_equal(labels == 0, red) and np.array_equal(labels == 1, green)
    assert np.array_equal(labels == -1, ~(red | green))
    assert props.imported_layers == "Background, Foreground1, Foreground2"


PARTS_FLAGS = {FIT_AUTO_PARTS_FLAG, C.FIT_NO_AUTO_PARTS_FLAG}


@pytest.mark.parametrize("find_parts", [True, False], ids=["on", "off"])
def test_find_parts_is_on_by_default_and_off_tells_the_engine_not_to_split(plain_scene, find_parts):
    """Find Parts on (the default): the fit gets the one --mask and no flag, so the engine splits the parts that
    move apart (writing their strokes into the run folder) as its default does; off: ``--no-auto-parts``, the
    object fitted as one layer. The estimate gets neither."""
    props = plain_scene
    props.use_scribbles = False
    assert props.find_parts, "Find Parts is on by default"
    props.find_parts = find_parts
    assert bpy.ops.neural_atlas.fit("EXEC_DEFAULT") == {"FINISHED"}, props.status
    argv = Path(props.log_path).read_text().splitlines()[0].split(" ")
    assert argv.count("--mask") == 1 and C.SCRIBBLE_ARG not in argv
    assert [a for a in argv if a in PARTS_FLAGS] == ([] if find_parts else [C.FIT_NO_AUTO_PARTS_FLAG])
    assert bpy.ops.neural_atlas.estimate("EXEC_DEFAULT") == {"FINISHED"}
    assert not PARTS_FLAGS & set(Path(props.run_dir + ".estimate.log").read_text().splitlines()[0].split(" "))


def test_find_parts_on_with_two_layers_fits_them_as_given(plain_scene, tmp_path):
    """Find Parts splits one object: with two foreground layers (its checkbox greyed out) the fit starts as it would
    without it, each layer's --mask and no flag (the engine splits nothing it was given two masks for)."""
    props = plain_scene
    props.use_scribbles = False
    second = props.layers.add()
    second.source = "FOLDER"
    second.folder = str(tmp_path / "second_masks")
    Path(second.folder).mkdir()
    assert props.find_parts
    assert bpy.ops.neural_atlas.fit("EXEC_DEFAULT") == {"FINISHED"}, props.status
    argv = Path(props.log_path).read_text().splitlines()[0].split(" ")
    assert argv.count("--mask") == 2 and not PARTS_FLAGS & set(argv)
