"""What decides a motion scene: its kind, its size and length, its texture seed and the camera's pan. The same
``MotionSpec`` always gives the same pixels (``bench.motion_scenes`` renders it)."""

from __future__ import annotations

from dataclasses import dataclass

TURNING = "turning"
DEFORMING = "deforming"
SMALL_FAST = "small_fast"
THIN = "thin"
TURNING_DEPTH = "turning_depth"
LIMBS_JUMP = "limbs_jump"
KINDS: tuple[str, ...] = (TURNING, DEFORMING, SMALL_FAST, THIN, TURNING_DEPTH, LIMBS_JUMP)
#: Real-clip scale: the ``clips`` bench fits one of these in a few minutes with ``draft``.
DEFAULT_SIZE = (480, 272)
DEFAULT_FRAMES = 36
#: Camera pan, px per frame (x, y): frame t shows the plate shifted by t * PAN.
PAN = (1.0, 0.3)


@dataclass(frozen=True)
class MotionSpec:
    """Everything that decides a motion scene (the same spec always gives the same pixels). Object sizes scale
    with the frame; speeds, the bend amplitude and the bar width are in pixels whatever the size."""

    kind: str
    width: int = DEFAULT_SIZE[0]
    height: int = DEFAULT_SIZE[1]
    frames: int = DEFAULT_FRAMES
    seed: int = 0
    pan: tuple[float, float] = PAN

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown motion scene {self.kind!r}; known: {', '.join(KINDS)}")
        if self.width < 16 or self.height < 16 or self.frames < 2:
            raise ValueError(f"a motion scene needs at least 16x16 pixels and 2 frames: {self}")
