"""What a fit is fitted to, as one value: the plate, its masks, the frames, the scribbles, the colour space, the
rate and numbering, masks found from motion and the parts search. The command line, the demo, the bench and the
tests build it; ``run_plan.plan_fit`` carries it in the plan (its frames turned into the plate's positions);
``prepare_clip`` reads it; a resume's comes from its clip record (``of_record``), so the plate is read as it was
fitted."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .auto_parts import PartsRequest
    from .run_folder import ClipRecord


@dataclass(frozen=True)
class FitInputs:
    """A fit's input. ``clip``: a frame folder or movie (None: a resume's recorded one). ``masks``: a folder per
    foreground object. ``frames``: positions in the plate, first and last inclusive (None: every frame).
    ``scribbles``: strokes that split the one mask's object into layers (paper Sec. 4.4). ``auto_masks``: no masks
    given, find them from motion. ``colorspace`` / ``colour_config``: the plate's colour space and the OCIO config
    naming it (None: the config's file rules or the file type; a resume: the recorded ones). ``fps`` and
    ``start_frame``: the plate's rate where its files state none, a movie's first frame number (recorded only: they
    do not change the fit). ``parts``: split the one mask into the parts that move apart (a fit that starts)."""

    clip: str | Path | None = None
    masks: Sequence[str | Path] = ()
    frames: tuple[int, int] | None = None
    scribbles: str | Path | None = None
    auto_masks: bool = False
    colorspace: str | None = None
    colour_config: str | None = None
    fps: Fraction | None = None
    start_frame: int | None = None
    parts: PartsRequest | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "masks", tuple(self.masks))  # hashable and unchanged, whatever sequence was given

    @classmethod
    def of_record(cls, record: ClipRecord) -> FitInputs:
        """What a recorded fit was fitted to, read as it was: its recorded plate, masks, frames, scribbles, colour
        space, rate and movie numbering, not today's defaults (a resume, a reload, the export's plate)."""
        return cls(
            clip=record.source,
            masks=record.masks,
            frames=record.frame_range,
            scribbles=record.scribbles,
            colorspace=record.colorspace,
            colour_config=record.colour_config,
            fps=record.exact_rate,
            start_frame=record.movie_start,
        )

    @property
    def plate(self) -> str | Path:
        """The clip, which a fit that reads the plate has (a resume's comes from ``of_record``)."""
        if self.clip is None:
            raise ValueError("FitInputs without a clip: a resume's inputs come from FitInputs.of_record")
        return self.clip


__all__ = ["FitInputs"]
