"""``export --follow-flow`` (the default): a layer's UV averaged along the flow (engine/export/follow_flow.py), on
arrays whose answer is known, then through real exports of a tiny fit, whole and staged."""

from __future__ import annotations

import io
import json
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from engine import contract as C
from engine.data.flow import DISFlow, FlowField, _save_cache
from engine.errors import InputError
from engine.export import exporter
from engine.export import follow_flow as FF
from engine.export.manifest import Manifest
from engine.export.staging import FOLLOW_FLOW_DIR
from engine.terms.cli import EXPORT_FOLLOW_FLOW_FLAG, EXPORT_STAGES
from engine.terms.run_folder import FLOW_CACHE_DIR, RUN_CLIP
from tests.engine.export.tiny_run import SPEC, export, make_run
from tests.folders import tree_digest

T, H, W = 8, 40, 56
SPEED = np.array([1.5, -0.5], np.float32)  # px per frame
UV_PER_PX = 0.01


def _flow(ok: bool = True) -> FlowField:
    """A whole-frame translation by SPEED: forward carries frame t to t+1, backward t+1 to t."""
    fwd = np.broadcast_to(SPEED, (T - 1, H, W, 2)).astype(np.float32)
    oks = np.full((T - 1, H, W), ok)
    return FlowField(fwd, -fwd, oks, oks.copy(), "dis-medium", 1.0)


def _true_uv() -> np.ndarray:
    """The UV of an ideal atlas of that translation: a point keeps its UV in every frame."""
    gy, gx = np.mgrid[0:H, 0:W].astype(np.float32)
    t = np.arange(T, dtype=np.float32)[:, None, None]
    return np.stack((gx[None] - SPEED[0] * t, gy[None] - SPEED[1] * t), -1) * UV_PER_PX


def _drifted(truth: np.ndarray) -> np.ndarray:
    """The UV of a mapping too smooth to follow the body: each frame's off by a shift growing by 1 px a frame."""
    drift_px = np.zeros((T, 1, 1, 2), np.float32)
    drift_px[:, 0, 0, 0] = np.arange(T, dtype=np.float32)
    return truth + drift_px * UV_PER_PX


def _inner() -> np.ndarray:
    """Owned pixels away from the frame's edge (a lookup there lands outside the frame in some frame)."""
    owned = np.zeros((T, H, W), bool)
    owned[:, 6:-6, 14:-14] = True
    return owned


@pytest.mark.parametrize(("weight", "fill"), [(FF.SHORT_WEIGHT, False), (FF.LONG_WEIGHT, True), (0.9, True)])
def test_each_frame_of_a_trajectory_weighs_w_to_the_distance_normalised_over_the_trajectory(weight, fill):
    """Still flow, every pixel carried: a pixel's result is sum_s w^|t-s| u_s / sum_s w^|t-s| exactly, so neither end
    of the clip weighs more than its place says (a plain recursive filter would leave w^t on frame 0)."""
    shape = (T, H, W)
    still = np.zeros((T - 1, H, W, 2), np.float32)
    oks = np.ones((T - 1, H, W), bool)
    flow = FlowField(still, still.copy(), oks, oks.copy(), "dis-medium", 1.0)
    u_t = np.array([0.0, 3.0, -1.0, 7.0, 2.0, 2.0, 10.0, -4.0], np.float32)[:T]
    uv = np.broadcast_to(u_t[:, None, None, None], (*shape, 2)).astype(np.float32)
    out = uv + FF.follow_flow(uv, np.ones(shape, bool), flow, weight, fill)
    k = np.abs(np.arange(T)[:, None] - np.arange(T)[None, :])
    expected = (weight**k * u_t[None, :]).sum(1) / (weight**k).sum(1)
    np.testing.assert_allclose(out[:, H // 2, W // 2, 0], expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(out[..., 1], out[..., 0], rtol=1e-6)


def test_uv_that_follows_the_flow_is_judged_still_and_left_alone():
    uv, owned = _true_uv(), _inner()
    assert FF.layer_slip_px(uv, owned, _flow()) == pytest.approx(0.0, abs=1e-3)
    assert np.abs(FF.follow_flow(uv, owned, _flow())).max() < 1e-5


def test_per_frame_jitter_is_measured_in_pixels_and_mostly_averaged_away():
    """Each frame's UV off by a random shift (the slip of a mapping too smooth to follow the body): the slip is
    the frame-to-frame difference in pixels, and the filtered UV keeps under half of that frame-to-frame change."""
    rng = np.random.default_rng(0)
    jitter_px = rng.normal(0.0, 2.0, (T, 1, 1, 2)).astype(np.float32)
    truth, owned = _true_uv(), _inner()
    uv = truth + jitter_px * UV_PER_PX
    steps = np.linalg.norm(np.diff(jitter_px[:, 0, 0], axis=0), axis=-1)
    assert FF.layer_slip_px(uv, owned, _flow()) == pytest.approx(float(np.median(steps)), rel=0.02)
    out = uv + FF.follow_flow(uv, owned, _flow())

    def per_frame_error_px(field: np.ndarray) -> np.ndarray:  # [T, 2]: each frame's mean UV error, in pixels
        return np.stack([(field[t] - truth[t])[owned[t]].mean(0) for t in range(T)]) / UV_PER_PX

    before, after = per_frame_error_px(uv), per_frame_error_px(out)
    # a shift common to every frame is the atlas's own gauge, not a slip: the slip is what changes between frames
    assert np.abs(np.diff(after, axis=0)).mean() < 0.5 * np.abs(np.diff(before, axis=0)).mean()


def test_a_slow_drift_is_removed_along_the_whole_clip():
    """Each frame's UV off by a shift that grows by 1 px a frame (a mapping too smooth to follow the body drifts, it
    does not only jitter): along whole trajectories a point keeps nearly one UV, so the frame-to-frame drift left is
    a small share of what it was; over a few frames most of it stays."""
    truth, owned = _true_uv(), _inner()
    uv = _drifted(truth)

    def drift_left(weight: float, fill: bool) -> float:
        out = uv + FF.follow_flow(uv, owned, _flow(), weight, fill)
        per_frame = np.stack([(out[t] - truth[t])[owned[t]].mean(0) for t in range(T)]) / UV_PER_PX
        return float(np.abs(np.diff(per_frame, axis=0)).mean())

    assert drift_left(FF.LONG_WEIGHT, True) < 0.05  # of 1 px a frame
    assert drift_left(FF.SHORT_WEIGHT, False) > 0.3


def test_where_the_flow_cannot_carry_a_pixel_it_takes_its_carried_neighbours_correction():
    """A band of pixels whose flow failed its check in the middle frame (an occlusion): it is not carried there, so
    without the fill it would start again from its drifted fitted UV and pass that drift on; with it, the band keeps
    the correction of the pixels around it, and the frames after it keep theirs."""
    truth, owned = _true_uv(), _inner()
    uv = _drifted(truth)
    flow = _flow()
    band = np.zeros((H, W), bool)
    band[:, 24:30] = True
    for ok in (flow.forward_ok, flow.backward_ok):
        ok[3][band] = False
    out = uv + FF.follow_flow(uv, owned, flow, FF.LONG_WEIGHT, fill=True)
    err = np.linalg.norm(out - truth, axis=-1) / UV_PER_PX  # px
    inside, around = band[None] & owned, ~band[None] & owned
    for t in range(T):
        assert err[t][inside[t]].mean() < err[t][around[t]].mean() + 0.35, t
    # without the fill the band starts again from its drifted UV and keeps that drift
    bare = uv + FF.follow_flow(uv, owned, flow, FF.LONG_WEIGHT, fill=False)
    bare_err = np.linalg.norm(bare - truth, axis=-1) / UV_PER_PX
    assert bare_err[4][inside[4]].mean() > err[4][inside[4]].mean() + 0.5


def test_pixels_the_layer_does_not_own_are_untouched_and_never_mixed_in():
    """UV outside the layer is garbage (another layer's, or nothing's): the correction there is exactly zero and
    no garbage reaches the owned pixels through a bilinear read at the outline."""
    uv, owned = _true_uv(), _inner()
    uv[~owned] = 1e6
    corr = FF.follow_flow(uv, owned, _flow())
    assert np.all(corr[~owned] == 0.0)
    assert np.abs(corr[owned]).max() < 1e-4


def test_the_correction_is_carried_past_the_outline_from_the_nearest_owned_pixel():
    """The export upsamples the correction bilinearly: a native pixel on the outline reads working pixels outside the
    layer too, and must read the correction of the layer's nearest pixel there, not zero (a UV halfway between the
    fitted and the followed one repeats a point's UV well inside it: paint shown twice)."""
    owned = np.zeros((3, 5, 6), bool)
    owned[0, 1:3, 2:4] = True  # a block
    owned[2] = True  # a frame the layer owns whole; frame 1 owns nothing
    corr = np.zeros((3, 5, 6, 2), np.float32)
    corr[0, 1:3, 2:4] = np.arange(8, dtype=np.float32).reshape(2, 2, 2) + 1.0
    corr[2] = 7.0
    before = corr.copy()
    out = FF.extended(corr, owned)
    assert np.array_equal(out[owned], before[owned])  # what the filter gave the layer's pixels is kept
    assert np.array_equal(out[0, 0, 0], before[0, 1, 2]) and np.array_equal(out[0, 4, 5], before[0, 2, 3])
    assert np.array_equal(out[0, 1, 0], before[0, 1, 2]) and np.array_equal(out[0, 2, 5], before[0, 2, 3])
    assert np.all(out[1] == 0.0) and np.all(out[2] == 7.0)
    assert out is corr  # in place: it is as large as the layer's UV


def test_flow_that_failed_its_check_is_not_followed():
    rng = np.random.default_rng(1)
    uv = _true_uv() + rng.normal(0.0, 0.02, (T, 1, 1, 2)).astype(np.float32)
    owned = _inner()
    assert FF.layer_slip_px(uv, owned, _flow(ok=False)) is None
    assert np.all(FF.follow_flow(uv, owned, _flow(ok=False)) == 0.0)


def test_weight_zero_a_single_frame_or_nothing_owned_change_nothing():
    uv, owned = _true_uv(), _inner()
    assert np.all(FF.follow_flow(uv, owned, _flow(), weight=0.0) == 0.0)
    assert np.all(FF.follow_flow(uv[:1], owned[:1], _flow()) == 0.0)
    none = np.zeros_like(owned)
    assert np.all(FF.follow_flow(uv, none, _flow()) == 0.0)
    assert FF.layer_slip_px(uv, none, _flow()) is None
    with pytest.raises(ValueError, match="weight"):
        FF.follow_flow(uv, owned, _flow(), weight=1.0)


def test_uv_scale_per_pixel_and_its_guards():
    uv, owned = _true_uv(), _inner()
    assert FF.uv_per_px(uv[0], owned[0]) == pytest.approx(UV_PER_PX, rel=1e-4)
    assert FF.uv_per_px(uv[0], np.zeros((H, W), bool)) is None
    assert FF.uv_per_px(np.zeros_like(uv[0]), owned[0]) == FF.MIN_UV_PER_PX  # a collapsed map: no division by 0


class _Said:
    """A reporter that keeps each stage message."""

    def __init__(self) -> None:
        self.messages: list[str] = []

    def emit(self, _event: str, **fields: object) -> None:
        self.messages.append(str(fields["message"]))


def test_the_parts_of_one_object_are_left_as_fitted_unless_the_export_insists():
    rng = np.random.default_rng(0)
    uv = _true_uv() + rng.normal(0, 0.8 * UV_PER_PX, (T, H, W, 2)).astype(np.float32)  # slips ~1 px a frame
    owned = _inner()
    working = SimpleNamespace(uv={0: uv, 1: uv, 2: uv}, owned={0: owned, 1: owned, 2: owned})
    job = SimpleNamespace(reporter=_Said())
    names = ["Background", "Foreground1", "Foreground2"]
    parts = exporter.split_parts(scribbled=True, insisted=None, layers=3)
    assert parts == {1, 2}
    out = exporter._flow_corrections(job, names, _flow(), working, parts)
    assert set(out) == {0}  # the background follows, the parts do not
    assert job.reporter.messages[0].endswith("following the flow over a few frames")  # no plate given: not tested
    for message in job.reporter.messages[1:]:
        assert "a part of one object: --follow-flow follows it" in message and message.endswith("left as fitted")
    # insisted on, or no scribbles: every layer over the gate follows
    assert exporter.split_parts(scribbled=True, insisted=True, layers=3) == frozenset()
    assert exporter.split_parts(scribbled=False, insisted=None, layers=3) == frozenset()
    assert set(exporter._flow_corrections(SimpleNamespace(reporter=_Said()), names, _flow(), working)) == {0, 1, 2}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    _, _, run = make_run(tmp_path_factory.mktemp("follow_flow"))
    return run


def _moved(plain: Manifest, followed: Manifest) -> list[float]:
    """How far each layer's UV moved between two exports, at most over every frame; their alphas are equal."""
    moved = [0.0] * len(plain.layers)
    for number in plain.frames:
        for i, (la, lb) in enumerate(zip(plain.read_passes(number), followed.read_passes(number), strict=True)):
            assert np.array_equal(la.alpha, lb.alpha)
            moved[i] = max(moved[i], float(np.abs(la.uv - lb.uv).max()))
    return moved


@pytest.mark.slow
def test_the_export_follows_the_flow_layer_by_layer(tiny, monkeypatch):
    """The wiring, the gate open (``_gate_open``): a layer that owns pixels has its UV moved, one that owns none is
    the plain export's bit for bit; every alpha is the plain export's; the manifest says which layers follow. (What
    it does to paint: the bench's paint table.)"""
    plain = Manifest(export(tiny, follow_flow=False))
    _gate_open(monkeypatch, owned_alpha=0.5)  # the background owns every pixel, the foreground none
    only_background = Manifest(export(tiny, follow_flow=True))
    background, foreground = _moved(plain, only_background)
    assert background > 0.0 and foreground == 0.0
    assert [layer["follows_flow"] for layer in only_background.layers] == [True, False]
    _gate_open(monkeypatch)
    both = Manifest(export(tiny, follow_flow=True))
    assert min(_moved(plain, both)) > 0.0 and all(layer["follows_flow"] for layer in both.layers)


def _gate_open(monkeypatch, owned_alpha: float = 0.4) -> None:
    """The tiny fit's foreground weight is about 0.42 everywhere (the background's 0.58): with the gate at 0 and the
    ownership threshold below both, each layer owns the frame and is filtered; at 0.5 only the background is."""
    monkeypatch.setattr(exporter, "MIN_SLIP_PX", 0.0)
    monkeypatch.setattr(exporter, "OWNED_ALPHA", owned_alpha)


@pytest.mark.slow
def test_a_staged_export_follows_the_flow_as_a_whole_export_does(tiny, tmp_path, monkeypatch):
    """The atlases stage computes the corrections and stages them; each passes chunk reads its frames of them; the
    published version equals a whole export of the same run byte for byte (the manifest's creation time apart),
    without the staged corrections, and its manifest says which layer follows the flow."""
    _gate_open(monkeypatch)
    run = shutil.copytree(tiny, tmp_path / "run", ignore=shutil.ignore_patterns(C.EXPORTS_DIR))
    whole = Path(export(run)).parent
    atlases, passes, publish = EXPORT_STAGES
    chunks = export(run, into="v002", stage=atlases)
    assert sorted(p.name for p in (chunks / FOLLOW_FLOW_DIR).iterdir()) == ["0.npy", "1.npy"]
    for frames in ((0, 1), (2, 3)):
        export(run, into="v002", stage=passes, frames=frames)
    staged = Path(export(run, into="v002", stage=publish)).parent
    a, b = tree_digest(whole), tree_digest(staged)
    assert sorted(a) == sorted(b) and {n for n in a if a[n] != b[n]} <= {C.MANIFEST_NAME}  # same second: equal too
    ma, mb = (json.loads((d / C.MANIFEST_NAME).read_text()) for d in (whole, staged))
    ma.pop("created"), mb.pop("created")
    assert ma == mb and [layer["follows_flow"] for layer in mb["layers"]] == [True, True]
    plain = Manifest(export(run, follow_flow=False))
    assert not any(layer["follows_flow"] for layer in plain.data["layers"])
    assert not np.array_equal(plain.read_passes(0)[1].uv, Manifest(staged / C.MANIFEST_NAME).read_passes(0)[1].uv)


@pytest.mark.slow
def test_a_stage_asked_otherwise_than_its_atlases_stage_is_refused_in_one_line(tiny, tmp_path):
    run = shutil.copytree(tiny, tmp_path / "run", ignore=shutil.ignore_patterns(C.EXPORTS_DIR))
    atlases, passes, publish = EXPORT_STAGES
    export(run, into="v001", stage=atlases, follow_flow=False)
    for stage in (atlases, passes, publish):
        with pytest.raises(
            InputError, match=f"v001 is staged not following the flow, not as {EXPORT_FOLLOW_FLOW_FLAG}"
        ):
            export(run, into="v001", stage=stage, follow_flow=True)
    export(run, into="v001", stage=passes)  # asked nothing: it follows the record
    manifest = Manifest(export(run, into="v001", stage=publish))
    assert not any(layer["follows_flow"] for layer in manifest.data["layers"])


def _plate_gone(monkeypatch) -> None:
    """The plate the fit read cannot be read any more (moved, a drive not mounted): what the export warns of."""

    def gone(clip):  # type: ignore[no-untyped-def]
        raise InputError(Path(clip.source), "is not there", "put the plate back")

    monkeypatch.setattr(exporter, "fitted_plate", gone)


def _cached_backends(run: Path) -> dict[str, str]:
    """The flow files in a run's ``flow_cache``: key -> backend."""
    out = {}
    for path in (run / FLOW_CACHE_DIR).glob("*.npz"):
        with np.load(path) as z:
            out[path.stem] = str(z["backend"])
    return out


@pytest.mark.slow
def test_the_export_follows_its_own_flow_and_the_fits_only_where_the_plate_is_gone(tiny, tmp_path, monkeypatch, capsys):
    """The export computes the flow it follows (``FOLLOW_FLOW_PRESET``) on the plate and caches it beside the fit's,
    so a run without the fit's flow still follows; where the plate cannot be read, the fit's flow stands in; with
    neither, the UV is exported as fitted (a warning), or refused in one line when it was insisted on."""
    _gate_open(monkeypatch)
    bare = shutil.copytree(tiny, tmp_path / "run", ignore=shutil.ignore_patterns(FLOW_CACHE_DIR, C.EXPORTS_DIR))
    stream = io.StringIO()
    assert all(layer["follows_flow"] for layer in Manifest(export(bare, stream=stream)).layers)
    assert list(_cached_backends(bare).values()) == [DISFlow(FF.FOLLOW_FLOW_PRESET).name] == ["dis-fine"]
    assert f"the flow the paint follows (dis-fine, {SPEC.frames - 1} frame pairs)" in stream.getvalue()

    _plate_gone(monkeypatch)
    run = shutil.copytree(tiny, tmp_path / "with_fit_flow", ignore=shutil.ignore_patterns(C.EXPORTS_DIR))
    fits = {k for k, b in _cached_backends(run).items() if b == "dis-medium"}
    assert fits == {json.loads((run / RUN_CLIP).read_text())["flow_key"]}
    assert all(layer["follows_flow"] for layer in Manifest(export(run)).layers)  # the fit's flow, a few frames
    assert "the plate cannot be read" in capsys.readouterr().err

    with pytest.raises(InputError, match="holds no flow of this fit") as err:
        export(bare, follow_flow=True)  # no plate and, in its cache, only the export's own flow
    assert FLOW_CACHE_DIR in str(err.value) and C.EXPORT_NO_FOLLOW_FLOW_FLAG in str(err.value)
    assert not (bare / C.EXPORTS_DIR / "v002").exists()
    manifest = Manifest(export(bare))  # the default: a warning, the UV as fitted
    assert "holds no flow of this fit: the layers' UV is exported as fitted" in capsys.readouterr().err
    assert not any(layer["follows_flow"] for layer in manifest.data["layers"])


@pytest.mark.slow
def test_another_plates_flow_in_the_cache_is_never_followed(tiny, tmp_path, monkeypatch):
    """A run folder whose ``flow_cache`` also holds another plate's flow of the same shape, written later (fit A,
    ``--refit`` on B, ``--refit`` on A again; or a cache shared between shots): the export follows the flow of its
    own plate (found by the plate's content), and, where the plate is gone, the flow its clip record names, as if
    the other were not there."""
    _gate_open(monkeypatch)
    run = shutil.copytree(tiny, tmp_path / "run", ignore=shutil.ignore_patterns(C.EXPORTS_DIR))
    own = Manifest(export(run))
    assert all(layer["follows_flow"] for layer in own.layers)
    cache, record = run / FLOW_CACHE_DIR, json.loads((run / RUN_CLIP).read_text())
    with np.load(cache / f"{record['flow_key']}.npz") as z:
        shape, threshold = z["forward"].shape, float(z["threshold_px"])
    shift, trusted = np.full(shape, 3.0, np.float32), np.ones(shape[:3], bool)
    for backend in ("dis-medium", "dis-fine"):
        other = FlowField(shift, -shift, trusted, trusted.copy(), backend, threshold)
        _save_cache(cache / f"{backend[-1] * 64}.npz", other)
    assert max(_moved(own, Manifest(export(run)))) == 0.0
    _plate_gone(monkeypatch)
    fitted = Manifest(export(run))
    for path in cache.glob("*.npz"):
        if path.stem[0] in "me":
            path.unlink()
    assert max(_moved(fitted, Manifest(export(run)))) == 0.0


def test_the_memory_it_needs_and_the_memory_the_system_says_is_available(tmp_path):
    assert FF.memory_needed(70, (768, 432), 2) == 70 * 768 * 432 * (30 + 2 * 30)  # bmx-trees: 1.9 GiB
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal:       24000000 kB\nMemFree:         1000000 kB\nMemAvailable:   12000000 kB\n")
    assert FF.available_memory(str(meminfo)) == 12000000 * 1024
    meminfo.write_text("MemTotal:       24000000 kB\n")  # an old kernel: not said
    assert FF.available_memory(str(meminfo)) is None
    meminfo.write_text("MemAvailable:   lots\n")
    assert FF.available_memory(str(meminfo)) is None
    assert FF.available_memory(str(tmp_path / "absent")) is None  # not Linux


@pytest.mark.slow
def test_more_than_the_memory_available_is_exported_as_fitted_or_refused_when_insisted_on(
    tiny, tmp_path, monkeypatch, capsys
):
    """A clip long enough that following the flow would not fit in memory: the default exports the UV as fitted
    with a warning that says how much it needs; insisting is refused in one line naming the flag that works."""
    run = shutil.copytree(tiny, tmp_path / "run", ignore=shutil.ignore_patterns(C.EXPORTS_DIR))
    _gate_open(monkeypatch)
    need = FF.memory_needed(4, (48, 32), 2)
    monkeypatch.setattr(exporter, "available_memory", lambda: int(need / FF.MEMORY_SHARE) - 1)
    with pytest.raises(InputError, match=r"following the flow needs about .* GiB of memory") as err:
        export(run, follow_flow=True)
    assert "\n" not in str(err.value) and C.EXPORT_NO_FOLLOW_FLOW_FLAG in str(err.value) and str(run) in str(err.value)
    assert not (run / C.EXPORTS_DIR / "v001").exists()
    manifest = Manifest(export(run))
    assert "the layers' UV is exported as fitted" in capsys.readouterr().err
    assert not any(layer["follows_flow"] for layer in manifest.data["layers"])
    monkeypatch.setattr(exporter, "available_memory", lambda: int(need / FF.MEMORY_SHARE) + 1024)
    assert all(layer["follows_flow"] for layer in Manifest(export(run)).data["layers"])  # enough: followed
    monkeypatch.setattr(exporter, "available_memory", lambda: None)  # the system does not say: followed
    assert all(layer["follows_flow"] for layer in Manifest(export(run)).data["layers"])
