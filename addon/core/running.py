"""The engine jobs running now, by the scene they run for (or the preferences, for Set up engine). No bpy here.

The modal operator that drives a job holds it; this table lets the Cancel button (another operator) reach it,
keeps a second job from starting for the same scene, and lets loading another file, unregistering or quitting
stop them all.
"""

from __future__ import annotations

from .jobs import Job

#: The key of Set up engine: one at a time, whatever the scene (it runs for the preferences).
SETUP_KEY = "Set up engine"

_RUNNING: dict[str, Job] = {}


def add(key: str, job: Job) -> None:
    if key in _RUNNING:
        raise RuntimeError(f"a job is already running for {key!r}")
    _RUNNING[key] = job


def remove(key: str) -> None:
    _RUNNING.pop(key, None)


def get(key: str) -> Job | None:
    return _RUNNING.get(key)


def is_running(key: str) -> bool:
    return key in _RUNNING


def jobs() -> dict[str, Job]:
    """A copy of the table."""
    return dict(_RUNNING)


def cancel_all() -> None:
    """Ask every running job to stop, and forget them (their modal operators end with the file)."""
    for job in list(_RUNNING.values()):
        job.cancel()
    _RUNNING.clear()
