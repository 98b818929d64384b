"""``fit --auto-parts``: the one masked object split into the parts that move apart before it is trained, as
``parts`` then ``fit --scribbles`` would do it, in one command. A fit given neither ``--auto-parts`` nor
``--no-auto-parts`` does it wherever it applies (``parts_wanted``). The search runs inside ``prepare_clip`` on the
fit's own decoded frames, snapped mask and optical flow (``PartsSearch``), so it costs the analysis alone, and an
object that moves as one piece is fitted bit for bit as without it: only objects whose parts move apart are fitted
differently.

The strokes go to RUN_DIR/parts (``terms.run_folder.AUTO_PARTS_DIR``), where the artist can check them, fix them, or
delete the folder to have them found again. A folder there that already holds stroke images (an earlier fit's, or
ones the artist fixed) is the fit's scribbles as it is: it is never searched again or overwritten, and a fit that
continues (``--resume-if-started``) sees the same scribbles it recorded. An object that moves as one piece gets no
folder and is fitted as one layer, as without the flag.

A jumping body whose limb swings across it cannot be held by one smooth mapping (its paint slides where the limb
crosses the body); split into the body and the limb it is fitted as two layers (``docs/engine.md``, *Parts from
motion*).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import contract as C
from ..config import FitConfig
from ..data.flow import FlowField
from ..data.mask_files import output_folder
from ..data.motion_parts import motion_parts
from ..data.motion_parts_files import STROKE, NothingToSplit, require_something_to_split, write_strokes
from ..data.scribbles import SCRIBBLE_EXTENSIONS, NoScribbles, read_scribbles
from ..errors import InputError
from ..io.clip_info import ClipInfo
from ..terms.run_folder import FIT_AUTO_MASKS_FLAG, FIT_AUTO_PARTS_FLAG
from .progress import Reporter
from .run_folder import RunFolder

#: The start of the one stderr line that says what the search found (``bench paint-table`` reads it from the log).
SAID_PREFIX = "auto parts: "


def check_auto_parts(
    cfg: FitConfig, mask_dirs: Sequence[str | Path], scribble_dir: str | Path | None, auto_masks: bool
) -> None:
    """The flags ``--auto-parts`` cannot go with, refused in one line before anything is read: it splits exactly one
    --mask object, its strokes are the scribbles (so not beside --scribbles), and the paper model fits one
    foreground layer only."""
    flag = FIT_AUTO_PARTS_FLAG
    if scribble_dir is not None:
        raise InputError(None, f"{flag} and {C.SCRIBBLE_ARG} both given", "pass one of them")
    if auto_masks:
        raise InputError(
            None,
            f"{flag} with {FIT_AUTO_MASKS_FLAG}: the parts are found inside masks you have checked",
            f"write the masks with `{C.VERB_MASKS}` first, check them, then fit with --mask FOLDER {flag}",
        )
    if len(mask_dirs) != 1:
        raise InputError(
            None,
            f"{flag} splits one object, but {len(mask_dirs)} --mask folders were given",
            "pass exactly one --mask (the whole object)",
        )
    if cfg.model == "paper":
        raise InputError(
            None,
            f"{flag} with the paper model, which fits one background and one foreground layer",
            "use a fast preset (draft, balanced or final)",
        )


def parts_wanted(
    flag: bool | None,
    cfg: FitConfig,
    mask_dirs: Sequence[str | Path],
    scribble_dir: str | Path | None,
    auto_masks: bool,
) -> bool:
    """Whether a fit that starts splits its object into parts: ``--auto-parts`` (``flag`` True) always, after
    ``check_auto_parts`` refused what it cannot go with; ``--no-auto-parts`` never; neither (None) wherever it
    applies, silently: one --mask, no --scribbles or --auto-masks, a fast model (a clip the search cannot split,
    one frame or an empty mask, is left to ``PartsSearch.check``, which fits it as it is)."""
    if flag is None:
        return len(mask_dirs) == 1 and scribble_dir is None and not auto_masks and cfg.model != "paper"
    if flag:
        check_auto_parts(cfg, mask_dirs, scribble_dir, auto_masks)
    return flag


def strokes_in_run(run_dir: Path) -> str | None:
    """RUN_DIR/parts when it holds stroke images (an earlier ``--auto-parts``'s, or the artist's fix of them, of any
    type ``--scribbles`` reads): the scribbles the fit uses as they are; None when there are none."""
    run = RunFolder(run_dir)
    folder = run.own_folder(run.auto_parts, "strokes")
    if folder.is_dir() and any(
        p.suffix.lower() in SCRIBBLE_EXTENSIONS and not p.name.startswith(".") for p in folder.iterdir()
    ):
        return str(folder)
    return None


#: The share of a stroke colour's pixels that must lie inside the fit's mask for strokes found in RUN_DIR/parts to
#: count as this fit's: a search draws them inside the mask; an artist's fix may stray over its edge.
STROKES_INSIDE = 0.5


def is_run_strokes(run: RunFolder, scribble_dir: str | Path) -> bool:
    """Whether ``scribble_dir`` is RUN_DIR/parts, the strokes the fit found there by looking (``strokes_in_run``)."""
    return Path(scribble_dir).resolve() == run.auto_parts.resolve()


def check_run_strokes(folder: str | Path, info: ClipInfo, size: tuple[int, int], masks: np.ndarray) -> np.ndarray:
    """The strokes in RUN_DIR/parts read as ``--scribbles`` reads them (int8 [T, H, W] at the working ``size``),
    refused in one line unless they belong to this fit: at least two colours of them on its frames, each with at
    least ``STROKES_INSIDE`` of its pixels inside its mask (``masks``: bool [F, T, H, W]). Strokes an earlier fit
    left there for another object or other frames (a ``--refit`` with another mask, ``--frames`` elsewhere) are
    never fitted, nor answered as if the artist had drawn them; the line names what to do."""
    problem = None
    try:
        labels = read_scribbles(folder, info, size)
    except NoScribbles:
        labels, problem = None, "hold no stroke on this fit's frames"
    if labels is not None:
        inside = masks.any(0)
        counted = 0
        for k in range(len(C.SCRIBBLE_COLOURS)):
            drawn = labels == k
            if drawn.any() and (drawn & inside).sum() >= STROKES_INSIDE * drawn.sum():
                counted += 1
        if counted < 2:
            problem = "do not lie on this fit's mask in two colours"
    if problem is not None:
        raise InputError(
            folder,
            f"the strokes an earlier fit left here {problem} (another object, or other frames)",
            f"delete the folder to have the parts found again, or fit with {C.FIT_NO_AUTO_PARTS_FLAG}",
        )
    return labels  # type: ignore[return-value]


@dataclass(frozen=True)
class PartsRequest:
    """A fit that starts asks ``prepare_clip`` to split its one mask into the parts that move apart. ``asked``: the
    artist asked (``--auto-parts``): a clip with nothing to split (one frame, an empty mask) is refused in one line
    before anything is written, and what the search found is said either way. Otherwise (the fit's default) such a
    clip is fitted as it is, and only a split is said on stderr (the progress messages carry every finding)."""

    asked: bool


class PartsSearch:
    """The search within ``prepare_clip``, on the fit's own decoded frames, snapped mask and flow: made before
    anything is decoded (a link at RUN_DIR/parts is refused at once), checked once the mask is read, run once the
    flow is there (under the run folder's lock, which the fit holds by then)."""

    def __init__(self, request: PartsRequest, info: ClipInfo, run: RunFolder, mask_dir: str | Path) -> None:
        self.asked, self.info, self.mask_dir = request.asked, info, mask_dir
        self.shown = run.own_folder(run.auto_parts, "strokes")  # the folder as messages name it
        self.wanted = True

    def check(self, masks: np.ndarray) -> None:
        """Before anything is written: whether there is anything to split in the mask (bool [T, H, W]); asked, a
        clip with nothing to split is one line (``NothingToSplit``); by default the search is left out."""
        try:
            require_something_to_split(self.info, self.mask_dir, masks)
        except NothingToSplit:
            if self.asked:
                raise
            self.wanted = False

    def find(self, masks: np.ndarray, flow: FlowField, reporter: Reporter) -> tuple[np.ndarray, str] | None:
        """The strokes of the parts that move apart in ``masks`` (the fit's, bool [T, H, W]) along ``flow`` (its
        adjacent flow), written to RUN_DIR/parts and read back as ``--scribbles`` reads them at the working size:
        (labels, folder); None when the object moves as one piece (nothing written)."""
        if not self.wanted:
            return None
        reporter.emit(C.EVENT_STAGE, stage=C.VERB_PARTS, message=f"looking for parts that move apart ({self.shown})")
        folder = output_folder(self.info, self.shown, STROKE)
        report = write_strokes(self.info, folder, motion_parts(masks, flow))
        if report.folder is None:
            said = f"{report.result.message}: fitted as one layer"
            reporter.emit(C.EVENT_STAGE, stage=C.VERB_PARTS, message=said, **{C.STAGE_PARTS_FIELD: 0})
            if self.asked:
                print(f"{SAID_PREFIX}{said}", file=sys.stderr)
            return None
        said = f"{report.result.message} ({self.shown})"
        reporter.emit(C.EVENT_STAGE, stage=C.VERB_PARTS, message=said, **{C.STAGE_PARTS_FIELD: report.result.parts})
        print(f"{SAID_PREFIX}{said}", file=sys.stderr)
        size = (masks.shape[2], masks.shape[1])
        return read_scribbles(report.folder, self.info, size), str(Path(report.folder).resolve())


__all__ = [
    "SAID_PREFIX",
    "STROKES_INSIDE",
    "PartsRequest",
    "PartsSearch",
    "check_auto_parts",
    "check_run_strokes",
    "is_run_strokes",
    "parts_wanted",
    "strokes_in_run",
]
