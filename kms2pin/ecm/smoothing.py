"""Zero-lag low-pass smoothing of a tracked trajectory, joint by joint (offline).

Measured kinematics are low-pass filtered before angles are read off them, in gait
analysis typically by a Butterworth filter at about 6 Hz run forwards and then
backwards, which leaves no lag (Winter, *Biomechanics and Motor Control of Human
Movement*).  :func:`smooth` does that to a track: a Butterworth low-pass of order
``order`` at ``cutoff_hz`` (``scipy.signal.butter``), run both ways
(``scipy.signal.filtfilt``: twice the order, -6 dB at the cutoff), on each joint's
coordinates in a form that keeps the pose valid:

- a revolute angle, unwrapped (so that -179° to 179° is a small step); a prismatic
  offset and a free root's position as they are;
- every rotation (a spherical joint, a free root's orientation) as its unit quaternion
  (x, y, z, w), each frame's sign chosen nearest the previous frame's, filtered
  component by component and normalized again: a rotation about a fixed axis stays
  about that axis, and its angle is the low-pass of the angle to within the
  curvature of the quaternion's path over the filter's few frames (a fraction of a
  degree for the wiggles of a track).

The result is clipped into the joint limits and, with loop closures, projected back
onto them (:meth:`~kms2pin.robot.Robot.project`).  It uses frames on both sides of each
frame, so it smooths a finished track, not one being tracked.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import butter, filtfilt

from ..errors import OptionError, RobotError
from ..robot import Robot

__all__ = ["smooth"]


def smooth(robot: Robot, q: np.ndarray, fps: float, cutoff_hz: float, order: int = 2) -> np.ndarray:
    """(frames, nq) configurations ``q`` of ``robot`` (a frame every 1/``fps`` s) low-pass
    filtered at ``cutoff_hz`` (module docstring).  A sequence of fewer than two frames
    comes back as it is.  Raises :class:`OptionError` for a cutoff not between 0 and
    half the frame rate (Nyquist) or an order below 1."""
    fps, cutoff_hz = float(fps), float(cutoff_hz)
    if not (np.isfinite(fps) and fps > 0):
        raise OptionError(f"fps must be a positive number of frames per second, not {fps:g}")
    if not 0.0 < cutoff_hz < fps / 2:
        raise OptionError(f"the smoothing cutoff must be above 0 and below half the frame rate "
                          f"({fps / 2:g} Hz at {fps:g} frames/s), not {cutoff_hz:g} Hz")
    if int(order) != order or order < 1:
        raise OptionError(f"the smoothing filter's order must be a whole number from 1, not {order!r}")
    q = np.array(q, dtype=float)
    if q.ndim != 2 or q.shape[1] != robot.nq:
        raise OptionError(f"q must have shape (frames, nq) with nq = {robot.nq}, not {q.shape}")
    if len(q) < 2:
        return q
    b, a = butter(int(order), cutoff_hz / (fps / 2))
    pad = min(3 * max(len(a), len(b)), len(q) - 1)  # filtfilt's default, or what a short track allows

    def low(x: np.ndarray) -> np.ndarray:
        return filtfilt(b, a, x, axis=0, padlen=pad)

    out = q.copy()
    for j in robot.joints:
        s = slice(j.idx_q, j.idx_q + j.nq)
        if j.kind == "free":
            out[:, j.idx_q : j.idx_q + 3] = low(q[:, j.idx_q : j.idx_q + 3])
            r = slice(j.idx_q + 3, j.idx_q + 7)
            out[:, r] = _rotations(q[:, r], low)
        elif j.kind == "spherical":
            out[:, s] = _rotations(q[:, s], low)
        elif j.nq == 2:  # an unbounded revolute joint: (cos, sin)
            angle = low(np.unwrap(np.arctan2(q[:, j.idx_q + 1], q[:, j.idx_q])))
            out[:, s] = np.column_stack([np.cos(angle), np.sin(angle)])
        elif j.kind == "revolute":
            out[:, s] = low(np.unwrap(q[:, s], axis=0))
        else:
            out[:, s] = low(q[:, s])
    out = robot.clamp(out)
    if robot.closures:
        for k in range(len(out)):
            try:
                out[k] = robot.project(out[k])
            except RobotError:
                out[k] = q[k]  # where the smoothed pose cannot be closed, the tracked one
    return out


def _rotations(quats: np.ndarray, low) -> np.ndarray:
    """(frames, 4) unit quaternions made sign-continuous, filtered by ``low`` and normalized."""
    x = quats / np.linalg.norm(quats, axis=1, keepdims=True)
    flip = np.sign(np.einsum("ij,ij->i", x[1:], x[:-1]))
    flip[flip == 0] = 1.0
    x[1:] *= np.cumprod(flip)[:, None]
    y = low(x)
    return y / np.linalg.norm(y, axis=1, keepdims=True)
