"""Prediction of the next frame's pose and the test of a frame's convergence.

Joint motion is measured in Pinocchio's tangent space (``pin.difference``), so a
quaternion joint is compared by its rotation, never by its components.  Translations (a
free root's, a prismatic joint's) are put on the angles' scale: 1 % of the model height
counts as 1°.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from ..errors import RobotError
from ..native import kernels
from ..robot import Robot
from .camera import Camera

__all__ = ["LEARNT_PRIOR_DEG", "Motion", "VelocityGain", "body_outline_pixels", "image_motion", "outline_pixels",
           "outline_points"]

#: the learnt motion model's prior (:class:`VelocityGain`): a steady motion of this many
#: degrees a frame, carried on in full
LEARNT_PRIOR_DEG = 1.0


class VelocityGain:
    """A motion model learnt as the track goes (``prediction="learnt"``): per coordinate,
    the share ``a`` of the last frame's velocity that the next frame carries on, the
    least-squares fit of v_k = a v_(k-1) over the past frames' velocities, each frame's
    weight falling by 1 - 1/``memory``: a = Σ v_k v_(k-1) / Σ v_(k-1)², clipped to [0, 1].
    A steady motion has a = 1 (constant velocity); a coordinate that jitters about a
    pose the images do not fix (its velocity changing sign from frame to frame) has
    a = 0, and is not carried away by its own noise.  Both sums start at
    :data:`LEARNT_PRIOR_DEG` squared (a = 1 until the velocities say otherwise).
    Velocities are on the angles' scale (:meth:`Motion.scaled`), in radians."""

    def __init__(self, nv: int, memory: float):
        prior = np.radians(LEARNT_PRIOR_DEG) ** 2
        self.decay = 1.0 - 1.0 / float(memory)
        self.num = np.full(nv, prior)
        self.den = np.full(nv, prior)
        self.last: np.ndarray | None = None

    def update(self, v: np.ndarray | None) -> None:
        """Fold in a frame's velocity ``v`` (None: a frame without one, which breaks the
        chain of successive velocities)."""
        if v is not None and self.last is not None:
            self.num = self.decay * self.num + v * self.last
            self.den = self.decay * self.den + self.last * self.last
        self.last = None if v is None else v.copy()

    @property
    def gain(self) -> np.ndarray:
        """(nv,) the share of the velocity carried on, in [0, 1]."""
        return np.clip(self.num / self.den, 0.0, 1.0)


class Motion:
    """Joint motion between configurations of ``robot``, in radians (the root's
    translation scaled as in the module docstring)."""

    def __init__(self, robot: Robot, max_prediction_deg: float):
        self.robot = robot
        self.root_dofs = 3 if robot.root == "free" else 0
        self.max_prediction = np.radians(float(max_prediction_deg))
        #: the velocity indices of prismatic joints (length units, like the root's translation)
        self.slides = np.array([j.idx_v for j in robot.joints if j.kind == "prismatic"], dtype=int)
        #: the learnt motion model (None: constant velocity)
        self.learnt: VelocityGain | None = None

    def scaled(self, v: np.ndarray) -> np.ndarray:
        """A tangent vector ``v`` with its translations on the angles' scale (module docstring), in place."""
        if self.root_dofs:
            v[:3] *= np.radians(1.0) / (0.01 * self.robot.height)
        if len(self.slides):
            v[self.slides] *= np.radians(1.0) / (0.01 * self.robot.height)
        return v

    def change(self, q0: np.ndarray, q1: np.ndarray) -> float:
        """The largest joint change from ``q0`` to ``q1`` (rad)."""
        dq = self.scaled(np.abs(pin.difference(self.robot.model, q0, q1)))
        return float(dq.max()) if len(dq) else 0.0

    def velocity(self, prev: np.ndarray, cur: np.ndarray) -> np.ndarray:
        """The motion from ``prev`` to ``cur`` (a tangent vector), each joint capped at
        ``max_prediction_deg`` and the root's translation at that many hundredths of the
        model height: a joint the images hardly fix can start to spin, and an uncapped
        prediction would carry the spin on from frame to frame."""
        v = pin.difference(self.robot.model, prev, cur)
        cap = np.full(len(v), self.max_prediction)
        if self.root_dofs:
            cap[:3] = np.degrees(self.max_prediction) * 0.01 * self.robot.height
        if len(self.slides):
            cap[self.slides] = np.degrees(self.max_prediction) * 0.01 * self.robot.height
        return np.clip(v, -cap, cap)

    def predict(self, cur: np.ndarray, prev: np.ndarray | None) -> np.ndarray:
        """``cur`` moved on by the capped motion from ``prev`` (constant velocity, or its
        learnt share per coordinate), clipped into the joint limits, and with loop closures
        projected back onto them (``cur`` where they cannot be closed there); ``cur`` itself
        without a ``prev``."""
        if prev is None:
            return cur
        v = self.velocity(prev, cur)
        if self.learnt is not None:
            v *= self.learnt.gain
        q = self.robot.clamp(pin.integrate(self.robot.model, cur, v))
        if self.robot.closures:
            try:
                q = self.robot.project(q)
            except RobotError:
                q = cur
        return q

    def learn(self, prev: np.ndarray | None, cur: np.ndarray) -> None:
        """Fold the motion from ``prev`` to ``cur`` (None: no velocity) into the learnt model."""
        if self.learnt is not None:
            self.learnt.update(None if prev is None else self.scaled(pin.difference(self.robot.model, prev, cur)))


def outline_points(Rs: np.ndarray, ts: np.ndarray, inner: np.ndarray) -> np.ndarray:
    """World points (n_bodies * 7, 3) that outline ellipsoids (rotations ``Rs``, centres
    ``ts``, semi-axes ``inner``): each centre and the two ends of each axis."""
    ends = Rs * inner[:, None, :]  # (n, 3, 3): column k = axis k's half length
    pts = np.concatenate([ts[:, None], ts[:, None] + ends.transpose(0, 2, 1), ts[:, None] - ends.transpose(0, 2, 1)], 1)
    return pts.reshape(-1, 3)


def outline_pixels(points: np.ndarray, cameras: Sequence[Camera]) -> list[np.ndarray]:
    """:func:`outline_points` projected into every camera (NaN behind it)."""
    return [cam.project(points) for cam in cameras]


def body_outline_pixels(Rs: np.ndarray, ts: np.ndarray, inner: np.ndarray, cameras: Sequence[Camera]) -> list[np.ndarray]:
    """:func:`outline_pixels` of :func:`outline_points` (rotations ``Rs``, centres ``ts``,
    semi-axes ``inner``): one ``outline_pixels`` kernel call per camera when none is
    distorted."""
    if any(cam.dist is not None for cam in cameras):
        return outline_pixels(outline_points(Rs, ts, inner), cameras)
    n = len(Rs)
    R9 = Rs.reshape(n, 9)
    out = [np.empty((7 * n, 2)) for _ in cameras]
    for cam, pixels in zip(cameras, out):
        kernels.outline_pixels(R9, ts, inner, cam.world_R_camera, cam.centre, cam.K, pixels)
    return out


def image_motion(a: list[np.ndarray], b: list[np.ndarray]) -> float:
    """The largest image displacement (pixels, over the cameras) between two sets of
    :func:`outline_pixels`; points behind a camera are left out."""
    moved = 0.0
    for pa, pb in zip(a, b):
        d = pa - pb
        d2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]  # np.linalg.norm's sum, its sqrt taken after the max
        m = float(np.fmax.reduce(d2)) if len(d2) else math.nan  # fmax leaves NaN (behind) out
        if m < math.inf:
            moved = max(moved, math.sqrt(m))
        elif m == math.inf:  # an overflow: left out, as the non-finite
            finite = d2[np.isfinite(d2)]
            moved = max(moved, math.sqrt(float(finite.max()))) if len(finite) else moved
    return moved
