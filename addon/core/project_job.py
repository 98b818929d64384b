"""Land Paint on Atlases as an engine job: ``engine project-frame`` out of process, with progress and Cancel. No bpy.

The engine composites the frame paint OVER each owning layer's edit layer file and keeps the previous one in
``edits/history/``; it says each stage (read, project, write) as a progress line, then prints the files it wrote.
A cancel (SIGTERM) leaves every edit layer as it was: the engine moves the new layers into place together, only
once all are written.
"""

from __future__ import annotations

from . import engine_commands as EC
from . import engine_process as EP
from . import frame_paint as FP
from .jobs import Command, Job


class ProjectFrameJob(Job):
    """``engine project-frame MANIFEST --frame N --edit PAINT``; ``landed`` (layer -> file) once it has finished."""

    idle_text = "landing the paint…"

    def __init__(self, python: str, manifest: str, frame: int, paint: str):
        self.manifest = manifest
        self.frame = frame
        self.paint = paint
        argv = FP.project_frame_argv(python, manifest, frame, paint)
        super().__init__([Command("project-frame", argv)], FP.log_file(manifest), EC.engine_env(), keep_log=True)
        #: layer -> the edit layer file the paint landed in (empty: the paint fell on no layer)
        self.landed: dict[str, str] = {}

    def status_text(self) -> str:
        if self.cancelling:
            return self.cancel_text
        st = self.state
        if not st.total:
            return self.idle_text
        return f"{FP.LAND_LABEL} {st.step + 1}/{st.total}: {st.message or st.stage}"

    @property
    def fraction(self) -> float:
        """Stages done of all (the engine says each as it starts)."""
        st = self.state
        return min(1.0, st.step / st.total) if st.total else 0.0

    def finish(self, result: EP.JobResult) -> EP.JobResult:
        if result.status == EP.STATUS_CANCELLED:
            return EP.JobResult(
                result.status, result.returncode, "cancelled: the edit layers are as they were", result.log_path
            )
        if result.status == EP.STATUS_OK:
            self.landed = FP.landed_layers(self.state.stderr_tail)
        return result
