"""The reach of the follow-flow filter on a real body (``tests.paths.CLIPS``; skipped on a fresh clone without the
clips): the first 24 frames of cows (a walking cow, legs and head; its ten tracks all on the cow) fitted short at the
working size (768x432), exported as the export chooses and with every layer held to a few frames. The cow's layer
slips against the flow, is tested on its plate, follows along whole trajectories (its texture within the guard), and
its paint follows the cow's points better than over a few frames (the full-length numbers:
docs/accuracy-vs-time.md)."""

from __future__ import annotations

import io

import pytest

from bench.paint_tracking import score_export
from bench.tracking import load_tracks
from engine.config import apply_overrides, preset_config
from engine.export import exporter
from engine.export import flow_reach as R
from engine.export.exporter import export_run
from engine.fit.fit_inputs import FitInputs
from tests.engine.fit_helpers import quiet_fit
from tests.paths import CLIPS, NO_CLIPS

DATA = CLIPS / "cows"
pytestmark = [pytest.mark.slow, pytest.mark.shared_data]


@pytest.mark.skipif(not DATA.exists(), reason=NO_CLIPS)
def test_a_walking_cow_follows_the_flow_along_whole_trajectories(tmp_path, monkeypatch):
    cfg = apply_overrides(
        preset_config("draft"),
        {"steps": "300", "bootstrap_steps": "150", "global_rigidity_steps": "80"},
    )
    run = tmp_path / "run"
    quiet_fit(run, cfg, FitInputs(DATA / "frames", [DATA / "masks"], frames=(0, 23)))
    reaches: list[R.Reach] = []
    choose = exporter.choose_reach

    def noted(*args):  # type: ignore[no-untyped-def]
        reaches.append(choose(*args))
        return reaches[-1]

    monkeypatch.setattr(exporter, "choose_reach", noted)
    chosen = export_run(run, atlas_size=512, progress_bar=False, stream=io.StringIO())
    assert reaches, "no layer slips against the flow"
    cow = reaches[-1]  # the layers are tested in order: the foreground last
    assert cow.name == R.LONG and cow.long_db > cow.short_db

    def few_frames(uv, owned, flow, _frames, _colours):  # type: ignore[no-untyped-def]
        return choose(uv, owned, flow, None)

    monkeypatch.setattr(exporter, "choose_reach", few_frames)
    short = export_run(run, atlas_size=512, progress_bar=False, stream=io.StringIO())
    tracks = load_tracks(DATA / "tracks_tapvid.npz")
    long_paint, short_paint = (score_export(m, tracks)["delta_avg"] for m in (chosen, short))
    print(f"cow: {cow.said}; paint {long_paint:.3f} against {short_paint:.3f} over a few frames")
    assert long_paint > short_paint + 0.03, (long_paint, short_paint)
