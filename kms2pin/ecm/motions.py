"""Named synthetic motions for ``kms2pin synth``: sequences of configurations (T, nq).

Every motion starts at the spec's rest pose (frame 0 is ``robot.q_rest``, the
tracker's default start) and is smooth at 30 frames/s.  A spherical joint moves by
a rotation vector w(t) in its parent's frame, R_ij = Exp(w) R_ij,rest (its quaternion
composed on the manifold, never added to); a prismatic joint slides by a fraction of
its range (its limits, or the model's height without them).

- ``sweep``: each revolute joint in turn swings +-40 deg about its rest angle, each
  spherical joint turns +-40 deg about its parent's x, then y, then z axis, each
  prismatic joint slides +-20 % of its range.
- ``walk``: a walking gait (hips, knees, ankles, shoulders, elbows found by name;
  a spherical joint swings about its parent end's axis and also sways out of that
  plane, about the axis across it and the rest vertical: hips 8°, shoulders 15°, others
  4°; other joints sway gently; prismatic joints stay at rest); with ``root="free"``
  the body also walks across the view along world x, turning round at the ends.
- ``random``: every joint coordinate a sum of random low-frequency sinusoids (+-30 deg,
  a spherical joint about all three axes at once; +-15 % of a prismatic range).

Revolute angles and prismatic offsets stay within the spec's joint limits, where it
gives them (clipped).  A model with loop closures moves the same way, each frame then
projected onto the closures (:meth:`Robot.project`) from the last frame moved by the
motion's step, so the closing joints follow and the motion stays continuous; a frame the
loops cannot reach keeps the last one.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from ..coordinates import JointCoordinates
from ..errors import Kms2pinError, RobotError
from ..robot import Robot

MOTIONS = ("sweep", "walk", "random")
FPS = 30.0
SWEEP_DEG, RANDOM_DEG = 40.0, 30.0
SWEEP_SLIDE, RANDOM_SLIDE = 0.2, 0.15  # fractions of a prismatic joint's range


def _moving(robot: Robot) -> list[JointCoordinates]:
    """The joints a motion moves: every revolute, spherical and prismatic joint."""
    return [j for j in robot.joints if j.kind in ("revolute", "spherical", "prismatic")]


def _slide_range(robot: Robot, j: JointCoordinates) -> float:
    """A prismatic joint's range: its limits' span, else the model's height."""
    lo, hi = robot.lower_limits[j.idx_q], robot.upper_limits[j.idx_q]
    return float(hi - lo) if np.isfinite(lo) else robot.height


def _turn(q: np.ndarray, j: JointCoordinates, w: np.ndarray) -> None:
    """Turn spherical joint ``j`` of every configuration in ``q`` (T, nq) by the rotation
    vectors ``w`` (T, 3) (radians, its parent's frame), in place."""
    for f in range(len(q)):
        block = q[f, j.idx_q : j.idx_q + 4]
        R = pin.exp3(w[f]) @ pin.Quaternion(block[3], block[0], block[1], block[2]).toRotationMatrix()
        q[f, j.idx_q : j.idx_q + 4] = pin.Quaternion(R).coeffs()


def _ramp(t: np.ndarray, t0: float, t1: float) -> np.ndarray:
    """Smooth 0 -> 1 between t0 and t1 (cosine)."""
    x = np.clip((t - t0) / max(t1 - t0, 1e-9), 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * x)


def sweep(robot: Robot, frames: int) -> np.ndarray:
    slots = [(j, k) for j in _moving(robot) for k in range(3 if j.kind == "spherical" else 1)]
    q = np.repeat(robot.q_rest[None], frames, axis=0)
    if not slots:
        return q
    per = frames / len(slots)
    t = np.arange(frames)
    for n, (j, k) in enumerate(slots):
        local = (t - n * per) / per
        inside = (local >= 0) & (local < 1)
        wave = np.sin(2 * np.pi * local[inside])
        if j.kind == "spherical":
            w = np.zeros((len(wave), 3))
            w[:, k] = np.radians(SWEEP_DEG) * wave
            block = q[inside]
            _turn(block, j, w)
            q[inside] = block
        elif j.kind == "prismatic":
            q[inside, j.idx_q] += SWEEP_SLIDE * _slide_range(robot, j) * wave
        else:
            q[inside, j.idx_q] += np.radians(SWEEP_DEG) * wave
    return q


def _gait_angle(name: str, phase: np.ndarray) -> np.ndarray:
    """Joint offsets (rad) of a walking gait; ``phase`` in radians, left leads right by pi."""
    low = name.lower()
    side = np.pi if "right" in low else 0.0
    ph = phase + side
    if "hip" in low:
        return np.radians(25.0) * np.sin(ph)
    if "knee" in low:
        return np.radians(25.0) * (1.0 - np.cos(ph)) * 0.5 + np.radians(10.0) * np.sin(ph - 0.5)
    if "ankle" in low:
        return np.radians(12.0) * np.sin(ph - 1.0)
    if "shoulder" in low:
        return -np.radians(20.0) * np.sin(ph)
    if "elbow" in low:
        return np.radians(15.0) * (1.0 - np.cos(ph)) * 0.5
    return np.radians(6.0) * np.sin(ph + 0.7)


def _sway(name: str, phase: np.ndarray) -> np.ndarray:
    """A spherical joint's sway out of its swing plane (rad): left and right in opposition."""
    low = name.lower()
    side = np.pi if "right" in low else 0.0
    amplitude = 8.0 if "hip" in low else 15.0 if "shoulder" in low else 4.0
    return np.radians(amplitude) * np.cos(phase + side)


def _sway_axis(robot: Robot, j: JointCoordinates) -> np.ndarray | None:
    """The axis (parent frame) across a spherical joint's swing axis and the vertical at rest."""
    R = robot.body_pose(robot.q_rest, j.spec.parent).rotation if j.spec.parent else np.eye(3)
    up = R.T @ np.array([0.0, 1.0, 0.0])
    axis = np.cross(np.asarray(j.spec.parent_bvec.orient, dtype=float), up)
    n = float(np.linalg.norm(axis))
    return axis / n if n > 1e-6 else None


def walk(robot: Robot, frames: int) -> np.ndarray:
    t = np.arange(frames) / FPS
    phase = 2.0 * np.pi * t / 1.2  # one gait cycle per 1.2 s
    q = np.repeat(robot.q_rest[None], frames, axis=0)
    for j in _moving(robot):
        if robot.root == "spec" and j.spec is robot.system.joints[0] or j.kind == "prismatic":
            continue  # the spec's own root joint and slides stay put
        angle = _gait_angle(j.name, phase) * _ramp(t, 0.0, 0.5)
        if j.kind == "spherical":  # about its parent end's axis, and out of that plane
            _turn(q, j, angle[:, None] * np.asarray(j.spec.parent_bvec.orient)[None])
            across = _sway_axis(robot, j)
            if across is not None:
                _turn(q, j, (_sway(j.name, phase) * _ramp(t, 0.0, 0.5))[:, None] * across[None])
        else:
            q[:, j.idx_q] += angle
    if robot.root == "free":
        rest = pin.XYZQUATToSE3(robot.q_rest[:7])
        up = np.array([0.0, 1.0, 0.0])
        span = 0.25 * robot.height  # walk +-span along world x
        period = 8.0  # s for a there-and-back
        s = np.sin(2 * np.pi * t / period)
        x = span * s
        heading = np.where(np.cos(2 * np.pi * t / period) >= 0, 1.0, -1.0)
        yaw = -np.pi / 2 * heading  # face the way it walks (the specs face -z at rest)
        yaw_smooth = np.convolve(np.pad(yaw, 15, mode="edge"), np.ones(31) / 31, mode="valid")
        for f in range(frames):
            R = pin.exp3(up * yaw_smooth[f]) @ rest.rotation
            p = rest.translation + np.array([x[f], 0.02 * robot.height * np.cos(2 * phase[f]), 0.0])
            q[f, :7] = pin.SE3ToXYZQUAT(pin.SE3(R, p))
        # start at rest: blend the first half second
        w = _ramp(t, 0.0, 0.5)
        for f in range(frames):
            if w[f] < 1.0:
                q[f, :7] = pin.SE3ToXYZQUAT(
                    pin.SE3.Interpolate(rest, pin.XYZQUATToSE3(q[f, :7]), float(w[f]))
                )
    return q


def random_smooth(robot: Robot, frames: int, rng: np.random.Generator) -> np.ndarray:
    t = np.arange(frames) / FPS
    q = np.repeat(robot.q_rest[None], frames, axis=0)
    ramp = _ramp(t, 0.0, 0.5)

    def wave(amplitude: float) -> np.ndarray:
        freqs = rng.uniform(0.1, 0.6, 3)
        amps = rng.uniform(0.3, 1.0, 3)
        amps *= amplitude / amps.sum()
        phases = rng.uniform(0, 2 * np.pi, 3)
        return sum(a * (np.sin(2 * np.pi * f * t + p) - np.sin(p)) for a, f, p in zip(amps, freqs, phases)) * ramp

    for j in _moving(robot):
        if j.kind == "spherical":
            _turn(q, j, np.stack([wave(np.radians(RANDOM_DEG)) for _ in range(3)], axis=1))
        elif j.kind == "prismatic":
            q[:, j.idx_q] += wave(RANDOM_SLIDE * _slide_range(robot, j))
        else:
            q[:, j.idx_q] += wave(np.radians(RANDOM_DEG))
    if robot.root == "free":
        rest = pin.XYZQUATToSE3(robot.q_rest[:7])
        drift = rng.uniform(-1, 1, (2, 3)) * 0.1 * robot.height
        turn = rng.uniform(-1, 1, 3) * np.radians(20.0)
        for f in range(frames):
            s = np.sin(2 * np.pi * 0.1 * t[f]) * ramp[f]
            R = pin.exp3(turn * s) @ rest.rotation
            p = (
                rest.translation
                + drift[0] * s
                + drift[1] * (1 - np.cos(2 * np.pi * 0.07 * t[f])) * ramp[f]
            )
            q[f, :7] = pin.SE3ToXYZQUAT(pin.SE3(R, p))
    return q


def closed_motion(robot: Robot, q: np.ndarray) -> np.ndarray:
    """Configurations ``q`` (T, nq) projected onto the loop closures frame by frame: frame f
    from frame f - 1's projection moved by the step q[f - 1] -> q[f] (tangent space), so a
    continuous motion stays continuous; a frame that cannot be closed repeats the last.
    ``q`` itself for a tree."""
    if not robot.closures or not len(q):
        return q
    model = robot.model
    out = np.empty_like(q)
    out[0] = robot.project(q[0])
    for f in range(1, len(q)):
        try:
            out[f] = robot.project(pin.integrate(model, out[f - 1], pin.difference(model, q[f - 1], q[f])))
        except RobotError:
            out[f] = out[f - 1]
    return out


def make_motion(
    robot: Robot, name: str, frames: int, rng: np.random.Generator | None = None
) -> np.ndarray:
    """Configurations (frames, nq) of motion ``name`` (one of :data:`MOTIONS`), projected
    onto the loop closures of a model that has some (:func:`closed_motion`)."""
    if frames < 1:
        raise Kms2pinError(f"a motion needs at least one frame, not {frames}")
    if name == "sweep":
        return closed_motion(robot, robot.clamp(sweep(robot, frames)))
    if name == "walk":
        return closed_motion(robot, robot.clamp(walk(robot, frames)))
    if name == "random":
        q = random_smooth(robot, frames, rng if rng is not None else np.random.default_rng(0))
        return closed_motion(robot, robot.clamp(q))
    raise Kms2pinError(f"unknown motion '{name}'; choose one of {', '.join(MOTIONS)}")
