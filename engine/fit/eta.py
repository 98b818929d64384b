"""Time left in a fit, from the steps run so far, aware of the fit's two cost regimes.

A step costs more while the global-rigidity term is on (two more mapping passes per layer, the first
``global_rigidity_steps``) than after; averaging over all steps so far therefore overestimates the time
left once that term is off. The first step after a start or a resume is left out of the rates (allocator, kernels).
"""

from __future__ import annotations


class StepClock:
    """Seconds per step since the fit started (or resumed), per regime; ``eta`` extrapolates each regime at its
    own rate.

    A regime not reached yet costs the other one's rate times ``late_ratio`` (late / early seconds per step,
    measured before training by ``trainer.regime_cost_ratio``), or the other one's rate when there is no
    measurement (without it the ETA of a fit still in the costlier regime runs high).
    """

    def __init__(self, boundary: int, late_ratio: float | None = None) -> None:
        self.boundary = boundary
        # a ratio only scales a measured rate: a non-positive or non-finite one would make the ETA meaningless
        ok = late_ratio is not None and 0.0 < late_ratio < float("inf")
        self.late_ratio = late_ratio if ok else None
        self.seconds = [0.0, 0.0]
        self.steps = [0, 0]
        self._warm = False

    def add(self, step: int, seconds: float) -> None:
        """Record that step ``step`` (0-based) took ``seconds``."""
        if not self._warm:
            self._warm = True
            return
        regime = 0 if step < self.boundary else 1
        self.seconds[regime] += seconds
        self.steps[regime] += 1

    def rate(self, regime: int) -> float | None:
        own = self.seconds[regime] / self.steps[regime] if self.steps[regime] else None
        if own is not None:
            return own
        other = self.seconds[1 - regime] / self.steps[1 - regime] if self.steps[1 - regime] else None
        if other is None or self.late_ratio is None:
            return other
        return other * self.late_ratio if regime == 1 else other / self.late_ratio

    def eta(self, next_step: int, total: int) -> float | None:
        """Seconds for steps ``next_step`` .. ``total - 1``; None before any rate is known."""
        early, late = self.rate(0), self.rate(1)
        if early is None or late is None:
            return None
        split = min(max(self.boundary, next_step), total)
        return max(0, split - next_step) * early + max(0, total - split) * late


__all__ = ["StepClock"]
