"""``fit --auto-parts``: the one masked object split into the parts that move apart before it is fitted, as
``parts`` then ``fit --scribbles`` would do it, in one command.

The strokes go to RUN_DIR/parts (``contract.AUTO_PARTS_DIR``), where the artist can check them, fix them, or
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
from collections.abc import Callable
from pathlib import Path

from .. import contract as C
from ..config import FitConfig
from ..errors import InputError
from .run_folder import RunFolder

#: What the run folder's lock names while the strokes are written.
LOCK_HOLDER = f"fit {C.FIT_AUTO_PARTS_FLAG}"
#: The start of the one stderr line that says what the search found (``bench paint-table`` reads it from the log).
SAID_PREFIX = "auto parts: "


def check_auto_parts(cfg: FitConfig, mask_dirs: list[str | Path], scribble_dir: str | None, auto_masks: bool) -> None:
    """The flags ``--auto-parts`` cannot go with, refused in one line before anything is read: it splits exactly one
    --mask object, its strokes are the scribbles (so not beside --scribbles), and the paper model fits one
    foreground layer only."""
    flag = C.FIT_AUTO_PARTS_FLAG
    if scribble_dir is not None:
        raise InputError(None, f"{flag} and {C.SCRIBBLE_ARG} both given", "pass one of them")
    if auto_masks:
        raise InputError(
            None,
            f"{flag} with {C.FIT_AUTO_MASKS_FLAG}: the parts are found inside masks you have checked",
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


def strokes_in_run(run_dir: Path) -> str | None:
    """RUN_DIR/parts when it holds stroke images (an earlier ``--auto-parts``'s, or the artist's fix of them): the
    scribbles the fit uses as they are; None when there are none."""
    run = RunFolder(run_dir)
    folder = run.own_folder(run.auto_parts, "strokes")
    if folder.is_dir() and any(p.suffix.lower() == ".png" and not p.name.startswith(".") for p in folder.iterdir()):
        return str(folder)
    return None


def find_parts(
    clip: str,
    mask_dir: str | Path,
    run_dir: Path,
    cfg: FitConfig,
    frame_range: tuple[int, int] | None,
    colorspace: str | None,
    say: Callable[[str], None],
) -> str | None:
    """Find the parts of the object in ``mask_dir`` that move apart (``motion_parts_files.write_motion_parts``) and
    write their strokes to RUN_DIR/parts, under the run folder's lock; the folder, or None when the object moves as
    one piece (nothing written). The analysis runs at the fit's working size, mask snap and flow (``cfg``), and
    its flow goes to the run's cache, where the fit finds it. ``say`` gets the progress; the result is one line on
    stderr, as ``--auto-masks`` says what it found."""
    from ..data.motion_parts_files import write_motion_parts

    run = RunFolder(run_dir)
    shown = run.own_folder(run.auto_parts, "strokes")
    say(f"looking for parts that move apart; strokes go to {shown}")
    existed = run.path.exists()
    try:
        with run.lock(LOCK_HOLDER):
            report = write_motion_parts(
                clip, mask_dir, shown, frame_range, colorspace, say=say, fit=cfg, flow_cache=run.flow_cache
            )
    except InputError:  # bad input (read before anything is written) leaves no run folder behind, as for a fit
        if not existed:
            _remove_lock_only(run.path)
        raise
    if report.folder is None:
        print(f"{SAID_PREFIX}{report.result.message}: fitted as one layer", file=sys.stderr)
        return None
    print(f"{SAID_PREFIX}{report.result.message} ({shown})", file=sys.stderr)
    return report.folder


def _remove_lock_only(folder: Path) -> None:
    """Remove ``folder`` when all it holds is the lock file the refused command created with it."""
    entries = list(folder.iterdir()) if folder.is_dir() else None
    if entries is not None and [e.name for e in entries] == [C.RUN_LOCK]:
        (folder / C.RUN_LOCK).unlink()
        folder.rmdir()


__all__ = ["LOCK_HOLDER", "check_auto_parts", "find_parts", "strokes_in_run"]
