"""Where the tests find the repository and the optional real clips, defined once.

Real clips (DAVIS frames, masks and TAP-Vid tracks) are not part of the repository: tests that need them
read the folder named by ``NEURAL_ATLAS_CLIPS`` (default: ``data`` in the ``shared`` folder beside the
checkout) and skip with that reason when it is absent.
"""

from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLIPS = Path(os.environ.get("NEURAL_ATLAS_CLIPS", ROOT.parent / "shared" / "data"))
NO_CLIPS = f"the real clips ({CLIPS}) are not present"
