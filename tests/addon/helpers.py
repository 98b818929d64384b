"""Shared helpers for the add-on tests (none imports bpy): stand-in engines and pip, the real engine's Python,
and stand-ins for what Blender only creates while its UI runs (a panel's layout, an operator instance, the
timer events of a modal operator)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import types
from pathlib import Path
from types import SimpleNamespace
from typing import Any

HERE = Path(__file__).resolve().parent


def fake_python(folder: Path) -> str:
    """An executable that behaves like `python -m engine ...` but runs fake_engine.py."""
    path = folder / "fake_python"
    path.write_text(
        f"#!{sys.executable}\n"
        "import runpy, sys\n"
        "args = sys.argv[1:]\n"
        "if args[:2] == ['-m', 'engine']:\n"
        "    args = args[2:]\n"
        f"sys.argv = [{str(HERE / 'fake_engine.py')!r}, *args]\n"
        f"runpy.run_path({str(HERE / 'fake_engine.py')!r}, run_name='__main__')\n"
    )
    os.chmod(path, 0o755)
    return str(path)


def engine_python(verb: str, needs: str) -> str:
    """The real engine's interpreter for end-to-end tests (NEURAL_ATLAS_TEST_ENGINE_PYTHON, else this
    checkout's .venv); the test is skipped when it cannot import ``needs`` or has no ``verb``."""
    import subprocess

    import pytest

    root = Path(__file__).resolve().parents[2]
    py = os.environ.get("NEURAL_ATLAS_TEST_ENGINE_PYTHON") or str(root / ".venv" / "bin" / "python")
    if not os.path.exists(py):
        pytest.skip(f"no engine Python at {py}")
    probe = subprocess.run(
        [py, "-c", f"import {needs}, engine.cli as c; c.build_parser().parse_args([{verb!r}, '-h'])"],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=120,
    )
    if "usage:" not in probe.stdout:
        pytest.skip(f"engine at {py} cannot run {verb} ({needs}): {probe.stderr.strip()[-200:]}")
    return py


def stand_in_pip(venv, release: Path | None = None) -> None:
    """``venv/bin/python``: prints pip's first line, then fails as pip does offline. With ``release``, it fails
    only once that file exists (the test makes it when it has seen the first line), so the first line is on
    screen until the test has seen it however loaded the machine is; after 300 s it fails anyway."""
    (venv / "bin").mkdir(parents=True)
    pip = venv / "bin" / "python"
    hold = "" if release is None else f"while not os.path.exists({str(release)!r}) and time.monotonic() < end:\n"
    pip.write_text(
        f"#!{sys.executable}\nimport os, sys, time\nend = time.monotonic() + 300\n"
        "print('Collecting torch==2.13.0', flush=True)\n"
        f"{hold}{'    ' if hold else ''}time.sleep(0.01)\n"
        "print('ERROR: Could not find a version that satisfies the requirement torch==2.13.0', flush=True)\n"
        "sys.exit(1)\n"
    )
    pip.chmod(0o755)


class RecordingLayout:
    """A stand-in for a panel's ``layout`` (``draw()`` never runs headless: there is no region): every call is
    recorded in ``calls`` as (name, args, kwargs) and returns the layout again; a property set on it (``enabled``,
    ``active``) is recorded as ("set", (name, value), {})."""

    def __init__(self):
        object.__setattr__(self, "calls", [])

    def __setattr__(self, name, value):
        self.calls.append(("set", (name, value), {}))

    def __getattr__(self, name):
        def record(*args, **kwargs):
            self.calls.append((name, args, kwargs))
            return self

        return record

    def draw(self, panel_cls, context) -> list[tuple[str, tuple, dict]]:
        """Run ``panel_cls.draw`` with this layout; the calls it made."""
        self.calls.clear()
        panel_cls.draw(SimpleNamespace(layout=self), context)
        return list(self.calls)


def as_operator(cls, **attrs) -> SimpleNamespace:
    """A stand-in instance of the operator class ``cls`` (Blender makes the real ones only when it runs an
    operator): its add-on methods bound to it, its plain class values, ``attrs``, and ``reports`` that
    collects what ``report`` says."""
    op = SimpleNamespace()
    for klass in reversed(cls.__mro__):
        if not klass.__module__.startswith("neural_atlas."):
            continue
        for name, value in vars(klass).items():
            if isinstance(value, classmethod):
                setattr(op, name, value.__get__(None, cls))
            elif isinstance(value, staticmethod):
                setattr(op, name, value.__func__)
            elif isinstance(value, types.FunctionType):
                setattr(op, name, types.MethodType(value, op))
            elif not name.startswith("__") and isinstance(value, str | int | float | tuple | type(None)):
                setattr(op, name, value)
    op.reports = []
    op.report = lambda level, message: op.reports.append((level, message))
    for name, value in attrs.items():
        setattr(op, name, value)
    return op


def drive_modal(cls, context, events, limit: int = 1500, **attrs):
    """The UI path of an engine operator without an event loop (none runs headless): its job made and started
    as ``invoke`` does, then ``modal`` called with the event ``events(tick, job)`` names until it ends.
    Returns (what modal returned, the operator stand-in, the job)."""
    op = as_operator(cls, **attrs)
    job = op._begin(context)
    assert job is not None, op.reports
    op._job = job
    op._timer = context.window_manager.event_timer_add(0.1, window=context.window)
    for tick in range(limit):
        ret = op.modal(context, SimpleNamespace(type=events(tick, job)))
        if ret != {"PASS_THROUGH"}:
            return ret, op, job
        time.sleep(0.02)
    raise AssertionError("the modal operator never finished")


def polygon_mask(
    data: Any, corners_by_frame: list[tuple[int, list[tuple[float, float]]]], width: int, height: int
) -> Any:
    """A Mask datablock "Roto" in ``data`` (``bpy.data``: passed in, this module imports no bpy) with one cyclic
    polygon, its points (pixels, origin bottom-left) keyed at each frame of ``corners_by_frame``."""
    from mask_reference import px_to_mask

    mask = data.masks.new("Roto")
    layer = mask.layers.new(name="L")
    spline = layer.splines.new()
    spline.points.add(len(corners_by_frame[0][1]) - 1)
    spline.use_cyclic = True
    for frame, corners in corners_by_frame:
        for i, (p, (x, y)) in enumerate(zip(spline.points, corners, strict=True)):
            p.handle_left_type = p.handle_right_type = "VECTOR"
            p.co = p.handle_left = p.handle_right = px_to_mask(x, y, width, height)
            for prop in ("co", "handle_left", "handle_right"):
                mask.keyframe_insert(f'layers["L"].splines[0].points[{i}].{prop}', frame=frame)
    return mask


def shape_key_mask(
    bpy, clip: Any, corners_by_frame: list[tuple[int, list[tuple[float, float]]]], width: int, height: int
):
    """A Mask "RotoKeys" with one cyclic polygon keyed with layer shape keys, as the Clip Editor's mask tools key it:
    at each frame of ``corners_by_frame`` the points (pixels, origin bottom-left) are placed and Insert Shape Key runs
    in a Clip Editor showing ``clip`` (the first area of the window becomes one)."""
    from mask_reference import px_to_mask

    mask = bpy.data.masks.new("RotoKeys")
    spline = mask.layers.new(name="L").splines.new()
    spline.points.add(len(corners_by_frame[0][1]) - 1)
    spline.use_cyclic = True
    window = bpy.context.window
    area = window.screen.areas[0]
    area.type = "CLIP_EDITOR"
    space = area.spaces.active
    space.mode, space.clip, space.mask = "MASK", clip, mask
    for frame, corners in corners_by_frame:
        bpy.context.scene.frame_set(frame)  # before editing: a frame change re-applies existing keys
        for p, (x, y) in zip(spline.points, corners, strict=True):
            p.handle_left_type = p.handle_right_type = "VECTOR"
            p.co = p.handle_left = p.handle_right = px_to_mask(x, y, width, height)
            p.select = True
        with bpy.context.temp_override(window=window, area=area, region=area.regions[-1], space_data=space):
            assert bpy.ops.mask.shape_key_insert() == {"FINISHED"}
    return mask


def write_tiny_clip(py: str, folder: Path) -> None:
    """The tiny synthetic clip the add-on's real fits use (48x36, 3 frames, one object; ``frames/`` and ``masks/``),
    written by the engine's Python ``py`` (Blender's has no engine requirements)."""
    subprocess.run(
        [py, "-c", "import sys; from pathlib import Path; from engine.data.synthetic import SceneSpec, make_scene, "
         "write_scene; spec = SceneSpec(width=48, height=36, frames=3, fg_size=(16, 12), fg_start=(8.0, 6.0)); "
         "write_scene(make_scene(spec), Path(sys.argv[1]))", str(folder)],
        cwd=HERE.parents[1], check=True, timeout=120,
    )  # fmt: skip


def fit_panel(bpy, clip_file: Path, masks: Path, run_dir: Path, preset: str = "draft", overrides: str = ""):
    """The Fit Atlas panel filled in as an artist does: the clip opened from ``clip_file``, one foreground layer
    from the mask folder ``masks``, the preset, the overrides and the Run Folder; returns the panel's properties."""
    props = bpy.context.scene.neural_atlas
    props.clip = bpy.data.movieclips.load(str(clip_file))
    layer = props.layers.add()
    layer.source = "FOLDER"
    layer.folder = str(masks)
    props.preset = preset
    props.overrides = overrides
    props.run_dir = str(run_dir)
    return props
