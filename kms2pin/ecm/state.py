"""The tracker's sequence state: the last poses, the frame count and the running fit."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["RunningFit", "SequenceState"]


@dataclass
class RunningFit:
    """The main hypothesis's fit (IoU), exponentially smoothed over the frames with
    weight ``smoothing`` on the new one."""

    smoothing: float
    score: float = 0.0

    def update(self, fit: float, frame: int) -> None:
        """Fold frame ``frame``'s fit in (the first frame's is taken as it is)."""
        a = self.smoothing
        self.score = fit if frame == 0 else (1.0 - a) * self.score + a * fit

    def settled(self, frame: int) -> bool:
        """Whether the running fit has settled by ``frame``: it averages about 1 /
        smoothing frames, and before that it is mostly the first frame's, which the size
        calibration (or the initialization) fitted to that very frame.  Until then a fall
        below it says nothing of a limb, and an alternative's lead nothing of the pose."""
        return frame >= round(1.0 / self.smoothing)


@dataclass
class SequenceState:
    """Where a track stands: the last frame's pose ``q`` and the one before (``prev``,
    None: no velocity), the frame count, the running fit and, per pair of twin limbs
    (by its left joint), the last frame they crossed."""

    q: np.ndarray
    running: RunningFit
    prev: np.ndarray | None = None
    frame: int = 0
    crossed: dict[str, int] = field(default_factory=dict)

    def advance(self, q: np.ndarray, keep_velocity: bool = True) -> None:
        """Move on to the next frame from pose ``q`` (no velocity if not ``keep_velocity``)."""
        self.prev = self.q.copy() if keep_velocity else q.copy()
        self.q = q.copy()
        self.frame += 1
