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


#: The share of the whole-job fraction the stages before training fill while no training rate is measured (a
#: new fit's reading and flow): the bar moves through the flow, and waits there for training to catch up.
PRE_TRAIN_SHARE = 0.05
#: The export that follows a fit, in seconds per reconstructed pixel of the fit (``JobClock.per_pixel``): its
#: coverage pass renders every frame at working size (as the evaluation), its passes every frame at native size
#: (``EXPORT_PASS_COST`` each: UV, alpha and STMap written as EXR), its atlas textures every texel of every layer
#: (``ATLAS_TEXEL_COST`` each: the colour network only, written as PNG and EXR); plus ``EXPORT_START_SECONDS`` to
#: start the engine and load the fit. Measured 2026-11-25 on a 2-core Xeon, no GPU (a 6-frame 96x64 synthetic
#: clip, atlas 1000, ``python -m engine export``: start-up 3.0 s, atlas 13.4 s for 2 x 10^6 texels, passes 0.7 s,
#: against 2.2e-5 s per pixel of the fit's evaluation). Rough: on that busy machine a sample's time varied tenfold
#: between calls; the export is a small part of a real fit.
EXPORT_START_SECONDS = 3.0
EXPORT_PASS_COST = 1.0
ATLAS_TEXEL_COST = 0.3


class JobClock:
    """How far a whole fit is and how long it still needs: flow, training, evaluation and the export after it.

    Each stage's seconds left come from a rate measured as it runs (flow seconds per pair; training's
    ``StepClock``, or a resumed fit's checkpoint: its training seconds per step; evaluation and export from the
    seconds per reconstructed pixel of the live PSNR's sample times their pixels). ``fraction`` is the seconds
    done over the seconds done and left (a resumed fit's training seconds count as done), never decreasing;
    before the training rate is known it is ``PRE_TRAIN_SHARE`` times the flow's own fraction.
    """

    def __init__(self) -> None:
        self.flow_done = 0.0
        self.flow_fraction = 0.0
        self.flow_left: float | None = 0.0
        self.train_done = 0.0
        self.train_left: float | None = None
        self.eval_done = 0.0
        self.eval_left: float | None = None
        self.export_left: float | None = None
        #: seconds per reconstructed pixel (timed on the live PSNR's sample); the pixels evaluation and export render
        self.per_pixel: float | None = None
        self.eval_pixels = 0
        self.export_pixels = 0
        self.atlas_texels = 0
        self._shown = 0.0

    def flow(self, seconds: float, done: int, total: int) -> float | None:
        """The flow has taken ``seconds`` for ``done`` of ``total`` pairs; the flow's seconds left."""
        self.flow_done = seconds
        self.flow_fraction = done / total if total > 0 else 1.0
        self.flow_left = (total - done) * seconds / done if done > 0 else None
        return self.flow_left

    def pixel_rate(self, seconds: float, pixels: int) -> None:
        """``pixels`` were reconstructed in ``seconds``: evaluation's and export's estimates follow (at the fastest
        rate seen)."""
        if pixels > 0 and seconds > 0:
            # the fastest seen: a call's fixed cost and a busy machine only ever slow a sample down
            rate = seconds / pixels
            self.per_pixel = rate if self.per_pixel is None else min(self.per_pixel, rate)
            if self.eval_done == 0.0:
                self.eval_left = self.eval_pixels * self.per_pixel
            work = self.eval_pixels + self.export_pixels * EXPORT_PASS_COST + self.atlas_texels * ATLAS_TEXEL_COST
            self.export_left = EXPORT_START_SECONDS + work * self.per_pixel

    def resume_from(self, fraction: float) -> None:
        """A resumed fit's bar starts where the stopped one showed it (``progress.logged_fraction``), whatever the
        rates measured in this process (a busy machine times a sample tenfold slower or faster)."""
        self._shown = max(self._shown, min(1.0, fraction))

    def train(self, done_seconds: float, left_seconds: float | None) -> None:
        self.train_done, self.train_left = done_seconds, left_seconds

    def evaluated(self, seconds: float) -> None:
        self.eval_done, self.eval_left = seconds, 0.0

    def left(self) -> float | None:
        """Seconds left in the whole job; None while a stage's cost is unknown."""
        parts = (self.flow_left, self.train_left, self.eval_left, self.export_left)
        return None if any(p is None for p in parts) else float(sum(parts))  # type: ignore[arg-type]

    def fraction(self) -> float:
        left = self.left()
        done = self.flow_done + self.train_done + self.eval_done
        now = PRE_TRAIN_SHARE * self.flow_fraction if left is None or done + left <= 0 else done / (done + left)
        self._shown = max(self._shown, min(1.0, now))
        return self._shown
