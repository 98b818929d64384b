"""Render Edited Clip frame by frame: which frames, what their files are named, how far it is, how long it still
needs. No bpy here.

The operator renders one frame per timer tick (``compositor.RenderSession.render_step``) so Blender stays
responsive, the panel shows "frame k/n · ETA", and Cancel stops between two frames. A movie is one file that
Blender writes in one animation render (a frame cannot be appended to a movie file), so it is one step.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from ...engine import contract as C  # type: ignore[import-not-found]
from .progress import format_seconds

#: The render formats that write one file per frame (``output_template``: ``edit.1001.exr`` ..); the others write one
#: movie.
FRAME_FORMATS = ("exr", "png")
#: A movie's name before the range Blender appends (``edit_1001-1012.mp4``).
MOVIE_PREFIX = "edit_"


def output_template(clip: Mapping[str, Any]) -> str:
    """The name Render Edited Clip gives Blender for the frames of an export whose manifest clip record is ``clip``:
    ``edit.`` and one ``#`` per digit (Blender writes the frame number there, zero-padded to the count of ``#``), the
    digits ``engine render`` pads its default names to (``C.frame_padding``, one rule for both): ``edit.####`` for a
    plate ``plate.1001.png`` .., so both write ``edit.1001.exr``; ``edit.#####`` for a movie, a plate whose files are
    not named by their number padded one way, or no clip record (``{}``)."""
    padding = C.frame_padding(list(clip.get("frame_files") or ()), list(clip.get("frame_numbers") or ()))
    return C.RENDER_FRAME_PREFIX + "#" * padding


def frame_list(start: int, end: int, step: int = 1) -> list[int]:
    """The frames an animation render of ``start`` .. ``end`` every ``step`` renders (Blender's own order)."""
    return list(range(start, end + 1, max(1, step)))


def exported_only(frames: list[int], exported: tuple[int, int]) -> tuple[list[int], list[int]]:
    """(the ``frames`` the export has passes for: ``exported`` is its first and last frame, contiguous; the others).
    A frame outside the export has no passes: Blender would show the nearest exported frame's passes there (the paint
    frozen where it was), so only the exported frames are rendered."""
    first, last = exported
    inside = [f for f in frames if first <= f <= last]
    return inside, [f for f in frames if not first <= f <= last]


def spans(frames: list[int]) -> str:
    """``1-2, 6-8``: the frames as runs of consecutive numbers."""
    runs: list[list[int]] = []
    for f in sorted(frames):
        if runs and f == runs[-1][1] + 1:
            runs[-1][1] = f
        else:
            runs.append([f, f])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


def outside_note(skipped: list[int], exported: tuple[int, int]) -> str:
    """What the render says of the scene frames it left out ('' when none)."""
    if not skipped:
        return ""
    return (
        f"scene frame(s) {spans(skipped)} not rendered: the export has passes for frames {exported[0]}-{exported[1]} "
        "only (export more frames to render them)"
    )


def no_exported_frames(scene_range: tuple[int, int], exported: tuple[int, int]) -> str:
    """The refusal when the scene's range holds none of the exported frames."""
    return (
        f"The scene's range {scene_range[0]}-{scene_range[1]} holds none of the exported frames "
        f"{exported[0]}-{exported[1]}: set the range inside them (Import Atlas with Set Scene Range does)"
    )


def steps_for(file_format: str, frames: list[int]) -> list[int | None]:
    """The render's steps: one per frame for an image sequence, one (None: the whole movie) for a movie."""
    return list(frames) if file_format in FRAME_FORMATS else [None]


@dataclass
class RenderProgress:
    """How far a render is: steps done of the total, and the seconds each took (the ETA's rate)."""

    total: int
    done: int = 0
    seconds: list[float] = field(default_factory=list)
    #: True for a movie: one step that renders every frame
    movie: bool = False
    frames: int = 0
    cancelled: bool = False
    #: What the report adds (``outside_note``: scene frames left out); '' for nothing
    note: str = ""

    @property
    def fraction(self) -> float:
        return min(1.0, self.done / self.total) if self.total > 0 else 0.0

    @property
    def finished(self) -> bool:
        return self.done >= self.total

    def add(self, seconds: float) -> None:
        """One step done in ``seconds``."""
        self.done += 1
        self.seconds.append(float(seconds))

    def eta(self) -> float | None:
        """Seconds for the steps left, at the mean rate of the steps so far (None before the first)."""
        if not self.seconds:
            return None
        return (self.total - self.done) * (sum(self.seconds) / len(self.seconds))

    def summary(self) -> str:
        """The panel's line: ``frame 3/12 · ETA 9s``; a movie: what it is doing in its one step."""
        if self.movie:
            return f"rendering the movie ({self.frames} frames) in one go…" if not self.finished else "movie done"
        text = f"frame {self.done}/{self.total}"
        eta = self.eta()
        if eta is not None and not self.finished:
            text += f" · ETA {format_seconds(eta)}"
        return text

    def report(self, out_dir: str) -> str:
        """The line the operator reports at the end: what was written, and for a cancel that the frames stay."""
        if self.movie:
            line = f"rendered the movie to {out_dir}"
        elif self.cancelled:
            line = f"render cancelled after {self.done}/{self.total} frames; the finished frames stay in {out_dir}"
        else:
            line = f"rendered {self.done} frame(s) to {out_dir}"
        return f"{line}; {self.note}" if self.note else line
