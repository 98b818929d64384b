"""Find Masks inside Blender with the REAL engine (``python -m engine masks``) on tiny synthetic clips: the
masks it adds as a foreground layer match the scene's true masks; a static clip is reported and changes no
layer; a second search never overwrites the first; engine errors are reported with the log.

The engine runs in its own interpreter: NEURAL_ATLAS_TEST_ENGINE_PYTHON, else the checkout's .venv (as in
test_end_to_end.py). Skipped when that Python has no torch/OpenCV or its engine has no ``masks`` verb.
"""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from cancel_at import cancel_at_step  # noqa: E402
from helpers import drive_modal, engine_python, fake_python  # noqa: E402
from neural_atlas.addon.core import needs, running  # noqa: E402
from neural_atlas.addon.ops import fit as fit_ops  # noqa: E402

from engine import contract as C  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
TAG = f"[bpy {bpy.app.version_string}]"
#: The IoU the found masks must reach against the scene's true masks (the test prints what they reach).
MIN_IOU = 0.93


def _engine_python() -> str:
    return engine_python("masks", "cv2")


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    """A moving sprite over a panning plate (frames/ + true masks/), and a static clip (frame 0 four times)."""
    py = _engine_python()
    root = tmp_path_factory.mktemp("masks_clips")
    script = (
        "import sys, shutil; from pathlib import Path; "
        "from engine.data.synthetic import SceneSpec, make_scene, write_scene\n"
        "d = Path(sys.argv[1]); write_scene(make_scene(SceneSpec(width=96, height=64, frames=6)), d / 'moving')\n"
        "s = d / 'static' / 'frames'; s.mkdir(parents=True)\n"
        "for t in range(4): shutil.copy(d / 'moving' / 'frames' / '00000.png', s / f'{t:05d}.png')"
    )
    subprocess.run([py, "-c", script, str(root)], cwd=ROOT, check=True, timeout=120)
    return py, root


@pytest.fixture
def masks_scene(blender, clips, tmp_path, monkeypatch):
    py, root = clips
    monkeypatch.setenv("NEURAL_ATLAS_ENGINE_PYTHON", py)
    props = blender.context.scene.neural_atlas
    props.run_dir = str(tmp_path / "run")
    return props, root


def _read_mask(path: Path) -> np.ndarray:
    img = bpy.data.images.load(str(path))
    img.colorspace_settings.name = "Non-Color"
    w, h = img.size
    px = np.zeros(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(h, w, 4)[::-1, :, 0] > C.MASK_THRESHOLD  # rows top-first, like the file


def test_find_masks_adds_a_layer_that_matches_the_true_masks(masks_scene, tmp_path):
    props, root = masks_scene
    props.clip = bpy.data.movieclips.load(str(root / "moving" / "frames" / "00000.png"))
    assert bpy.ops.neural_atlas.find_masks("EXEC_DEFAULT") == {"FINISHED"}, props.status
    assert len(props.layers) == 1 and props.layer_index == 0
    layer = props.layers[0]
    out = tmp_path / "run" / C.AUTO_MASKS_DIR
    assert layer.source == "FOLDER" and layer.folder == str(out)
    assert props.status.startswith("Find Masks: foreground in 6/6 frames")
    check = bpy.data.movieclips[fit_ops.AUTO_MASKS_CLIP]  # to scrub through in the clip editor
    assert check.source == "SEQUENCE" and check.frame_duration == 6 and tuple(check.size) == (96, 64)
    assert check.filepath == str(out / "00000.png") and props.clip.name == "00000.png"
    argv = Path(props.log_path).read_text().splitlines()[0].split(" ")
    assert argv[argv.index(C.VERB_MASKS) + 1] == str(root / "moving" / "frames" / "#####.png")  # the clip's pattern
    assert argv[argv.index("--frames") + 1] == "0:5"
    names = sorted(os.listdir(out))
    assert names == [f"{t:05d}.png" for t in range(6)]  # named like the frames: the fit matches them by number
    ious = []
    for name in names:
        auto, truth = _read_mask(out / name), _read_mask(root / "moving" / "masks" / name)
        assert auto.shape == truth.shape == (64, 96)
        ious.append((auto & truth).sum() / max(int((auto | truth).sum()), 1))
    print(f"{TAG} Find Masks IoU vs the scene's masks: mean {np.mean(ious):.3f}, min {min(ious):.3f}")
    assert min(ious) >= MIN_IOU, ious

    # a second search never overwrites the first (an artist may have fixed it): a numbered sibling, a second layer
    first = {n: (out / n).read_bytes() for n in names}
    assert bpy.ops.neural_atlas.find_masks("EXEC_DEFAULT") == {"FINISHED"}
    assert [lyr.folder for lyr in props.layers] == [str(out), str(out) + "_2"]
    assert {n: (out / n).read_bytes() for n in names} == first


def test_find_masks_on_a_static_clip_reports_and_keeps_the_layers(masks_scene, tmp_path):
    props, root = masks_scene
    props.clip = bpy.data.movieclips.load(str(root / "static" / "frames" / "00000.png"))
    kept = props.layers.add()
    kept.source = "FOLDER"
    kept.folder = "/somewhere/hand_made_masks"
    assert bpy.ops.neural_atlas.find_masks("EXEC_DEFAULT") == {"CANCELLED"}
    assert props.status.startswith("Find Masks: no foreground found (static camera)")
    assert props.status.endswith("The layers are unchanged")
    assert [lyr.folder for lyr in props.layers] == ["/somewhere/hand_made_masks"]
    assert not (tmp_path / "run" / C.AUTO_MASKS_DIR).exists()  # its empty masks are not left behind
    assert fit_ops.AUTO_MASKS_CLIP not in bpy.data.movieclips
    assert "no foreground found" in Path(props.log_path).read_text()
    assert not props.running and running.jobs() == {}


def test_find_masks_errors_name_the_fix_and_the_log(masks_scene, tmp_path, monkeypatch):
    props, root = masks_scene
    with pytest.raises(RuntimeError, match=re.escape(needs.NO_MASKS_CLIP)):  # greyed out: the poll's line
        bpy.ops.neural_atlas.find_masks("EXEC_DEFAULT")
    props.clip = bpy.data.movieclips.load(str(root / "moving" / "frames" / "00000.png"))
    props.use_clip_range = False
    props.frame_start = props.frame_end = 2
    with pytest.raises(RuntimeError, match="needs at least two frames"):
        bpy.ops.neural_atlas.find_masks("EXEC_DEFAULT")
    props.use_clip_range = True
    monkeypatch.setenv("NEURAL_ATLAS_ENGINE_PYTHON", fake_python(tmp_path))
    monkeypatch.setenv("FAKE_ENGINE_MODE", "bad_input")
    with pytest.raises(
        RuntimeError, match=r"Find Masks bad_input: .*mask folder does not exist .*\(log: .*run\.masks\.log\)"
    ):
        bpy.ops.neural_atlas.find_masks("EXEC_DEFAULT")
    monkeypatch.setenv("FAKE_ENGINE_MODE", "hang")
    with monkeypatch.context() as m:
        pressed = cancel_at_step(m, 1)  # Cancel once the engine is under way: its first progress line
        assert bpy.ops.neural_atlas.find_masks("EXEC_DEFAULT") == {"CANCELLED"}
    assert len(pressed) == 1, pressed  # pressed once: the job stopped on it
    assert props.status == "Find Masks: cancelled. The layers are unchanged"
    assert len(props.layers) == 0 and running.jobs() == {}
    assert props.log_path == str(tmp_path / "run") + ".masks.log"
    assert "cancel requested: SIGTERM" in Path(props.log_path).read_text()


def test_find_masks_modal_path_with_timer_events(masks_scene, tmp_path):
    """The UI path without an event loop: the modal operator polled by hand-made TIMER events (none fire
    headless), then the layer is added as on the blocking path."""
    props, root = masks_scene
    props.clip = bpy.data.movieclips.load(str(root / "moving" / "frames" / "00000.png"))
    polls = []

    def events(_tick, _job):
        polls.append((bpy.ops.neural_atlas.find_masks.poll(), bpy.ops.neural_atlas.fit.poll(), props.running))
        return "TIMER"

    ret, op, _ = drive_modal(fit_ops.NEURALATLAS_OT_find_masks, bpy.context, events)
    assert polls[0] == (False, False, True)  # one at a time
    assert ret == {"FINISHED"}, op.reports
    assert op.reports[-1][0] == {"INFO"} and "foreground layer 1" in op.reports[-1][1]
    assert [lyr.folder for lyr in props.layers] == [str(tmp_path / "run" / C.AUTO_MASKS_DIR)]
    assert not props.running and running.jobs() == {} and bpy.ops.neural_atlas.find_masks.poll()
