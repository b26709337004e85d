"""Accuracy of a tracked trajectory against the truth (``kms2pin evaluate``)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from ..errors import InputDataError
from ..robot import Robot
from .tracker import Trajectory


def evaluate(
    robot: Robot, tracked: Trajectory, truth: Trajectory, camera_centre: np.ndarray | None = None
) -> dict:
    """Per-joint RMSE, body-centre error (% of height) overall, per frame and worst.

    ``joint_rmse_deg``: revolute angle errors, wrapped to (-180°, 180°] (a tracked angle
    360° off is exact), and for a spherical joint the angle of the rotation between the
    tracked and the true one; ``revolute_rmse_deg`` and ``spherical_rmse_deg`` are
    their RMS over the joints of each type; ``prismatic_rmse``: each prismatic joint's
    offset error (spec length units).

    Frames are compared in order; when the counts differ, the first ``frames`` (the
    shorter trajectory's count) are compared, silently: ``tracked_frames`` and
    ``truth_frames`` in the result give both counts for a caller to warn about (as
    ``kms2pin evaluate`` does).
    Raises :class:`InputDataError` when either trajectory is empty.

    ``camera_centre`` (one camera's centre, world frame): also split each body's centre
    error into its part along the ray from the camera through the body's true centre
    (``depth_error_pct``, the mean of its length) and its part across that ray, which the
    camera sees directly (``centre_error_across_rays_pct`` and its
    ``first_vs_last_ratio_across_rays``); the two parts are orthogonal, so each is at
    most the centre error.  One view gives a distance only through the apparent size,
    so with one camera the depth error is most of the error.
    """
    n = min(len(tracked), len(truth))
    if n == 0:
        which = "the tracked trajectory has" if len(truth) else "the true trajectory has" if len(tracked) else "both trajectories have"
        raise InputDataError(f"nothing to evaluate: {which} no frames")
    joints, offsets, kinds = _joint_errors(robot, tracked, truth, n)
    per_frame, depth, across = _centre_errors(robot, tracked, truth, n, camera_centre)
    rev = np.array([e for name, e in joints.items() if kinds[name] == "revolute"])
    sph = np.array([e for name, e in joints.items() if kinds[name] == "spherical"])
    m = min(30, n)

    def ratio(e: np.ndarray) -> float:
        head, tail = e[:m].mean(), e[-m:].mean()
        return float(tail / head) if head > 0 else float("inf")

    extra = {}
    if camera_centre is not None:
        extra = {
            "depth_error_pct": float(depth.mean()),
            "centre_error_across_rays_pct": float(across.mean()),
            "first_vs_last_ratio_across_rays": ratio(across),
        }
    return {
        "frames": n,
        "tracked_frames": len(tracked),
        "truth_frames": len(truth),
        "joint_rmse_deg": joints,
        "revolute_rmse_deg": float(np.sqrt(np.mean(rev**2))) if len(rev) else 0.0,
        "spherical_rmse_deg": float(np.sqrt(np.mean(sph**2))) if len(sph) else 0.0,
        "prismatic_rmse": offsets,
        "mean_centre_error_pct": float(per_frame.mean()),
        "worst_frame": int(per_frame.argmax()),
        "worst_frame_error_pct": float(per_frame.max()),
        "first_vs_last_ratio": ratio(per_frame),
        "per_frame_centre_error_pct": per_frame.tolist(),
        **extra,
    }


def _joint_errors(robot: Robot, tracked: Trajectory, truth: Trajectory, n: int):
    """Per joint: the RMSE (degrees) of revolute and spherical joints, of prismatic offsets
    (length units), and each joint's kind, over the first ``n`` frames."""
    model = robot.model
    d = np.array([pin.difference(model, truth.q[k], tracked.q[k]) for k in range(n)]).reshape(n, model.nv)
    joints, offsets, kinds = {}, {}, {}
    for j in robot.joints:
        dv = d[:, j.idx_v]
        if j.kind == "revolute":  # a point on the circle: compare modulo 2π, in (-π, π]
            joints[j.name] = float(np.degrees(np.sqrt(np.mean(((dv + np.pi) % (2 * np.pi) - np.pi) ** 2))))
        elif j.kind == "spherical":  # the angle of the relative rotation (|log3|)
            angle = np.linalg.norm(d[:, j.idx_v : j.idx_v + 3], axis=1)
            joints[j.name] = float(np.degrees(np.sqrt(np.mean(angle**2))))
        elif j.kind == "prismatic":
            offsets[j.name] = float(np.sqrt(np.mean(dv**2)))
        kinds[j.name] = j.kind
    return joints, offsets, kinds


def ray_parts(points: np.ndarray, truth: np.ndarray, camera_centre) -> tuple[np.ndarray, np.ndarray]:
    """Each error ``points - truth`` (..., 3; world) split along the ray from
    ``camera_centre`` through the true point (signed, towards the far side positive) and
    across it (its length): (...,) and (...,), in the points' units."""
    rays = truth - np.asarray(camera_centre, dtype=float)
    rays /= np.maximum(np.linalg.norm(rays, axis=-1, keepdims=True), 1e-300)
    along = np.sum((points - truth) * rays, axis=-1)
    return along, np.linalg.norm(points - truth - along[..., None] * rays, axis=-1)


def _centre_errors(robot: Robot, tracked: Trajectory, truth: Trajectory, n: int, camera_centre):
    """Per frame: the mean body-centre error (% of the height), and its parts along and
    across the camera's rays (when a camera centre is given)."""
    per_frame, depth, across = np.empty(n), np.empty(n), np.empty(n)
    scale = 100.0 / robot.height
    for k in range(n):
        a = robot.maximal_coordinates(tracked.q[k])[:, :3]
        b = robot.maximal_coordinates(truth.q[k])[:, :3]
        per_frame[k] = np.linalg.norm(a - b, axis=1).mean() * scale
        if camera_centre is not None:
            along, side = ray_parts(a, b, camera_centre)
            depth[k] = np.abs(along).mean() * scale
            across[k] = side.mean() * scale
    return per_frame, depth, across
