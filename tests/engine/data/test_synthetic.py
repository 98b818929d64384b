"""Synthetic scenes: deterministic, exact ground truth, and an idempotent writer."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from engine.data.synthetic import SCENE_JSON, SceneSpec, SyntheticScene, demo_spec, make_scene, write_scene

SMALL = SceneSpec(width=96, height=64, frames=5, fg_start=(20.0, 15.0), fg_size=(30, 20))


@pytest.fixture(scope="module")
def scene() -> SyntheticScene:
    return make_scene(SMALL)


def _ellipse(spec: SceneSpec, off: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Analytic ellipse test value q (inside: q < 1) at every pixel centre."""
    ys, xs = np.mgrid[0 : spec.height, 0 : spec.width].astype(np.float64)
    a, b = spec.fg_size[0] / 2.0, spec.fg_size[1] / 2.0
    return ((xs - off[0] - a) / a) ** 2 + ((ys - off[1] - b) / b) ** 2, np.stack((xs, ys), -1)


def test_frames_are_float32_in_unit_range(scene: SyntheticScene) -> None:
    t, h, w = SMALL.frames, SMALL.height, SMALL.width
    assert scene.frames.shape == (t, h, w, 3) and scene.frames.dtype == np.float32
    assert scene.masks.shape == (t, h, w) and scene.masks.dtype == bool
    assert scene.bg_offset.shape == scene.fg_offset.shape == (t, 2)
    assert scene.bg_offset.dtype == scene.fg_offset.dtype == np.float32
    assert np.isfinite(scene.frames).all()
    assert scene.frames.min() >= 0.0 and scene.frames.max() <= 1.0
    bg = scene.frames[~scene.masks]
    assert bg.min() >= 0.1 and bg.max() <= 0.9  # the plate's colours stay in (0.1, 0.9)
    assert bg.std() > 0.03  # textured, not flat


def test_deterministic_and_seeded(scene: SyntheticScene) -> None:
    again = make_scene(SMALL)
    assert np.array_equal(scene.frames, again.frames) and np.array_equal(scene.masks, again.masks)
    other = make_scene(replace(SMALL, seed=1))
    assert np.abs(other.frames - scene.frames).mean() > 0.02


def test_offsets_follow_spec(scene: SyntheticScene) -> None:
    t = np.arange(SMALL.frames)[:, None]
    np.testing.assert_allclose(scene.bg_offset, t * np.array(SMALL.bg_velocity), atol=1e-5)
    np.testing.assert_allclose(scene.fg_offset, np.array(SMALL.fg_start) + t * np.array(SMALL.fg_velocity), atol=1e-5)


def test_mask_is_the_sprite_ellipse(scene: SyntheticScene) -> None:
    for t in range(SMALL.frames):
        q, _ = _ellipse(SMALL, scene.fg_offset[t].astype(np.float64))
        decided = np.abs(q - 1.0) > 1e-6
        assert np.array_equal(scene.masks[t][decided], (q < 1.0)[decided])
        assert abs(int(scene.masks[t].sum()) - np.pi * 15 * 10) < 0.06 * np.pi * 15 * 10


def test_sprite_edge_is_antialiased(scene: SyntheticScene) -> None:
    """Pixels just outside the ellipse blend sprite over background (coverage in (0, 0.5))."""
    q, xy = _ellipse(SMALL, scene.fg_offset[0].astype(np.float64))
    bg = scene.bg_color(xy + scene.bg_offset[0].astype(np.float64))
    fg = scene.fg_color(xy - scene.fg_offset[0].astype(np.float64))
    diff = np.abs(scene.frames[0] - bg).max(-1)
    far = q > 1.3
    assert diff[far].max() < 1e-5  # untouched background
    deep = q < 0.7
    assert np.abs(scene.frames[0] - fg).max(-1)[deep].max() < 1e-5  # pure sprite
    rim = (q > 1.0) & (q < 1.05)
    assert (diff[rim] > 1e-3).any()  # partially covered


def test_background_point_keeps_its_colour(scene: SyntheticScene) -> None:
    # bg_velocity (2, 0.5): frames 0 and 2 differ by an integer shift (4, 1).
    t0, t1 = 0, 2
    for px in ((80, 50), (85, 5), (70, 60)):
        tex = np.asarray(px, dtype=np.float64) + scene.bg_offset[t0]
        p0 = scene.bg_point_in_frame(tex, t0)
        p1 = scene.bg_point_in_frame(tex, t1)
        np.testing.assert_allclose(p0, px)
        np.testing.assert_allclose(p1, np.asarray(px) - (4.0, 1.0))
        (x0, y0), (x1, y1) = np.rint(p0).astype(int), np.rint(p1).astype(int)
        assert not scene.masks[t0, y0, x0] and not scene.masks[t1, y1, x1]
        assert np.abs(scene.frames[t0, y0, x0] - scene.frames[t1, y1, x1]).max() < 1e-5


def test_sprite_point_keeps_its_colour(scene: SyntheticScene) -> None:
    # fg_velocity (3, 1): any two frames differ by an integer shift; start (20, 15) is integral.
    for tex in ((15.0, 10.0), (8.0, 9.0), (22.0, 12.0)):
        pts = [scene.fg_point_in_frame(tex, t) for t in range(SMALL.frames)]
        cols = [scene.frames[t, int(p[1]), int(p[0])] for t, p in enumerate(pts)]
        assert all(scene.masks[t, int(p[1]), int(p[0])] for t, p in enumerate(pts))
        assert np.abs(np.array(cols) - cols[0]).max() < 1e-5
        np.testing.assert_allclose(cols[0], scene.fg_color(tex), atol=1e-6)


def test_subpixel_offsets_are_exact() -> None:
    """Non-integer motion is rendered analytically: every frame equals the textures at its exact offset."""
    spec = replace(SMALL, bg_velocity=(0.37, -0.71), fg_velocity=(1.3, 0.45), frames=3)
    sc = make_scene(spec)
    ys, xs = np.mgrid[0 : spec.height, 0 : spec.width].astype(np.float64)
    xy = np.stack((xs, ys), -1)
    for t in range(3):
        q, _ = _ellipse(spec, sc.fg_offset[t].astype(np.float64))
        bg = sc.bg_color(xy + np.array(spec.bg_velocity) * t)
        assert np.abs(sc.frames[t] - bg)[q > 1.3].max() < 1e-5
        fg = sc.fg_color(xy - (np.array(spec.fg_start) + np.array(spec.fg_velocity) * t))
        assert np.abs(sc.frames[t] - fg)[q < 0.7].max() < 1e-5


def _saturation(rgb: np.ndarray) -> np.ndarray:
    return rgb.max(-1) - rgb.min(-1)


def test_sprite_looks_different_from_background(scene: SyntheticScene) -> None:
    fg = scene.frames[0][scene.masks[0]]
    bg = scene.frames[0][~scene.masks[0]]
    assert _saturation(fg).mean() > 2 * _saturation(bg).mean()


def test_true_flow(scene: SyntheticScene) -> None:
    flow = scene.true_flow(1)
    assert flow.shape == (SMALL.height, SMALL.width, 2) and flow.dtype == np.float32
    np.testing.assert_allclose(flow[~scene.masks[1]], np.broadcast_to((-2.0, -0.5), (int((~scene.masks[1]).sum()), 2)))
    np.testing.assert_allclose(flow[scene.masks[1]], np.broadcast_to((3.0, 1.0), (int(scene.masks[1].sum()), 2)))


def test_demo_spec() -> None:
    spec = demo_spec()
    assert (spec.width, spec.height, spec.frames) == (320, 180, 24)
    assert spec.bg_velocity == (2.5, 0.6) and spec.fg_velocity == (4.0, 1.2) and spec.fg_size == (70, 50)
    last = np.array(spec.fg_start) + (spec.frames - 1) * np.array(spec.fg_velocity)
    assert (np.array(spec.fg_start) >= 0).all()
    assert last[0] + spec.fg_size[0] <= spec.width and last[1] + spec.fg_size[1] <= spec.height


def test_write_scene_round_trip_and_idempotent(tmp_path: Path, scene: SyntheticScene) -> None:
    frames_dir, masks_dir = write_scene(scene, tmp_path / "demo")
    assert frames_dir == tmp_path / "demo" / "frames" and masks_dir == tmp_path / "demo" / "masks"
    names = [f"{t:05d}.png" for t in range(SMALL.frames)]
    assert sorted(p.name for p in frames_dir.iterdir()) == names
    assert sorted(p.name for p in masks_dir.iterdir()) == names
    for t, name in enumerate(names):
        bgr = cv2.imread(str(frames_dir / name), cv2.IMREAD_UNCHANGED)
        assert bgr.dtype == np.uint8 and bgr.shape == (SMALL.height, SMALL.width, 3)
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0
        assert np.abs(rgb - scene.frames[t]).max() <= 0.5 / 255 + 1e-6  # RGB order preserved
        mask = cv2.imread(str(masks_dir / name), cv2.IMREAD_UNCHANGED)
        assert mask.dtype == np.uint8 and mask.shape == (SMALL.height, SMALL.width)
        assert set(np.unique(mask)) <= {0, 255}
        assert np.array_equal(mask == 255, scene.masks[t])
    # The sprite is orange/magenta: its mean red must exceed its mean blue in the file too.
    rgb0 = cv2.cvtColor(cv2.imread(str(frames_dir / names[0])), cv2.COLOR_BGR2RGB)[scene.masks[0]]
    assert rgb0[:, 0].mean() > rgb0[:, 2].mean()
    meta = json.loads((tmp_path / "demo" / SCENE_JSON).read_text())
    assert meta["spec"]["width"] == SMALL.width

    mtimes = {p: p.stat().st_mtime_ns for p in (*frames_dir.iterdir(), *masks_dir.iterdir())}
    assert write_scene(scene, tmp_path / "demo") == (frames_dir, masks_dir)
    assert {p: p.stat().st_mtime_ns for p in mtimes} == mtimes


def test_write_scene_replaces_a_different_scene(tmp_path: Path, scene: SyntheticScene) -> None:
    folder = tmp_path / "demo"
    write_scene(scene, folder)
    (folder / "frames" / "notes.txt").write_text("keep me")
    shorter = make_scene(replace(SMALL, frames=3, seed=3))
    frames_dir, _ = write_scene(shorter, folder)
    assert sorted(p.name for p in frames_dir.glob("*.png")) == ["00000.png", "00001.png", "00002.png"]
    assert (frames_dir / "notes.txt").read_text() == "keep me"
    back = cv2.cvtColor(cv2.imread(str(frames_dir / "00001.png")), cv2.COLOR_BGR2RGB) / 255.0
    assert np.abs(back - shorter.frames[1]).max() <= 0.5 / 255 + 1e-6
    # A missing file means the folder is not complete: it is rewritten.
    (frames_dir / "00002.png").unlink()
    write_scene(shorter, folder)
    assert (frames_dir / "00002.png").is_file()
