"""A pose's parts taken from another pose where that fits the masks better.

A track that holds a limb may have another off.  Each *part* (:func:`parts`: every joint
but a free root, with the joints below it) is taken on a frame from another pose of the
same frame (another track's, or a frame beside's) where the masks bear it out: a hinge (a
knee, an elbow) at the other pose's angle, a ball joint (a hip, a shoulder) pointing its
body as the other pose points it, from this pose's body above.  Used online by the tracks
beside (:func:`~kms2pin.ecm.secondtrack.better`) and offline by
:mod:`~kms2pin.ecm.bothways` and :mod:`~kms2pin.ecm.stretches`.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable

import numpy as np
import pinocchio as pin

from ..errors import RobotError
from ..robot import Robot

__all__ = ["Parts", "branching", "hinges", "parts", "take_parts"]


def hinges(robot: Robot) -> tuple[str, ...]:
    """The names of ``robot``'s revolute joints, in tree order: a person's knees and elbows
    (on the thesis's models, where every joint is revolute, every joint)."""
    return tuple(j.name for j in robot.joints if j.kind == "revolute")


def parts(robot: Robot) -> tuple[str, ...]:
    """The joints :func:`take_parts` and :func:`~kms2pin.ecm.bothways.take_beside` try, in tree order: every joint
    but a free root (a person's hips, knees, ankles and toes, the spine and the neck, the
    collars, shoulders, elbows and wrists; on the thesis's models every joint): a track
    that holds a limb may still have the trunk or a foot off (docs/design/tracking-history.md)."""
    return tuple(j.name for j in robot.joints if j.kind != "free")


def branching(robot: Robot) -> tuple[str, ...]:
    """The parts (:func:`parts`) with a branch below them: a joint two or more joints hang
    from, or above one (a person's lower back and chest, which carry both arms and the
    head).  :func:`take_parts` does not take them from the other track: that would be the
    whole upper body's track changed on a frame, without the cost a change of track pays
    (:func:`~kms2pin.ecm.bothways.choose`; docs/design/tracking-history.md)."""
    pm = robot.model
    return tuple(n for n in parts(robot) if any(len(pm.children[j]) >= 2 for j in pm.subtrees[pm.getJointId(n)]))


class Parts:
    """What :func:`take_parts` and :func:`~kms2pin.ecm.bothways.take_beside` try on a frame: each of :func:`parts`
    with its joint, columns and held velocities, worked out once."""

    def __init__(self, robot: Robot, branches: bool = True):
        pm = self.pm = robot.model
        self._robot = weakref.ref(robot)  # weak: secondtrack caches a Parts per robot
        # without ``branches`` a part with a branch below it (:func:`branching`) is not tried
        skipped = set() if branches else set(branching(robot))
        self.here, self.there = pm.createData(), pm.createData()
        self.names = parts(robot)
        kinds = {j.name: j.kind for j in robot.joints}
        # per part: its joint, whether it has one coordinate (a hinge, a slider), its own q
        # columns, those below it, its v columns
        self.plan = []
        for name in self.names:
            if name in skipped:
                self.plan.append(None)
                continue
            jid = pm.getJointId(name)
            below = [np.arange(pm.idx_qs[j], pm.idx_qs[j] + pm.nqs[j]) for j in pm.subtrees[jid] if j != jid]
            self.plan.append((jid, kinds[name] != "spherical", slice(pm.idx_qs[jid], pm.idx_qs[jid] + pm.nqs[jid]),
                              np.concatenate(below or [np.arange(0)]),
                              list(range(pm.idx_vs[jid], pm.idx_vs[jid] + pm.nvs[jid]))))

    @property
    def robot(self) -> Robot:
        return self._robot()

    def take(self, score: Callable[[np.ndarray], float], q: np.ndarray, other: np.ndarray, fit: float,
             taken: np.ndarray) -> tuple[np.ndarray, float]:
        """One frame: each part in tree order taken from ``other`` into ``q`` (its ``fit``)
        where ``score`` is higher, each on the last; ``taken`` (parts,) set where taken.  A
        ``score`` with a ``rebase`` method (:class:`~kms2pin.ecm.silhouette.IncrementalFit`)
        is told each pose the trials are made from."""
        pm, here, there = self.pm, self.here, self.there
        rebase = getattr(score, "rebase", None)  # an IncrementalFit: told the pose the trials are made from
        if rebase is not None:
            rebase(q)
        pin.forwardKinematics(pm, there, other)
        for h, step in enumerate(self.plan):
            if step is None:
                continue
            jid, hinge, own, cols, held = step
            trial = q.copy()
            trial[cols] = other[cols]
            if hinge:  # one coordinate: the other track's
                trial[own] = other[own]
            else:  # a ball joint: this track's parent, the other track's world orientation
                pin.forwardKinematics(pm, here, q)
                above = here.oMi[pm.parents[jid]].rotation @ pm.jointPlacements[jid].rotation
                quat = pin.Quaternion(above.T @ there.oMi[jid].rotation).coeffs()
                trial[own] = -quat if np.dot(quat, q[own]) < 0 else quat  # the kept sign
            if np.abs(trial - q).max() <= 1e-12:  # the same pose (np.allclose's test for finite poses, faster)
                continue
            if self.robot.closures:
                try:
                    trial = self.robot.project(trial, hold=held)
                except RobotError:
                    continue
            f = score(trial)
            if f > fit:
                q, fit, taken[h] = trial, f, True
                if rebase is not None:
                    rebase(q)
        return q, fit


def take_parts(robot: Robot, scorer: Callable[[int], Callable[[np.ndarray], float]], q: np.ndarray,
               other: np.ndarray, fit_q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each of :func:`parts` in tree order but those with a branch below them
    (:func:`branching`), on each frame k, taken with the joints below it from ``other[k]``
    (frames, nq; the other track) into ``q[k]`` (frames, nq; its fit ``fit_q``) where that
    fits better (``scorer(k)``, asked once a frame, scores a pose on frame k: the IoU).  A
    hinge (or a slider) takes the other track's coordinate.  A ball joint takes the rotation that gives the body it moves the other track's orientation in the world, from
    this track's body above it: a thigh or an upper arm then points as the other track has
    it, from this track's hip or shoulder (its angles, relative to a trunk the tracks place
    differently, would point it elsewhere).  On a model with loops each trial is closed
    first with the joint held (:meth:`Robot.project`) and skipped if it cannot be.  Returns
    (q, its fit, (frames, parts) True where taken)."""
    tried = Parts(robot, branches=False)
    q, fit_q = np.array(q, dtype=float), np.array(fit_q, dtype=float)
    taken = np.zeros((len(q), len(tried.names)), dtype=bool)
    for k in range(len(q)):  # the frames are independent
        q[k], fit_q[k] = tried.take(scorer(k), q[k], other[k], fit_q[k], taken[k])
    return q, fit_q, taken
