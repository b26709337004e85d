"""Alternative hypotheses tracked beside the pose: what one view cannot tell apart.

With one camera a pose and its mirror image through the plane across the viewing ray
(the subject turned the other way, front for back) cast nearly the same silhouette,
and so do a pose and the pose with left and right limbs exchanged.  Each such
alternative is spawned as the *flip* of the tracked pose, tracked with its own
constant-velocity prediction and ECM, and scored by its running fit (IoU, smoothed
as the main one's).  One whose running fit leads the main one's by more than its
margin, once the running fit has settled, becomes the tracked pose (the frame is
flagged ``"switched to the ... hypothesis"``); one that merges with the main one or
falls well behind is dropped, and the next frame spawns a fresh one.  The limb search
(:mod:`kms2pin.ecm.limbsearch`) spawns a third kind, ``"limb"``, from its best
candidate.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..robot import Robot
from .camera import Camera
from .limbsearch import LimbMove
from .loop import FrameECM
from .masks import Views
from .prediction import Motion
from .state import SequenceState
from .symmetry import Symmetry, spherical_angle

__all__ = ["KIND_WORDS", "Hypotheses", "Hypothesis", "mirror_pose"]

#: how a switch to each kind of hypothesis is reported
KIND_WORDS = {"mirror": "mirror", "swap": "left/right-swapped", "limb": "limb-search"}
#: an alternative this close to the main pose (root rotation, joints) has merged with it
MERGE = np.radians(10.0)
#: how far behind the main pose's running fit an alternative is dropped
BEHIND = {"mirror": 0.05, "swap": 0.05, "limb": 0.02}


@dataclass
class Hypothesis:
    """An alternative pose: this frame's (``q``), the last frame's (``prev``, for its
    velocity), its running fit (``score``) and this frame's fit (None when just spawned)."""

    q: np.ndarray
    prev: np.ndarray
    score: float
    fit: float | None = None


def mirror_pose(q: np.ndarray, camera: Camera, sagittal: np.ndarray) -> np.ndarray:
    """The mirror image of free-root configuration ``q`` in ``camera``: the root's
    orientation reflected through the plane across the viewing ray at the root and
    through the model's own left/right plane (``sagittal``, a reflection in the root
    frame; together a proper rotation), the joints kept."""
    M = pin.XYZQUATToSE3(q[:7])
    d = M.translation - camera.centre
    d /= max(float(np.linalg.norm(d)), 1e-12)
    R = (np.eye(3) - 2.0 * np.outer(d, d)) @ M.rotation @ sagittal
    out = q.copy()
    out[:7] = pin.SE3ToXYZQUAT(pin.SE3(R, M.translation))
    return out


def root_angle(a: np.ndarray, b: np.ndarray) -> float:
    """The angle (rad) between two free-root configurations' root orientations."""
    Ra, Rb = pin.XYZQUATToSE3(a[:7]).rotation, pin.XYZQUATToSE3(b[:7]).rotation
    return float(np.linalg.norm(pin.log3(Ra.T @ Rb)))


class Hypotheses:
    """The alternatives of one track (module docstring).

    Args:
        robot: the model.
        ecm: the frame ECM that tracks them.
        kinds: which kinds are tracked, each with its margin (``"mirror"``, ``"swap"``,
            ``"limb"``).
        sagittal: the model's left/right reflection (root frame), for the mirror.
        symmetry: the model's twin joints (:class:`Symmetry`), for the swap.
        joint_dofs: the velocity indices of the joints (not the free root).
        iterations: ECM iterations of an alternative a frame.
        binned: track the alternatives on the masks binned 2x2.
    """

    def __init__(self, robot: Robot, ecm: FrameECM, motion: Motion, kinds: dict[str, float],
                 sagittal: np.ndarray | None, symmetry: Symmetry | None, joint_dofs: np.ndarray, iterations: int, binned: bool,
                 predict: bool):
        self.robot, self.ecm, self.motion = robot, ecm, motion
        self.margins = dict(kinds)
        self.sagittal, self.symmetry = sagittal, symmetry
        self.joint_dofs = joint_dofs
        self.iterations, self.binned, self.predict = iterations, binned, predict
        self.alts: dict[str, Hypothesis] = {}

    def _flip(self, kind: str, q: np.ndarray, camera: Camera) -> np.ndarray | None:
        if kind == "mirror":
            return mirror_pose(q, camera, self.sagittal)
        if kind == "swap":
            return self.symmetry.swap(q)
        return None  # "limb" is spawned by the limb search

    def merged(self, kind: str, qa: np.ndarray, q: np.ndarray) -> bool:
        """Whether alternative ``qa`` of ``kind`` has become the main pose ``q``."""
        if self.robot.root == "free" and root_angle(qa, q) >= MERGE:
            return False
        if kind == "mirror":
            return True
        if kind == "limb":
            dq = self.motion.scaled(np.abs(pin.difference(self.robot.model, qa, q)))
            return float(dq[self.joint_dofs].max()) < MERGE
        worst = 0.0
        for j in self.symmetry.swapped_joints():
            if j.kind == "spherical":
                worst = max(worst, spherical_angle(qa[j.idx_q : j.idx_q + 4], q[j.idx_q : j.idx_q + 4]))
            else:
                worst = max(worst, float(abs(qa[j.idx_q] - q[j.idx_q])))
        return worst < MERGE

    def _track(self, alt: Hypothesis, views: Views, timings: dict, coarse: Views | None,
               binned: bool, smoothing: float) -> Hypothesis:
        """One frame of an alternative: predicted, ECM, scored."""
        pred = self.motion.predict(alt.q, alt.prev) if self.predict else alt.q
        qa_new, _, _ = self.ecm.run(pred, views, timings, self.iterations, coarse, binned)
        fa = self.ecm.fit(qa_new, views)
        return Hypothesis(qa_new, alt.q, (1.0 - smoothing) * alt.score + smoothing * fa, fa)

    def step(self, q: np.ndarray, fit: float, state: SequenceState, views: Views, timings: dict,
             coarse: Views | None = None, binned_views: Callable[[], Views | None] | None = None,
             spawn: tuple[np.ndarray, float, LimbMove] | None = None) -> tuple[np.ndarray, float, str]:
        """Track the alternatives on this frame beside the main pose ``q`` (its ``fit``);
        returns the pose to report, its fit and the kind switched to ("" if none).  On a
        switch ``state.q`` becomes the alternative's last pose (for its velocity) and the
        running fit its score.  ``spawn``: the limb search's candidate (configuration,
        fit, move) to track as the ``"limb"`` alternative, its last pose the main one's
        with the moved limbs as in the candidate (no velocity)."""
        running = state.running
        a = running.smoothing
        last_score = running.score
        running.update(fit, state.frame)
        switched = ""
        if state.frame == 0:
            return q, fit, switched
        binned = self.binned and bool(self.alts)
        if binned:  # all the alternatives' iterations on the binned masks
            coarse = coarse if coarse is not None else binned_views()
            binned = coarse is not None
        best = None
        for kind, margin in self.margins.items():
            alt = self.alts.get(kind)
            if alt is None:  # spawn: the flipped image of this frame's fit and of the last frame's
                flip = self._flip(kind, q, views.cameras[0])
                if flip is not None:
                    self.alts[kind] = Hypothesis(flip, self._flip(kind, state.q, views.cameras[0]), running.score)
                continue
            self.alts[kind] = alt = self._track(alt, views, timings, coarse, binned, a)
            if alt.score > running.score + margin and (best is None or alt.score > self.alts[best].score) \
                    and running.settled(state.frame):
                best = kind
        if best is not None:
            alt = self.alts[best]
            # the alternative leads: it becomes the main pose (its last pose too, for the
            # velocity); the old main pose becomes that alternative
            self.alts[best] = Hypothesis(q, state.q.copy(), running.score, fit)
            state.q = alt.prev.copy()
            q, fit = alt.q, alt.fit
            running.score = alt.score
            switched = best
            for kind in list(self.alts):  # the others were flips of the old main pose
                if kind != best:
                    del self.alts[kind]
        if spawn is not None and not switched and "limb" not in self.alts:
            qs, fs, move = spawn
            last = state.q.copy()
            last[move.indices] = qs[move.indices]
            self.alts["limb"] = Hypothesis(qs, last, (1.0 - a) * last_score + a * fs, fs)
        for kind in list(self.alts):
            alt = self.alts[kind]
            # a hypothesis that is (or merged into) the main one, or fell well behind, is
            # dropped; the next frame spawns a fresh one
            if self.merged(kind, alt.q, q) or alt.score < running.score - BEHIND[kind]:
                del self.alts[kind]
        return q, fit, switched
