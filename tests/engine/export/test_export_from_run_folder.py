"""``export`` works from the run folder alone: with the plate, its masks and the flow cache deleted after the fit,
it writes the same passes and atlases as an export with them that keeps the UV as fitted (``--no-follow-flow``: the
atlas textures the networks' colours, as without the plate), at the native resolution ``clip.json`` records."""

from __future__ import annotations

import io
import json
import shutil

import numpy as np
import pytest

from engine.config import apply_overrides, preset_config
from engine.data.synthetic import SceneSpec, make_scene, write_scene
from engine.errors import InputError
from engine.export.exporter import export_run
from engine.fit.fit_inputs import FitInputs
from engine.fit.fitted_run import load_fitted
from engine.io.images import read_exr, read_image
from engine.terms.export_names import PASSES_DIR, pass_file_name
from engine.terms.run_folder import FLOW_CACHE_DIR, RUN_CLIP, SCENE_FILE
from tests.engine.fit_helpers import quiet_fit

#: 96x64 fitted at 48x32: the passes (96x64) can only get their size from the run folder's record.
SPEC = SceneSpec(width=96, height=64, frames=4, fg_size=(28, 20), fg_start=(20.0, 20.0))
TINY = {"steps": "12", "batch": "300", "eval_every": "12", "bootstrap_steps": "6", "global_rigidity_steps": "3"}


def _export(run, **kw):
    return export_run(run, atlas_size=48, progress_bar=False, stream=io.StringIO(), **kw)


def test_export_without_the_plate_equals_export_with_it(tmp_path):
    frames_dir, masks_dir = write_scene(make_scene(SPEC), tmp_path / "clip")
    cfg = apply_overrides(preset_config("draft"), {**TINY, "long_edge": "48"})
    run = tmp_path / "run"
    quiet_fit(run, cfg, FitInputs(frames_dir, [masks_dir]))
    with_plate = _export(run, follow_flow=False)

    shutil.rmtree(tmp_path / "clip")  # the plate and its masks
    shutil.rmtree(run / FLOW_CACHE_DIR)
    without = _export(run)  # the flow it would follow needs the plate: a warning, the UV as fitted
    assert without.parent != with_plate.parent

    a, b = json.loads(with_plate.read_text()), json.loads(without.read_text())
    assert b["clip"]["resolution"] == [96, 64] and b["clip"]["working_resolution"] == [48, 32]
    assert {k: v for k, v in a.items() if k != "created"} == {k: v for k, v in b.items() if k != "created"}
    for frame in a["passes"]["frames"]:
        name = pass_file_name(frame)
        pa, pb = read_exr(with_plate.parent / PASSES_DIR / name), read_exr(without.parent / PASSES_DIR / name)
        assert pa.keys() == pb.keys()
        for channel in pa:
            assert pa[channel].shape == (64, 96)
            assert np.array_equal(pa[channel], pb[channel]), (name, channel)
    for layer in a["layers"]:
        atlases = [read_image(m.parent / layer["atlas_png"])[0] for m in (with_plate, without)]
        assert np.array_equal(*atlases)

    # the model comes back from the record and the checkpoint alone
    fitted = load_fitted(run)
    assert (fitted.clip.native_size, fitted.clip.working_size, fitted.clip.layers) == ((96, 64), (48, 32), 2)
    assert fitted.model.num_layers == 2 and fitted.metrics is not None


def test_export_of_a_run_without_its_records_is_one_line(tmp_path):
    frames_dir, masks_dir = write_scene(make_scene(SPEC), tmp_path / "clip")
    run = tmp_path / "run"
    cfg = apply_overrides(preset_config("draft"), TINY)
    quiet_fit(run, cfg, FitInputs(frames_dir, [masks_dir]))
    record = json.loads((run / RUN_CLIP).read_text())
    del record["layers"]
    (run / RUN_CLIP).write_text(json.dumps(record))
    with pytest.raises(InputError, match="clip record has no 'layers' — restore it"):
        _export(run)
    (run / SCENE_FILE).unlink()
    with pytest.raises(InputError):
        _export(run)
