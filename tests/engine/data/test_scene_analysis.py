"""Scene analysis (engine.data.scene_analysis): each decision on a named scene that has exactly that property, the model
and objective computing only what the analysis keeps, and the record in scene.json, progress and manifest.
"""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
import torch

from bench.scenes import SCENES, make_named_scene
from engine import contract as C
from engine.config import apply_overrides, preset_config
from engine.data.flow import DISFlow, compute_flow
from engine.data.scene_analysis import PANZOOM_RESIDUAL_PX, STATIC_MOTION_PX, analyse_scene
from engine.data.video import build_video_tensors, sample_pixels
from engine.errors import InputError
from engine.fit.fit_inputs import FitInputs
from engine.fit.fitted_run import load_run
from engine.fit.model_build import build_model
from engine.fit.prepare import prepare_clip
from engine.fit.progress import Reporter
from engine.fit.run_folder import RunFolder
from engine.io.images import write_png
from engine.loss_terms import ALL_TERMS
from engine.model.atlas_model import FastModel
from engine.model.objective import compute_losses
from engine.terms.export_names import (
    PASSES_DIR,
    alpha_pass,
    pass_file_name,
    uv_pass,
)
from engine.terms.manifest import validate_scene
from engine.terms.run_folder import (
    BG_MOTION_DEFORMABLE,
    BG_MOTION_PAN_ZOOM,
    BG_MOTION_STATIC,
    FLOW_CACHE_DIR,
    RUN_CLIP,
    SCENE_FILE,
    SCENE_LAYERS_AUTO,
    SCENE_LAYERS_NONE,
)
from tests.engine.fit_helpers import quiet_fit

TINY = {"steps": "60", "batch": "512", "eval_every": "30", "bootstrap_steps": "30", "global_rigidity_steps": "20"}


def _analyse(name: str, with_masks: bool = True, **overrides: str):
    scene = make_named_scene(name)
    flow = compute_flow(scene.frames, DISFlow("medium"))
    masks = scene.masks[None] if (with_masks and scene.has_object) else np.zeros((0, *scene.masks.shape), bool)
    cfg = apply_overrides(preset_config("draft"), overrides)
    return analyse_scene(len(scene.frames), flow, masks, cfg), scene


def _write_clip(folder, frames, masks=None):
    for t, f in enumerate(frames):
        write_png(folder / "frames" / f"{t:05d}.png", f)
        if masks is not None:
            write_png(folder / "masks" / f"{t:05d}.png", masks[t][..., None].astype(np.float32))
    return folder / "frames", (folder / "masks" if masks is not None else None)


def test_every_named_scene_renders_with_a_docstring():
    for name, build in SCENES.items():
        s = build(width=40, height=24, frames=3)
        assert s.name == name and s.frames.shape == (3, 24, 40, 3) and build.__doc__
        assert np.isfinite(s.frames).all() and s.frames.min() >= 0.0 and s.frames.max() <= 1.0
        assert s.masks.any() == s.has_object
    with pytest.raises(ValueError, match="known"):
        make_named_scene("nope")


@pytest.mark.parametrize(
    ("name", "motion"),
    [
        ("static_camera", BG_MOTION_STATIC),
        ("lighting_change", BG_MOTION_STATIC),
        ("pan", BG_MOTION_PAN_ZOOM),
        ("parallax", BG_MOTION_DEFORMABLE),
    ],
)
def test_background_motion_class(name, motion):
    scene, _ = _analyse(name)
    assert scene.background_motion == motion, scene.reasons["background_motion"]
    m = scene.measured
    if motion == BG_MOTION_STATIC:
        assert m["background_median_motion_px"] < STATIC_MOTION_PX
        assert "global_rigidity_bg" not in scene.active_terms
    else:
        assert m["background_median_motion_px"] > 1.0  # the scenes move 2 px/frame or more
    if motion == BG_MOTION_PAN_ZOOM:
        assert m["similarity_residual_px"] < PANZOOM_RESIDUAL_PX
    if motion == BG_MOTION_DEFORMABLE:
        assert m["similarity_residual_px"] > 2 * PANZOOM_RESIDUAL_PX
    assert m["pairs_measured"] == m["pairs"] == 5


def test_background_only_has_no_foreground_terms_and_no_alpha_network():
    scene, _ = _analyse("lighting_change")
    assert scene.num_layers == 1 and scene.layers_source == SCENE_LAYERS_NONE and not scene.alpha_network
    assert "no masks were given" in scene.reasons["layers"]
    assert scene.active_terms == ["rgb", "gradient", "rigidity", "flow"]


def test_single_frame_has_no_flow_terms():
    s = make_named_scene("static_camera", frames=1)
    cfg = preset_config("draft")
    scene = analyse_scene(1, None, s.masks[None], cfg)
    assert not scene.flow and "flow" not in scene.active_terms and "alpha_flow" not in scene.active_terms
    assert scene.num_layers == 2 and "sparsity" in scene.active_terms


def test_zero_weight_and_scribbles_and_bad_components():
    scene, _ = _analyse("pan", w_sparsity="0", w_mask_prior="0")
    assert "sparsity" not in scene.active_terms and "weight" in scene.reasons["sparsity"]
    assert "mask_prior" not in scene.active_terms and "mask" in scene.active_terms
    s = make_named_scene("pan")
    cfg = preset_config("draft")
    sc = analyse_scene(len(s.frames), None, s.masks[None], cfg, scribbles=2)
    assert "scribble" in sc.active_terms and sc.scribbles == 2
    with pytest.raises(InputError, match="components"):
        _analyse("pan", components="some")


def test_components_all_forces_everything_and_records_it():
    auto, _ = _analyse("static_camera")
    forced, _ = _analyse("static_camera", components="all")
    assert forced.background_motion == BG_MOTION_DEFORMABLE and forced.active_terms == list(ALL_TERMS)
    assert forced.term_set is None and auto.term_set == frozenset(auto.active_terms)
    assert any("static" in o for o in forced.overrides) and any("global_rigidity_bg" in o for o in forced.overrides)
    # what the analysis measured is kept, so the record says what was overridden and why
    assert forced.measured == auto.measured


def _count_calls(model: torch.nn.Module) -> dict[str, int]:
    counts: dict[str, int] = {}
    for name, mod in model.named_modules():
        if name and not list(mod.children()):
            mod.register_forward_hook(lambda m, i, o, n=name: counts.__setitem__(n, counts.get(n, 0) + 1))
    return counts


def test_static_background_only_evaluates_fewer_modules_and_terms(tmp_path):
    """Counting, not timing: one objective evaluation of the same clip with components auto vs all."""
    s = make_named_scene("lighting_change")
    frames_dir, _ = _write_clip(tmp_path / "clip", s.frames)
    results = {}
    for comp in ("auto", "all"):
        cfg = apply_overrides(preset_config("draft"), {"components": comp})
        prep = prepare_clip(FitInputs(frames_dir), cfg, tmp_path / comp, Reporter(None, io.StringIO()))
        scene = analyse_scene(len(prep.frames), prep.flow, prep.masks, cfg)
        model = build_model(cfg, prep, scene)
        video = build_video_tensors(prep.frames, prep.masks, prep.flow, cfg.mask_prior_margin_px, torch.device("cpu"))
        counts = _count_calls(model)
        ix, iy, tt = sample_pixels(video.shape, 256, torch.Generator().manual_seed(0), torch.device("cpu"))
        total, terms = compute_losses(model, video, cfg, 0, ix, iy, tt)
        total.backward()
        n_params = sum(p.numel() for p in model.parameters())
        results[comp] = (set(counts), sum(counts.values()), set(terms), n_params, model)
    auto, full = results["auto"], results["all"]
    assert isinstance(auto[4], FastModel) and auto[4].alpha_grid is None and full[4].alpha_grid is not None
    assert auto[4].mappings[0].residual is None and auto[4].mappings[0].warp is None
    assert not any("alpha" in n or "residual" in n or "warp" in n for n in auto[0])
    assert auto[1] < full[1], (auto[1], full[1])
    assert auto[2] == {"rgb", "gradient", "rigidity", "flow"}
    assert full[2] >= {"sparsity", "alpha_flow", "global_rigidity_bg", "global_rigidity_fg"}
    print(f"\nleaf module calls auto {auto[1]} vs all {full[1]}; parameters {auto[3]} vs {full[3]}")
    assert auto[3] < full[3] / 2


@pytest.mark.slow
def test_fit_records_scene_and_export_has_one_layer(tmp_path):
    """A background-only static clip: scene.json, the 'scene' stage event, a 1-layer export whose passes
    hold only the background, and a manifest carrying the scene; the background reconstructs."""
    from engine.export.exporter import export_run
    from engine.io.images import read_exr

    s = make_named_scene("lighting_change", width=64, height=40, frames=4)
    still = np.repeat(s.frames[:1], 4, axis=0)  # a tripod plate under constant light
    frames_dir, _ = _write_clip(tmp_path / "clip", still)
    psnr = {}
    for comp in ("all", "auto"):
        cfg = apply_overrides(preset_config("draft"), {**TINY, "components": comp})
        stream = io.StringIO()
        run = tmp_path / f"run_{comp}"
        metrics = quiet_fit(run, cfg, FitInputs(frames_dir), stream)
        psnr[comp] = metrics["psnr"]
    print(f"\nbackground-only still plate, 60 steps: psnr auto {psnr['auto']:.2f} dB, all {psnr['all']:.2f} dB")
    assert psnr["auto"] > 25.0 and psnr["auto"] > psnr["all"] - 0.5 and metrics["alpha_iou"] == []
    scene = RunFolder(run).read_scene()
    assert scene.background_motion == BG_MOTION_STATIC and scene.num_layers == 1
    events = [m for m in map(C.parse_progress_line, stream.getvalue().splitlines()) if m]
    staged = [m for m in events if m["event"] == C.EVENT_STAGE and m["stage"] == "scene"]
    assert len(staged) == 1 and staged[0]["scene"]["background_motion"] == BG_MOTION_STATIC
    losses = [m["losses"] for m in events if m["event"] == C.EVENT_PROGRESS]
    assert losses and all(set(x) == {"rgb", "gradient", "rigidity", "flow"} for x in losses)
    model, _, _ = load_run(run)
    assert model.num_layers == 1 and model.active_terms == frozenset(scene.active_terms)

    manifest_path = export_run(run, atlas_size=64, progress_bar=False, stream=io.StringIO())
    manifest = C.load_manifest(str(manifest_path))
    assert [layer["name"] for layer in manifest["layers"]] == ["Background"]
    assert manifest["scene"]["background_motion"] == BG_MOTION_STATIC
    assert manifest["scene"]["num_layers"] == 1
    chans = read_exr(manifest_path.parent / PASSES_DIR / pass_file_name(0))
    assert set(chans) == {C.channel_name(uv_pass("Background"), c) for c in C.UV_CHANNELS} | {
        C.channel_name(alpha_pass("Background"), "V")
    }  # the STMap copy is written only when asked for
    assert np.array_equal(chans[C.channel_name(alpha_pass("Background"), "V")], np.ones((40, 64), np.float32))


def test_a_run_without_its_scene_analysis_is_refused(tmp_path):
    with pytest.raises(InputError, match="no scene analysis") as err:
        RunFolder(tmp_path).read_scene()
    assert SCENE_FILE in str(err.value) and "\n" not in str(err.value)


def test_manifest_scene_is_validated():
    good = {"components": "auto", "num_layers": 1, "layers_source": "none", "background_motion": "static"}
    good |= {"flow": True, "active_terms": ["rgb"], "reasons": {}}
    validate_scene(good, 1)
    with pytest.raises(C.ManifestError, match="background_motion"):
        validate_scene({**good, "background_motion": "wobbly"})
    with pytest.raises(C.ManifestError, match="2 layers"):
        validate_scene({**good, "num_layers": 2}, 1)
    with pytest.raises(C.ManifestError, match="active_terms"):
        validate_scene({k: v for k, v in good.items() if k != "active_terms"})


@pytest.mark.slow
def test_single_frame_fit_computes_no_flow(tmp_path):
    s = make_named_scene("static_camera", width=48, height=32, frames=1)
    frames_dir, masks_dir = _write_clip(tmp_path / "clip", s.frames, s.masks)
    cfg = apply_overrides(preset_config("draft"), {**TINY, "steps": "20"})
    stream = io.StringIO()
    run = tmp_path / "run"
    metrics = quiet_fit(run, cfg, FitInputs(frames_dir, [masks_dir]), stream)
    assert np.isfinite(metrics["psnr"])
    assert not (run / FLOW_CACHE_DIR).exists()
    stages = [m["stage"] for m in map(C.parse_progress_line, stream.getvalue().splitlines()) if m and "stage" in m]
    assert "flow" not in stages and "scene" in stages
    scene = json.loads((run / SCENE_FILE).read_text())
    assert scene["flow"] is False and "flow" not in scene["active_terms"]


@pytest.mark.slow
def test_auto_masks_fit_uses_found_masks_or_falls_back(tmp_path):
    """--auto-masks on the static-camera scene finds the object (IoU vs truth reported) and fits 2 layers;
    on the lighting-change scene (nothing moves) it fits the background alone, with the reason recorded."""
    from engine.data.auto_masks import mask_iou
    from engine.io.clip import open_clip, read_masks

    s = make_named_scene("static_camera", width=128, height=80, frames=6)
    frames_dir, masks_dir = _write_clip(tmp_path / "obj", s.frames, s.masks)
    cfg = apply_overrides(preset_config("draft"), {**TINY, "steps": "20"})
    run = tmp_path / "run_obj"
    quiet_fit(run, cfg, FitInputs(frames_dir, auto_masks=True))
    scene = RunFolder(run).read_scene()
    assert scene.layers_source == SCENE_LAYERS_AUTO and scene.num_layers == 2
    info = open_clip(frames_dir)
    found = read_masks(run / C.AUTO_MASKS_DIR, info, (128, 80))
    iou = mask_iou(found, read_masks(masks_dir, info, (128, 80)))
    print(f"\nauto masks on static_camera: IoU mean {iou.mean():.3f} min {iou.min():.3f}")
    assert iou.mean() >= 0.5
    assert json.loads((run / RUN_CLIP).read_text())["masks"] == [str((run / C.AUTO_MASKS_DIR).resolve())]

    still = make_named_scene("lighting_change", width=128, height=80, frames=6)
    frames_dir, _ = _write_clip(tmp_path / "still", still.frames)
    run = tmp_path / "run_still"
    quiet_fit(run, cfg, FitInputs(frames_dir, auto_masks=True))
    scene = RunFolder(run).read_scene()
    assert scene.num_layers == 1 and scene.layers_source == SCENE_LAYERS_AUTO
    assert "no moving object was found" in scene.reasons["layers"]


def test_pan_builds_a_small_residual_and_no_warp_grid(tmp_path):
    """Pan/zoom background: similarity + a 16-wide residual MLP, no warp grid; the same clip with
    components=all gets the full mapping (warp grid, 64-wide MLP)."""
    from engine.model.atlas_model import PANZOOM_MAPPING_HIDDEN

    s = make_named_scene("pan")
    frames_dir, masks_dir = _write_clip(tmp_path / "clip", s.frames, s.masks)
    built = {}
    for comp in ("auto", "all"):
        cfg = apply_overrides(preset_config("draft"), {"components": comp})
        prep = prepare_clip(FitInputs(frames_dir, [masks_dir]), cfg, tmp_path / comp, Reporter(None, io.StringIO()))
        scene = analyse_scene(len(prep.frames), prep.flow, prep.masks, cfg)
        built[comp] = (scene, build_model(cfg, prep, scene))
    scene, model = built["auto"]
    assert scene.background_motion == BG_MOTION_PAN_ZOOM and "global_rigidity_bg" in scene.active_terms
    bg = model.mappings[0]
    assert bg.warp is None and bg.residual.linears[0].out_features == PANZOOM_MAPPING_HIDDEN
    assert model.mappings[1].kind == BG_MOTION_DEFORMABLE  # foreground mappings are never reduced
    full = built["all"][1].mappings[0]
    assert full.warp is not None and full.residual.linears[0].out_features == 64


@pytest.mark.slow
def test_scene_speed_compares_the_same_fit_with_and_without_the_analysis(tmp_path):
    """The measurement helper behind the docs' speed-up table: both fits, same steps; numbers only, no
    timing assertion (the ratio depends on the machine)."""
    from bench.scene_speed import compare_components

    s = make_named_scene("lighting_change", width=48, height=32, frames=3)
    frames_dir, _ = _write_clip(tmp_path / "clip", np.repeat(s.frames[:1], 3, axis=0))
    res = compare_components(frames_dir, [], tmp_path / "runs", steps=10, long_edge=48)
    assert res["auto"]["background_motion"] == BG_MOTION_STATIC
    assert res["all"]["background_motion"] == BG_MOTION_DEFORMABLE
    assert len(res["auto"]["active_terms"]) < len(res["all"]["active_terms"])
    assert np.isfinite(res["speedup"]) and res["speedup"] > 0
    assert all(np.isfinite(res[c]["psnr"]) for c in ("auto", "all"))


def test_textureless_clip_is_deformable_because_nothing_can_be_measured():
    """The MIN_VECTORS guard: flat frames give no reliable flow; the analysis says so and keeps the full
    mapping (the safe choice) instead of calling an unmeasured camera static."""
    frames = np.broadcast_to(np.array([0.3, 0.55, 0.7], np.float32), (3, 24, 32, 3)).copy()
    flow = compute_flow(frames, DISFlow("medium"))
    flow.forward_ok[:] = False  # whatever DIS returns on a flat image, nothing is reliable
    scene = analyse_scene(3, flow, np.zeros((0, 3, 24, 32), bool), preset_config("draft"))
    assert scene.background_motion == BG_MOTION_DEFORMABLE and "too little" in scene.reasons["background_motion"]
    assert scene.measured["background_median_motion_px"] is None and scene.measured["pairs_measured"] == 0


def test_auto_masks_and_masks_together_is_one_line_error(tmp_path):
    s = make_named_scene("static_camera", width=48, height=32, frames=3)
    frames_dir, masks_dir = _write_clip(tmp_path / "clip", s.frames, s.masks)
    cfg = apply_overrides(preset_config("draft"), TINY)
    with pytest.raises(InputError, match="--auto-masks and --mask"):
        quiet_fit(tmp_path / "run", cfg, FitInputs(frames_dir, [masks_dir], auto_masks=True))
    assert not (tmp_path / "run").exists()
