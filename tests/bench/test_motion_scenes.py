"""The synthetic motion scenes: their ground truth agrees with their pixels, each shows the motion it is named for,
the clip folders are byte-identical on rewrite, and the ``clips`` bench scores one end to end. The two bodies of
``bench.motion_bodies`` have their own motion checked in tests/bench/test_motion_bodies.py."""

from __future__ import annotations

import contextlib
import io
import zipfile

import cv2
import numpy as np
import pytest

from bench.__main__ import main as bench_main
from bench.all_clips import clips_plan, run_all_clips
from bench.bench_clip import TRACKS_FILE
from bench.degrade import RECIPES, degrade_mask, dropped_frames, read_gt
from bench.motion_bodies import FRONT_LIMB, LimbsJump, TurningDepth
from bench.motion_builders import ARM_LENGTH, BAR_WIDTH, DESCRIPTIONS, SMALL_AREA, SMALL_SPEED
from bench.motion_scenes import (
    GT_UV_NPZ,
    PART_MASKS,
    ROUGH_MASKS,
    ROUGH_RECIPE,
    TEXTURE_PNG,
    ZIP_DATE,
    MotionScene,
    make_motion_scene,
    part_masks,
    write_motion_clip,
    write_motion_spec,
)
from bench.motion_spec import DEFAULT_FRAMES, DEFAULT_SIZE, KINDS, MotionSpec
from bench.motion_tracks import TRACKS
from bench.tool_parsers import build_parser
from bench.tracking import load_tracks
from engine import contract as C
from tests.folders import tree_digest

SIZE = {"width": 128, "height": 96, "frames": 8}
#: The texture re-sampled through the exact UV field (bicubic) matches the frames' unblended object pixels to this.
TEXTURE_MIN_PSNR_DB = 40.0


@pytest.fixture(scope="module")
def scenes() -> dict[str, MotionScene]:
    return {kind: make_motion_scene(kind, **SIZE) for kind in KINDS}


def _centres(h: int, w: int) -> np.ndarray:
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    return np.stack((xs, ys), -1) + 0.5


def _wrapped(scene: MotionScene, duv: np.ndarray) -> np.ndarray:
    """A difference of surface coordinates; a turning body's u wraps round it."""
    period = scene.model.u_period
    if period is None:
        return duv
    out = duv.copy()
    out[..., 0] = (out[..., 0] + period / 2.0) % period - period / 2.0
    return out


def _px_error(scene: MotionScene, t: int, p: np.ndarray, duv: np.ndarray) -> float:
    """A surface-coordinate error ``duv`` at point ``p`` of frame ``t`` in frame pixels: through the inverse of the
    local Jacobian of the surface coordinate (central differences)."""
    eps = 1e-3
    cols = [(scene.uv_at(t, p + d)[0] - scene.uv_at(t, p - d)[0]) / (2 * eps) for d in np.eye(2) * eps]
    return float(np.hypot(*np.linalg.solve(np.stack(cols, -1), _wrapped(scene, duv))))


def _unblended(scene: MotionScene, t: int, p: np.ndarray) -> np.ndarray:
    """Where frame points ``p`` [..., 2] (centres at i + 0.5) show one surface's own colour: fully covered, and of
    a body in parts, by the visible part alone (no part in front reaches them)."""
    x, y = p[..., 0] - 0.5, p[..., 1] - 0.5
    if isinstance(scene.model, LimbsJump):
        return scene.model.unblended(t, x, y)
    return np.asarray(scene.model.surface(t, x, y)[1] >= 0.999)


def _one_surface_round(scene: MotionScene, t: int, p: np.ndarray) -> bool:
    """The four pixels round ``p`` show one smooth piece of surface: bilinear interpolation of the field bends on a
    turning body's foreshortened sides and mixes two parts' texture regions where parts meet."""
    model = scene.model
    if isinstance(model, TurningDepth):
        return bool(model.facing_cos(t, scene.uv_at(t, p)[0]) > 0.5)
    if isinstance(model, LimbsJump):
        x0, y0 = np.floor(p - 0.5)
        corners = np.array([[x0, y0], [x0 + 1, y0], [x0, y0 + 1], [x0 + 1, y0 + 1]])
        return len(set(model.visible_part(t, corners[:, 0], corners[:, 1]).tolist())) == 1
    return True


def _bilinear(field: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``field`` [H, W, C] at ``xy`` [2] (centres at i + 0.5): NaN unless all four neighbours are set."""
    x, y = xy - 0.5
    x0, y0 = int(np.floor(x)), int(np.floor(y))
    if not (0 <= x0 < field.shape[1] - 1 and 0 <= y0 < field.shape[0] - 1):
        return np.full(field.shape[-1], np.nan)
    fx, fy = x - x0, y - y0
    top = field[y0, x0] * (1 - fx) + field[y0, x0 + 1] * fx
    bottom = field[y0 + 1, x0] * (1 - fx) + field[y0 + 1, x0 + 1] * fx
    return top * (1 - fy) + bottom * fy


@pytest.mark.parametrize("kind", KINDS)
def test_frames_masks_and_uv_field_are_the_forward_model(scenes, kind):
    scene = scenes[kind]
    t_n, h, w = scene.masks.shape
    assert scene.frames.shape == (t_n, h, w, 3) and scene.uv.shape == (t_n, h, w, 2)
    assert scene.frames.min() >= 0.0 and scene.frames.max() <= 1.0
    pts = _centres(h, w)
    for t in (0, t_n - 1):
        np.testing.assert_allclose(scene.colour_at(t, pts), scene.frames[t], atol=1e-6)
        uv, cov = scene.uv_at(t, pts)
        np.testing.assert_array_equal(scene.masks[t], cov > 0.5)
        assert np.isnan(scene.uv[t][~scene.masks[t]]).all() and np.isfinite(scene.uv[t][scene.masks[t]]).all()
        np.testing.assert_allclose(scene.uv[t][scene.masks[t]], uv[scene.masks[t]], atol=1e-4)
        assert scene.masks[t].sum() > 20


@pytest.mark.parametrize("kind", KINDS)
def test_tracks_follow_the_surface_point(scenes, kind):
    """A track's position shows its query's surface point (exactly, and through the stored field re-projected
    to within 0.05 px) and the same colour in every frame where it is visible."""
    scene = scenes[kind]
    tr = scene.tracks
    t_n = scene.spec.frames
    n_tracks = len(tr.xy)
    assert tr.xy.shape == (n_tracks, t_n, 2) and tr.on_mask is not None and tr.on_mask.all()
    # TRACKS per part; a limb seen in a sliver at a query frame may have fewer unblended pixels than its share
    assert n_tracks == TRACKS if scene.model.n_parts == 1 else 0.9 * TRACKS * scene.model.n_parts <= n_tracks
    assert len(np.unique(tr.query_txy[:, 0])) == 4 and tr.query_txy[:, 0].max() == t_n - 1
    checked_field = 0
    for n in range(len(tr.xy)):
        tq, qx, qy = tr.query_txy[n]
        tq = int(tq)
        assert not tr.occluded[n, tq]
        np.testing.assert_allclose(tr.xy[n, tq], (qx, qy), atol=1e-4)
        quv, qcov = scene.uv_at(tq, np.array([qx, qy]))
        qcol = scene.colour_at(tq, np.array([qx, qy]))
        assert qcov == pytest.approx(1.0, abs=1e-3)
        for t in np.flatnonzero(~tr.occluded[n]):
            p = tr.xy[n, t].astype(np.float64)
            uv = scene.uv_at(int(t), p)[0]
            assert _px_error(scene, int(t), p, uv - quv) < 1e-3  # the float32 of the stored position
            if _unblended(scene, int(t), p):
                assert np.abs(scene.colour_at(int(t), p) - qcol).max() < 1e-3
            if not _one_surface_round(scene, int(t), p):
                continue
            if kind == "turning" and abs(p[0] - 0.5 - scene.model._centre(t)[0]) > 0.7 * scene.model.radius:  # type: ignore[union-attr]
                continue  # the foreshortened limb: bilinear interpolation of the field bends there
            field_uv = _bilinear(scene.uv[t].astype(np.float64), p)
            if not np.isfinite(field_uv).all():
                continue
            assert _px_error(scene, int(t), p, field_uv - quv) < 0.05
            checked_field += 1
    assert checked_field >= 30


@pytest.mark.parametrize("kind", KINDS)
def test_the_texture_through_the_uv_field_gives_the_frames(scenes, kind):
    """The true texture, sampled (bicubic) at the ground-truth UV of every unblended object pixel, is the frame
    there: the atlas a perfect fit would hold, and the mapping that would show it."""
    scene = scenes[kind]
    tw, th = scene.model.texture_size
    assert scene.texture.shape == (th, tw, 3)
    pts = _centres(scene.spec.height, scene.spec.width)
    for t in range(scene.spec.frames):
        uv = np.nan_to_num(scene.uv[t], nan=-10.0)
        resampled = cv2.remap(scene.texture, uv[..., 0], uv[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
        # bicubic reads texels -1..+2 round the point: inside the texture only
        keep = _unblended(scene, t, pts) & (uv[..., 0] >= 1) & (uv[..., 0] <= tw - 3)
        keep &= (uv[..., 1] >= 1) & (uv[..., 1] <= th - 3)
        assert keep.sum() > 100
        mse = float(((resampled[keep] - scene.frames[t][keep]) ** 2).mean())
        assert -10.0 * np.log10(mse) > TEXTURE_MIN_PSNR_DB
        off = ~scene.masks[t]
        assert np.abs(resampled[off] - scene.frames[t][off]).max() > 0.1  # the plate is not the texture


def test_turning_hides_and_reveals_texture(scenes):
    scene = scenes["turning"]
    model, last = scene.model, scene.spec.frames - 1
    first_uv = scene.uv[0][scene.masks[0]].astype(np.float64)
    last_uv = scene.uv[last][scene.masks[last]].astype(np.float64)
    hidden = 1.0 - model.position(float(last), first_uv)[1].mean()
    new = 1.0 - model.position(0.0, last_uv)[1].mean()
    assert hidden > 0.9 and new > 0.9  # 200 degrees of turn: nearly all of one side is replaced
    tr = scene.tracks
    turned_away = [n for n in range(len(tr.xy)) if tr.occluded[n].any()]
    assert len(turned_away) >= 8
    assert all(
        not tr.occluded[n, int(tr.query_txy[n, 0])] for n in turned_away
    )  # visible at the query, hidden later or earlier


def _similarity_residual(src: np.ndarray, dst: np.ndarray) -> float:
    """RMS px of the least-squares similarity (rotation, scale, translation) from ``src`` to ``dst`` [N, 2]."""
    a = np.zeros((2 * len(src), 4))
    a[0::2] = np.c_[src[:, 0], -src[:, 1], np.ones(len(src)), np.zeros(len(src))]
    a[1::2] = np.c_[src[:, 1], src[:, 0], np.zeros(len(src)), np.ones(len(src))]
    coef, *_ = np.linalg.lstsq(a, dst.reshape(-1), rcond=None)
    return float(np.sqrt(((a @ coef - dst.reshape(-1)) ** 2).reshape(-1, 2).sum(-1).mean()))


def test_deforming_is_not_a_similarity_and_the_rigid_ones_are(scenes):
    residual = {}
    for kind in ("deforming", "small_fast", "thin"):
        scene = scenes[kind]
        uv = scene.uv[0][scene.masks[0]].astype(np.float64)
        src = scene.model.position(0.0, uv)[0]
        residual[kind] = max(
            _similarity_residual(src, scene.model.position(float(t), uv)[0]) for t in range(1, scene.spec.frames)
        )
    assert residual["deforming"] > 2.0
    assert residual["small_fast"] < 1e-3 and residual["thin"] < 1e-3


def test_small_fast_is_small_and_fast(scenes):
    scene = scenes["small_fast"]
    area = scene.masks.mean(axis=(1, 2))
    assert np.abs(area - SMALL_AREA).max() < 0.002
    centre = np.array([np.argwhere(m)[:, ::-1].mean(0) for m in scene.masks])
    step = np.linalg.norm(np.diff(centre, axis=0), axis=-1)
    assert step.min() > SMALL_SPEED - 0.5 and step.max() < 3 * SMALL_SPEED


def test_thin_bars_are_three_pixels_wide(scenes):
    scene = scenes["thin"]
    arm = ARM_LENGTH * scene.spec.height
    width = scene.masks.sum(axis=(1, 2)) / (4.0 * arm - BAR_WIDTH)  # mask area over the cross's centre lines
    assert np.abs(width - BAR_WIDTH).max() < 0.3
    pts = _centres(scene.spec.height, scene.spec.width) - 0.5
    for t, m in enumerate(scene.masks):
        depth = cv2.distanceTransform(m.astype(np.uint8), cv2.DIST_L2, 5)
        off_hub = np.hypot(*(pts - scene.model.path(t)).transpose(2, 0, 1)) > 2 * BAR_WIDTH  # type: ignore[union-attr]
        assert depth[off_hub].max() <= 2.3  # a 3 px bar's middle pixel is 2 from the outside, at any angle


@pytest.mark.parametrize("kind", ["turning_depth", "limbs_jump"])
def test_a_clip_written_a_frame_at_a_time_is_the_scenes_clip_byte_for_byte(tmp_path, kind):
    """``write_motion_spec`` (what ``bench motion-scenes`` runs, for plates larger than memory) writes the very files
    ``write_motion_clip`` writes of the whole rendered scene, part masks included, and leaves no field file."""
    spec = MotionSpec(kind, 72, 40, 7)
    whole = write_motion_clip(make_motion_scene(spec), tmp_path / "whole")
    streamed = write_motion_spec(spec, tmp_path / "streamed")
    a, b = tree_digest(whole), tree_digest(streamed)
    assert a == b and len(a) >= 3 * 7 + 3
    assert any(name.startswith(PART_MASKS) for name in a) == (kind == "limbs_jump")
    assert not [p for p in streamed.iterdir() if p.name.startswith(".")]


def test_clip_folder_is_written_byte_identical(tmp_path):
    scene = make_motion_scene(MotionSpec("thin", 64, 48, 5))
    a, b = write_motion_clip(scene, tmp_path / "a"), write_motion_clip(scene, tmp_path / "b")
    names = sorted(str(p.relative_to(a)) for p in a.rglob("*") if p.is_file())
    pngs = [f"{d}/{t:05d}.png" for d in ("frames", "masks", ROUGH_MASKS) for t in range(5)]
    assert names == sorted([*pngs, GT_UV_NPZ, TRACKS_FILE, TEXTURE_PNG])
    for n in names:
        assert (a / n).read_bytes() == (b / n).read_bytes(), n
    for npz in (GT_UV_NPZ, TRACKS_FILE):
        with zipfile.ZipFile(a / npz) as z:
            assert {i.date_time for i in z.infolist()} == {ZIP_DATE}
    for t in range(5):
        np.testing.assert_array_equal(read_gt(a / "masks" / f"{t:05d}.png"), scene.masks[t])
        png = cv2.cvtColor(cv2.imread(str(a / "frames" / f"{t:05d}.png")), cv2.COLOR_BGR2RGB)
        np.testing.assert_array_equal(png, np.rint(scene.frames[t] * 255).astype(np.uint8))
    texture = cv2.cvtColor(cv2.imread(str(a / TEXTURE_PNG)), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(texture, np.rint(scene.texture * 255).astype(np.uint8))
    tracks = load_tracks(a / TRACKS_FILE)
    visible = ~scene.tracks.occluded
    np.testing.assert_array_equal(tracks.occluded, scene.tracks.occluded)
    np.testing.assert_array_equal(tracks.xy[visible], scene.tracks.xy[visible])
    with np.load(a / GT_UV_NPZ) as d:
        np.testing.assert_array_equal(d["uv"], scene.uv)
        assert str(d["kind"]) == "thin"


def test_rough_masks_are_the_clips_bench_default_recipe(tmp_path):
    """masks_rough/ is the exact masks grown by 10 px with a tenth of the frames dropped (empty), the frames
    ``clips`` drops with its default seed: what the bench fits, ready for a fit by hand."""
    assert ROUGH_RECIPE == "dilated10_dropped10"
    scene = make_motion_scene(MotionSpec("limbs_jump", 96, 64, 20))
    folder = write_motion_clip(scene, tmp_path / "clip")
    dropped = dropped_frames(20, RECIPES[ROUGH_RECIPE].drop_fraction, 0)
    assert len(dropped) == 2 and 0 not in dropped
    for t in range(20):
        rough = read_gt(folder / ROUGH_MASKS / f"{t:05d}.png")
        if t in dropped:
            assert not rough.any()
            continue
        np.testing.assert_array_equal(rough, degrade_mask(scene.masks[t], RECIPES[ROUGH_RECIPE]))
        assert rough[scene.masks[t]].all() and rough.sum() > 1.5 * scene.masks[t].sum()


def test_the_jumping_body_is_written_as_two_parts_a_compositor_would_roto(tmp_path):
    """masks_parts/front_limb holds the pixels showing the front limb, masks_parts/body the rest of the object:
    disjoint, together the object's masks; the limb is in every frame; a one-part scene writes none."""
    scene = make_motion_scene(MotionSpec("limbs_jump", 96, 64, 8))
    folder = write_motion_clip(scene, tmp_path / "clip")
    body = np.stack([read_gt(folder / PART_MASKS / "body" / f"{t:05d}.png") for t in range(8)])
    limb = np.stack([read_gt(folder / PART_MASKS / "front_limb" / f"{t:05d}.png") for t in range(8)])
    assert not (body & limb).any()
    np.testing.assert_array_equal(body | limb, scene.masks)
    assert limb.sum(axis=(1, 2)).min() > 100 and body.sum() > 2 * limb.sum()  # a limb is about a third of the body
    shown = scene.model.part_of(scene.uv[limb])  # type: ignore[attr-defined]
    assert set(np.unique(shown)) == {FRONT_LIMB}
    assert part_masks(make_motion_scene(MotionSpec("thin", 32, 24, 4))) == {}
    thin = write_motion_clip(make_motion_scene(MotionSpec("thin", 32, 24, 4)), tmp_path / "thin")
    assert not (thin / PART_MASKS).exists()


def test_a_shorter_rewrite_leaves_no_stale_frames(tmp_path):
    write_motion_clip(make_motion_scene(MotionSpec("thin", 32, 24, 6)), tmp_path / "clip")
    write_motion_clip(make_motion_scene(MotionSpec("thin", 32, 24, 4)), tmp_path / "clip")
    for d in ("frames", "masks", ROUGH_MASKS):
        assert sorted(p.name for p in (tmp_path / "clip" / d).iterdir()) == [f"{t:05d}.png" for t in range(4)]


def test_the_cli_writes_the_chosen_scenes(tmp_path, capsys):
    out = tmp_path / "scenes"
    args = ["motion-scenes", str(out), "--width", "64", "--height", "48", "--frames", "4"]
    assert bench_main([*args, "--kinds", "thin,small_fast"]) == C.EXIT_OK
    assert sorted(p.name for p in out.iterdir()) == ["small_fast", "thin"]
    assert capsys.readouterr().out.split() == [str((out / k).resolve()) for k in ("thin", "small_fast")]
    assert len(list((out / "thin" / "frames").iterdir())) == 4
    defaults = build_parser().parse_args(["motion-scenes", str(out)])
    assert (defaults.width, defaults.height, defaults.frames) == (*DEFAULT_SIZE, DEFAULT_FRAMES)
    assert bench_main([*args, "--kinds", "spinning"]) == C.EXIT_BAD_INPUT
    assert "unknown scene 'spinning'" in capsys.readouterr().err


def test_clips_bench_scores_a_motion_clip(tmp_path):
    """One tiny deforming clip through ``run_all_clips``: a row with atlas and chained-flow delta_avg."""
    root = tmp_path / "root"
    write_motion_clip(make_motion_scene("deforming", width=64, height=48, frames=6), root / "deforming")
    with contextlib.redirect_stderr(io.StringIO()):
        plan = clips_plan("draft", overrides={"steps": "30", "batch": "400"}, device_name="cpu", threads=1)
        table = run_all_clips(root, tmp_path / "out", plan, degrade="exact")
    (row,) = table["rows"]
    assert row["clip"] == "deforming" and not row["failed"] and row["steps"] == 30
    assert 0.0 <= row["atlas_delta_avg"] <= 1.0 and 0.0 <= row["flow_delta_avg"] <= 1.0
    assert 0.0 <= row["fg_iou"] <= 1.0 and np.isfinite(row["psnr"])
    assert (tmp_path / "out" / "clips.md").is_file()


def test_descriptions_name_the_numbers():
    assert DESCRIPTIONS["turning"].startswith("a textured cylinder turning 200 degrees")
    assert "(2% of the frame)" in DESCRIPTIONS["small_fast"] and "12 px/frame" in DESCRIPTIONS["small_fast"]
    assert "3 px wide bars, turning 0.1 rad/frame" in DESCRIPTIONS["thin"] and "(6 px)" in DESCRIPTIONS["deforming"]
    assert DESCRIPTIONS["turning_depth"].startswith("an elongated textured body turning 180 degrees")
    assert "swinging 35 degrees either way" in DESCRIPTIONS["limbs_jump"]


def test_unknown_kind_is_refused():
    with pytest.raises(ValueError, match="unknown motion scene 'spinning'"):
        MotionSpec("spinning")
