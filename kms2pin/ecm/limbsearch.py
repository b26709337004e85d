"""The limb search: limbs swung the other way, put back at rest, twins exchanged.

ECM descends to the nearest fit, and a limb on the wrong side of the trunk (an arm
swung back that the image shows forward), a finger folded the wrong way, or twin
limbs that took each other's images are local minima it does not leave.  When a
frame's fit falls well below the running fit, every such move (:class:`LimbMove`) is
tried: each candidate is screened by a few ECM iterations on the masks binned 2x2,
the best few are refined at full resolution, and the best is kept if its fit (IoU)
beats the frame's by :data:`GAIN`.  After twin limbs cross (side-on, one view), their
exchange is tried for a few frames even without a fall: the fit hardly falls when a
model limb follows its twin's image.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..robot import Robot
from .limbs import limb_joints, twin_limbs
from .loop import FrameECM
from .masks import Views
from .state import SequenceState

__all__ = ["GAIN", "LimbMove", "LimbSearch"]

#: a joint closer to its rest angle than this is not swung (rad)
MIN_ANGLE = np.radians(5.0)
#: the IoU a moved limb must gain to be kept
GAIN = 0.003
#: the ECM iterations (binned masks) a candidate is screened with
SCREEN_ITERATIONS = 3
#: twin limbs whose first joints come this close, or pass each other, have crossed; for
#: this many frames after, their exchange is tried
CROSS_ANGLE = np.radians(8.0)
CROSS_FRAMES = 4
#: how many of the best screened candidates of each kind are refined (a candidate that
#: has further to go screens lower); the kinds in the order they are refined on a tie
REFINED = {"swing": 2, "exchange": 1, "reset": 1}


@dataclass(frozen=True)
class LimbMove:
    """A move of the limb search: ``"swing"`` (the first joint reflected about its rest
    angle, the joints below kept or put back at rest), ``"reset"`` (the joints below the
    first put back at rest) or ``"exchange"`` (twin limbs' angles exchanged).  ``joints``:
    the limb's first joint, or the twins' (left, right); ``indices``: every q index moved."""

    kind: str
    joints: tuple[str, ...]
    indices: np.ndarray

    def flag(self) -> str:
        """How a frame reports the move."""
        if self.kind == "reset":
            return f"put the joints below '{self.joints[0]}' back at rest"
        if self.kind == "swing":
            return f"swung '{self.joints[0]}' the other way"
        return f"swapped '{self.joints[0]}' and '{self.joints[1]}'"


class LimbSearch:
    """The limb search of one track over ``robot``'s limbs (:func:`limb_joints`),
    screening and refining candidates with ``ecm``."""

    def __init__(self, robot: Robot, ecm: FrameECM):
        self.robot, self.ecm = robot, ecm
        m = robot.model
        # limb joint name -> (its q index, q indices of the revolute joints below it)
        self.limbs: dict[str, tuple[int, np.ndarray]] = {}
        for name in limb_joints(robot):
            j = m.getJointId(name)
            below = [m.joints[k].idx_q for k in m.subtrees[j][1:] if m.joints[k].nq == 1]
            self.limbs[name] = (m.joints[j].idx_q, np.array(below, dtype=int))
        self.pairs = twin_limbs(robot, list(self.limbs))

    def exchange_move(self, left: str, right: str) -> LimbMove:
        """The move that exchanges twin limbs ``left`` and ``right`` (their first joints)."""
        iq = np.concatenate([np.r_[self.limbs[n][0], self.limbs[n][1]] for n in (left, right)]).astype(int)
        return LimbMove("exchange", (left, right), iq)

    def _exchanged(self, q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
        """``q`` with the angles at q indices ``a`` and ``b`` (twin limbs) exchanged, or
        None if no angle of theirs differs by :data:`MIN_ANGLE`."""
        if np.abs(q[a] - q[b]).max() < MIN_ANGLE:
            return None
        c = q.copy()
        c[a], c[b] = q[b], q[a]
        return self.robot.clamp(c)

    def candidates(self, q: np.ndarray) -> list[tuple[LimbMove, np.ndarray]]:
        """Every move from ``q`` with its configuration: twin limbs exchanged; each limb
        put back at rest below its first joint; each limb swung the other way, once
        with the joints below kept and once with them put back at rest (an arm swung
        back over the trunk is often bent there too)."""
        rest = self.robot.q_rest
        out = []
        for left, right, a, b in self.pairs:
            c = self._exchanged(q, a, b)
            if c is not None:
                out.append((self.exchange_move(left, right), c))
        for name, (iq, below) in self.limbs.items():
            indices = np.r_[iq, below].astype(int)
            far_below = len(below) and np.abs(q[below] - rest[below]).max() >= MIN_ANGLE
            if far_below:
                c = q.copy()
                c[below] = rest[below]
                out.append((LimbMove("reset", (name,), indices), self.robot.clamp(c)))
            if abs(q[iq] - rest[iq]) < MIN_ANGLE:
                continue
            c = q.copy()
            c[iq] = 2.0 * rest[iq] - q[iq]
            swing = LimbMove("swing", (name,), indices)
            out.append((swing, self.robot.clamp(c)))
            if far_below:
                c = c.copy()
                c[below] = rest[below]
                out.append((swing, self.robot.clamp(c)))
        return out

    def search(self, q: np.ndarray, fit: float, views: Views, binned: Views | None, coarse: Views | None,
               timings: dict, screen_only: bool = False) -> tuple[np.ndarray, float, LimbMove | None]:
        """Try every candidate from ``q`` (its ``fit``), screened on the ``binned`` views:
        the best of each kind (:data:`REFINED`) refined (``coarse``: the frame's coarse
        views), the best kept if it gains :data:`GAIN`.  Returns the configuration, its
        fit and the move (None if none was kept).  ``screen_only``: the best screened
        candidate unrefined (the limb-search hypothesis's start)."""
        cands = self.candidates(q)
        if not cands or binned is None:
            return q, fit, None
        screened = []
        for move, c in cands:
            qc, _, _ = self.ecm.run(c, views, timings, SCREEN_ITERATIONS, binned, binned=True)
            screened.append((self.ecm.fit(qc, views), move, qc))
        screened.sort(key=lambda x: -x[0])
        if screen_only:
            fc, move, qc = screened[0]
            return (qc, fc, move) if fc > fit + GAIN else (q, fit, None)
        slots = dict(REFINED)
        order = list(REFINED)
        refined = []
        for s in screened:
            if slots[s[1].kind] > 0:
                slots[s[1].kind] -= 1
                refined.append((-s[0], order.index(s[1].kind), s))
        out = (q, fit, None)
        for *_, (_, move, qc) in sorted(refined, key=lambda x: x[:2]):
            qc, _, _ = self.ecm.run(qc, views, timings, coarse=coarse)
            fc = self.ecm.fit(qc, views)
            if fc > out[1] + GAIN:
                out = (qc, fc, move)
        return out

    def exchange_crossed(self, q: np.ndarray, fit: float, state: SequenceState, views: Views,
                         coarse: Callable[[], Views | None], timings: dict) -> tuple[np.ndarray, float, LimbMove | None]:
        """Try the exchange of twin limbs that crossed in the last :data:`CROSS_FRAMES`
        frames (their first joints within :data:`CROSS_ANGLE`, or passed each other since
        the last frame, recorded in ``state.crossed``); keep it if it gains :data:`GAIN`.
        Returns as :meth:`search`."""
        out = (q, fit, None)
        views_c = None
        for left, right, a, b in self.pairs:
            d, d_last = q[a[0]] - q[b[0]], state.q[a[0]] - state.q[b[0]]
            if abs(d) < CROSS_ANGLE or d * d_last < 0.0:
                state.crossed[left] = state.frame
                continue
            c = self._exchanged(q, a, b)
            if c is None or state.frame - state.crossed.get(left, -CROSS_FRAMES - 1) > CROSS_FRAMES:
                continue
            views_c = views_c if views_c is not None else coarse()
            qc, _, _ = self.ecm.run(c, views, timings, coarse=views_c)
            fc = self.ecm.fit(qc, views)
            if fc > out[1] + GAIN:
                out = (qc, fc, self.exchange_move(left, right))
        return out
