"""The limb search: limbs swung the other way, put back at rest, twins exchanged.

ECM descends to the nearest fit, and a limb on the wrong side of the trunk (an arm
swung back that the image shows forward), a finger folded the wrong way, or twin
limbs that took each other's images (with one camera, which cannot tell them apart:
two or more views do, and there an exchange that fit a little better traded a real
walker's legs; docs/design/tracking-history.md) are local minima it does not leave.  When a
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
import pinocchio as pin

from ..coordinates import JointCoordinates, quaternion_matrix
from ..robot import Robot
from .limbs import left_right_pairs, limb_joints, movable, twin_name
from .loop import FrameECM
from .masks import Views
from .state import SequenceState
from .symmetry import Symmetry

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
    first put back at rest), ``"exchange"`` (twin limbs' angles exchanged) or, of the
    reach search (:mod:`~kms2pin.ecm.reach`), ``"reach"`` (a lost body re-aimed).  ``joints``:
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
        if self.kind == "reach":
            return f"pointed '{self.joints[0]}' at the masks"
        return f"swapped '{self.joints[0]}' and '{self.joints[1]}'"


@dataclass(frozen=True)
class Limb:
    """A limb: its first joint and the joints below it (revolute, prismatic, spherical),
    with their q and velocity indices."""

    first: JointCoordinates
    below: tuple[JointCoordinates, ...]

    @property
    def chain(self) -> tuple[JointCoordinates, ...]:
        return (self.first, *self.below)

    @staticmethod
    def _q(joints) -> np.ndarray:
        return np.array([k for j in joints for k in range(j.idx_q, j.idx_q + j.nq)], dtype=int)

    @property
    def below_q(self) -> np.ndarray:
        return self._q(self.below)

    @property
    def below_v(self) -> np.ndarray:
        return np.array([k for j in self.below for k in range(j.idx_v, j.idx_v + (3 if j.kind == "spherical" else 1))],
                        dtype=int)

    @property
    def indices(self) -> np.ndarray:
        return self._q(self.chain)


def _swing(q: np.ndarray, rest: np.ndarray, j: JointCoordinates) -> np.ndarray:
    """``q`` with joint ``j`` swung the other way about its rest value: the angle or offset
    reflected (2 rest - q); a spherical joint's swing about its parent end's axis u
    reflected, the rest of its rotation kept (R = Exp(v) R_rest turned to Exp(v - 2 (v.u) u) R_rest,
    v in the parent's axes): what one view confuses is the swing, as for a revolute joint."""
    c = q.copy()
    if j.kind != "spherical":
        c[j.idx_q] = 2.0 * rest[j.idx_q] - q[j.idx_q]
        return c
    R0, R = quaternion_matrix(rest[j.idx_q : j.idx_q + 4]), quaternion_matrix(q[j.idx_q : j.idx_q + 4])
    u = np.asarray(j.spec.parent_bvec.orient, dtype=float)
    u = u / np.linalg.norm(u)
    v = pin.log3(R @ R0.T)
    c[j.idx_q : j.idx_q + 4] = pin.Quaternion(pin.exp3(v - 2.0 * float(v @ u) * u) @ R0).coeffs()
    return c


class LimbSearch:
    """The limb search of one track over ``robot``'s limbs (:func:`limb_joints`),
    screening and refining candidates with ``ecm``; twin limbs are exchanged mirrored
    (``symmetry``; one-coordinate twins exchange their values without one)."""

    def __init__(self, robot: Robot, ecm: FrameECM, symmetry: Symmetry | None = None):
        self.robot, self.ecm, self.symmetry = robot, ecm, symmetry
        m = robot.model
        by_id = {m.getJointId(j.name): j for j in robot.joints}
        self.limbs: dict[str, Limb] = {}
        for name in limb_joints(robot):
            jid = m.getJointId(name)
            below = tuple(by_id[k] for k in m.subtrees[jid][1:] if movable(robot, k))
            self.limbs[name] = Limb(by_id[jid], below)
        self.pairs = self._twins()

    def _twins(self) -> list[tuple[str, str, Limb, Limb]]:
        """The pairs of twin limbs whose joints all have twins (in the same order)."""
        by_low = {j.name.lower(): j for j in self.robot.joints}
        pairs = []
        for i, t in left_right_pairs(list(self.limbs)):
            name, twin = list(self.limbs)[i], list(self.limbs)[t]
            left = self.limbs[name]
            mates = [by_low.get(twin_name(j.name.lower(), by_low)) for j in left.chain]
            if any(x is None or x.kind != j.kind for x, j in zip(mates, left.chain)):
                continue
            if any(j.kind == "spherical" for j in left.chain) and self.symmetry is None:
                continue
            pairs.append((name, twin, left, Limb(mates[0], tuple(mates[1:]))))
        return pairs

    def exchange_move(self, left: str, right: str) -> LimbMove:
        """The move that exchanges twin limbs ``left`` and ``right`` (their first joints)."""
        iq = np.concatenate([self.limbs[n].indices for n in (left, right)]).astype(int)
        return LimbMove("exchange", (left, right), iq)

    def _exchanged(self, q: np.ndarray, a: Limb, b: Limb) -> np.ndarray | None:
        """``q`` with twin limbs ``a`` and ``b`` exchanged (mirrored), or None if no joint of
        theirs differs from its twin's mirror by :data:`MIN_ANGLE`."""
        if all(j.kind != "spherical" for j in a.chain):
            ia, ib = a.indices, b.indices
            if np.abs(q[ia] - q[ib]).max() < MIN_ANGLE:
                return None
            c = q.copy()
            c[ia], c[ib] = q[ib], q[ia]
            return self.robot.clamp(c)
        if self.symmetry.difference(q, a.chain, b.chain) < MIN_ANGLE:
            return None
        return self.robot.clamp(self.symmetry.exchange(q, a.chain, b.chain))

    def _bend(self, q: np.ndarray, j: JointCoordinates) -> float:
        """A first joint's bend for the crossing test: its angle or offset; a spherical
        joint's rotation about its parent end's axis (rad)."""
        if j.kind != "spherical":
            return float(q[j.idx_q])
        R = quaternion_matrix(q[j.idx_q : j.idx_q + 4])
        return float(pin.log3(R) @ np.asarray(j.spec.parent_bvec.orient, dtype=float))

    @staticmethod
    def _swung(q: np.ndarray, rest: np.ndarray, j: JointCoordinates) -> float:
        """How far a first joint is swung from rest: the angle or offset; a spherical
        joint's rotation about its parent end's axis (rad)."""
        if j.kind != "spherical":
            return abs(q[j.idx_q] - rest[j.idx_q])
        R0, R = quaternion_matrix(rest[j.idx_q : j.idx_q + 4]), quaternion_matrix(q[j.idx_q : j.idx_q + 4])
        u = np.asarray(j.spec.parent_bvec.orient, dtype=float)
        return abs(float(pin.log3(R @ R0.T) @ u)) / float(np.linalg.norm(u))

    def candidates(self, q: np.ndarray, exchange: bool = True) -> list[tuple[LimbMove, np.ndarray]]:
        """Every move from ``q`` with its configuration: twin limbs exchanged (if
        ``exchange``); each limb put back at rest below its first joint; each limb swung
        the other way, once with the joints below kept and once with them put back at
        rest (an arm swung back over the trunk is often bent there too)."""
        rest = self.robot.q_rest
        out = []
        for left, right, a, b in self.pairs if exchange else ():
            c = self._exchanged(q, a, b)
            if c is not None:
                out.append((self.exchange_move(left, right), c))
        away = np.abs(pin.difference(self.robot.model, rest, q))  # tangent: no arithmetic on quaternions
        for name, limb in self.limbs.items():
            indices, below = limb.indices, limb.below_q
            far_below = len(below) and away[limb.below_v].max() >= MIN_ANGLE
            if far_below:
                c = q.copy()
                c[below] = rest[below]
                out.append((LimbMove("reset", (name,), indices), self.robot.clamp(c)))
            if self._swung(q, rest, limb.first) < MIN_ANGLE:
                continue
            first = limb.first
            c = _swing(q, rest, first)
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
        views), the best kept if it gains :data:`GAIN`.  Twins are exchanged with one
        view only (module docstring).  Returns the configuration, its
        fit and the move (None if none was kept).  ``screen_only``: the best screened
        candidate unrefined (the limb-search hypothesis's start)."""
        cands = self.candidates(q, exchange=len(views) == 1)
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
        frames (their first joints' bends within :data:`CROSS_ANGLE`, or passed each other
        since the last frame, recorded in ``state.crossed``); keep it if it gains
        :data:`GAIN`.  Returns as :meth:`search`."""
        out = (q, fit, None)
        views_c = None
        for left, right, a, b in self.pairs:
            d = self._bend(q, a.first) - self._bend(q, b.first)
            d_last = self._bend(state.q, a.first) - self._bend(state.q, b.first)
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
