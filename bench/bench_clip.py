"""A clip the bench fits: its frames, the masks it is fitted with, its TAP-Vid tracks and the precise masks its
decomposition is scored against, found from a clip folder or a frame folder (``resolve_clip``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from engine.errors import InputError

#: A clip folder's ground-truth tracks.
TRACKS_FILE = "tracks_tapvid.npz"


@dataclass
class BenchClip:
    name: str
    frames: Path
    masks: list[Path]
    tracks: Path | None
    #: Precise masks the decomposition is scored against (``fg_iou``); empty: not scored.
    score_masks: list[Path] = field(default_factory=list)


def resolve_clip(
    path: str | Path,
    masks: list[str | Path] | None = None,
    tracks: str | Path | None = None,
    score_masks: list[str | Path] | None = None,
) -> BenchClip:
    """A clip given as ``<clip>/`` with ``frames/``, ``masks/`` and maybe ``tracks_tapvid.npz`` inside (a clip
    folder), or as a frame folder whose masks come from ``masks`` (tracks then default to
    ``tracks_tapvid.npz`` beside the frame folder). The decomposition is scored against ``score_masks``, by
    default against a clip folder's own ``masks/`` (also when the fit is given other masks)."""
    p = Path(path).expanduser().resolve()
    if not p.is_dir():
        raise InputError(p, "is not a folder", "pass a frame folder, or a clip folder holding frames/ and masks/")
    if (p / "frames").is_dir():
        frames, name, home = p / "frames", p.name, p
        mask_dirs = [Path(m) for m in masks] if masks else ([p / "masks"] if (p / "masks").is_dir() else [])
    else:
        frames, home = p, p.parent
        name = p.parent.name if p.name == "frames" else p.name
        mask_dirs = [Path(m) for m in masks or []]
    if tracks is None and (home / TRACKS_FILE).is_file():
        tracks = home / TRACKS_FILE
    if score_masks:
        score = [Path(m) for m in score_masks]
    else:
        score = [p / "masks"] if (p / "frames").is_dir() and (p / "masks").is_dir() else []
    return BenchClip(name, frames, mask_dirs, Path(tracks) if tracks else None, score)


__all__ = ["TRACKS_FILE", "BenchClip", "resolve_clip"]
