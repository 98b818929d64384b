"""Suite-wide set-up. ``bash run.sh test`` runs the suite on every core (pytest-xdist): each worker, and the
engine processes its tests start, gets its share of the CPU threads, so the workers' torch pools do not fight over
the same cores (two pools spinning on two cores run slower than one)."""

from __future__ import annotations

import os
import sys


def _share_the_cores() -> None:
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers <= 1:
        return
    share = str(max(1, (os.cpu_count() or 1) // workers))
    for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):  # read by torch when it starts, here or in a child
        os.environ.setdefault(name, share)
    torch = sys.modules.get("torch")
    if torch is not None:  # already started (a plugin imported it): its pool is sized now
        torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))


_share_the_cores()
