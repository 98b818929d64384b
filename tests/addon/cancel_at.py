"""Cancel an engine operator's blocking path (``execute``) at a known point of the engine's progress.

A cancel after a fixed time lands wherever a loaded machine happens to be: before the engine has started, or said
a step, or installed its SIGTERM handler, and then the result depends on the machine. Cancelling once the engine
has reported a given step lands at the same point on every machine. This module imports no bpy at import time:
the add-on's helpers are imported by tests that run without Blender too.
"""

from __future__ import annotations

from typing import Any

import pytest


def cancel_at_step(monkeypatch: pytest.MonkeyPatch, step: int) -> list[int]:
    """From now on (until ``monkeypatch`` undoes it), every engine operator's blocking path presses Cancel
    (``neural_atlas.cancel``, the panel's button) once its engine has reported ``step`` steps. Returns the list
    of the steps at which Cancel was pressed, filled as it happens."""
    import bpy
    from neural_atlas.addon.ops import driver

    pressed: list[int] = []
    show = driver.EngineJobOperator.show

    def show_then_cancel(self: Any, context: Any, job: Any) -> None:
        show(self, context, job)
        if job.state.step >= step and not job.cancelling:
            pressed.append(job.state.step)
            assert bpy.ops.neural_atlas.cancel() == {"FINISHED"}

    monkeypatch.setattr(driver.EngineJobOperator, "show", show_then_cancel)
    return pressed
