"""A pose file: a user's starting pose for ``kms2pin track --init POSE.json``.

``{"joints": {name: value}, "root": {"position": [x, y, z], "rotation": 3x3 |
"quaternion_xyzw": [x, y, z, w]}}``; the names are the trajectory CSV's
(:attr:`Robot.coordinate_names`: a revolute joint's angle and a spherical joint's
``<joint>_x|y|z`` angles in degrees, a prismatic joint's offset in spec length units);
joints left out keep their rest values, the root left out keeps its rest pose.  The position must be within +-1e6 (the spec's lengths'
range); the quaternion need not be unit (any non-zero one is normalized).
"""

from __future__ import annotations

import math
import os

import numpy as np
import pinocchio as pin

from ..errors import InputDataError, did_you_mean
from ..jsonfile import read_json
from ..lang.symbols import MAX_LENGTH
from ..robot import Robot, rotation_error

__all__ = ["read_pose_json"]


def _rotation(value, where: str) -> np.ndarray:
    if not (isinstance(value, list) and len(value) == 3 and all(_numbers(row, 3) for row in value)):
        raise InputDataError(f"{where}: root rotation must be a 3x3 matrix")
    R = np.array(value, dtype=float)
    off, det = rotation_error(R)
    if off > 1e-3 or det < 0:
        raise InputDataError(f"{where}: root rotation is not a rotation matrix (RᵀR ≠ I or det < 0)")
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def read_pose_json(robot: Robot, path: str | os.PathLike) -> np.ndarray:
    """The configuration of a pose file (module docstring); angles in degrees."""
    where = str(path)
    data = read_json(path, InputDataError)
    if not isinstance(data, dict):
        raise InputDataError(f"{where}: expected an object with 'joints' and/or 'root'")
    unknown = sorted(set(data) - {"joints", "root"})
    if unknown:
        raise InputDataError(f"{where}: unknown key(s) {', '.join(unknown)} (expected 'joints', 'root')")
    q = np.array(robot.q_rest, dtype=float)
    joints = data.get("joints", {})
    if not isinstance(joints, dict):
        raise InputDataError(f"{where}: 'joints' must be an object {{name: degrees}}")
    kinds = {n: j.kind for j in robot.joints if j.kind != "free" for n in j.names}
    for name, deg in joints.items():
        if name not in kinds:
            if f"{name}_x" in kinds:
                raise InputDataError(f"{where}: joint '{name}' is spherical: give {name}_x, {name}_y and "
                                     f"{name}_z (its X-Y-Z angles, degrees)")
            raise InputDataError(
                f"{where}: '{robot.system.name}' has no joint coordinate '{name}'{did_you_mean(name, kinds)}"
            )
        unit = "spec length units" if kinds[name] == "prismatic" else "degrees"
        if not _number(deg):
            raise InputDataError(f"{where}: joint '{name}': value must be a number ({unit}), not {deg!r}")
    q = robot.with_coordinates(q, {name: float(v) for name, v in joints.items()})
    if "root" in data:
        root = data["root"]
        if robot.root != "free":
            raise InputDataError(f"{where}: 'root' given but the model's root is not free (use --root free)")
        if not isinstance(root, dict):
            raise InputDataError(f"{where}: 'root' must be an object with 'position' and 'rotation'")
        T = pin.XYZQUATToSE3(q[:7])
        p, R = T.translation.copy(), T.rotation.copy()
        if "position" in root:
            pos = np.asarray(root["position"], dtype=float) if _numbers(root["position"], 3) else None
            if pos is None:
                raise InputDataError(f"{where}: root position must be [x, y, z]")
            if np.abs(pos).max() > MAX_LENGTH:
                raise InputDataError(f"{where}: root position must be within +-{MAX_LENGTH:g}, got {pos.tolist()}")
            p = pos
        if "rotation" in root and "quaternion_xyzw" in root:
            raise InputDataError(f"{where}: give the root's 'rotation' or 'quaternion_xyzw', not both")
        if "rotation" in root:
            R = _rotation(root["rotation"], where)
        elif "quaternion_xyzw" in root:
            if not _numbers(root["quaternion_xyzw"], 4):
                raise InputDataError(f"{where}: quaternion_xyzw must be [x, y, z, w]")
            v = np.array(root["quaternion_xyzw"], dtype=float)
            if not np.abs(v).max() > 0:
                raise InputDataError(f"{where}: quaternion_xyzw is zero")
            v /= np.abs(v).max()  # scaled first, so that huge or tiny values do not overflow
            x, y, z, w = v / np.linalg.norm(v)
            R = pin.Quaternion(w, x, y, z).toRotationMatrix()
        q[:7] = pin.SE3ToXYZQUAT(pin.SE3(R, p))
    return q


def _number(value) -> bool:
    """A JSON number (not a bool) that is a finite double."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:  # an integer beyond the doubles
        return False


def _numbers(value, n: int) -> bool:
    return isinstance(value, list) and len(value) == n and all(_number(v) for v in value)
