"""The table of running jobs (``core.running``): one per key, reachable for Cancel, all stopped at once."""

from __future__ import annotations

import pytest
from neural_atlas.addon.core import running
from neural_atlas.addon.core.jobs import Job


class _Job(Job):
    """A job that only records whether it was cancelled."""

    def __init__(self):
        super().__init__([], "unused.log")
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True


def test_one_job_per_key_and_cancel_all():
    a, b = _Job(), _Job()
    running.add("Scene", a)
    try:
        with pytest.raises(RuntimeError, match="already running"):
            running.add("Scene", b)
        running.add("Other", b)
        assert running.is_running("Scene") and running.get("Other") is b and set(running.jobs()) == {"Scene", "Other"}
        running.remove("Other")
        assert not running.is_running("Other") and running.get("Other") is None
    finally:
        running.cancel_all()
    assert a.cancelled and not b.cancelled and running.jobs() == {}
