"""A short fit on a real clip (``tests.paths.CLIPS``; skipped on a fresh clone without the clips).

Ten frames of blackswan at 384x216, 300 steps: typically 27.0 dB and alpha IoU 0.92 on a 2-core CPU; the
bounds leave room for machine differences. The full-length numbers are in docs/engine.md.
"""

from __future__ import annotations

import pytest

from engine.config import apply_overrides, preset_config
from engine.fit.fit_inputs import FitInputs
from tests.engine.fit_helpers import quiet_fit
from tests.paths import CLIPS, NO_CLIPS

DATA = CLIPS / "blackswan"
pytestmark = [pytest.mark.slow, pytest.mark.shared_data]


@pytest.mark.skipif(not DATA.exists(), reason=NO_CLIPS)
def test_blackswan_short_fit(tmp_path):
    cfg = apply_overrides(
        preset_config("draft"),
        {
            "steps": "300",
            "long_edge": "384",
            "bootstrap_steps": "150",
            "global_rigidity_steps": "80",
            "eval_every": "100",
        },
    )
    m = quiet_fit(tmp_path / "run", cfg, FitInputs(DATA / "frames", [DATA / "masks"], frames=(0, 9)))
    assert m["working_size"] == [384, 216] and m["frames"] == 10
    assert m["psnr"] >= PSNR_MIN
    assert m["alpha_iou"][0] >= 0.85


PSNR_MIN = 24.0
