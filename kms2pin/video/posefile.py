"""A pose file: a user's starting pose for ``kms2pin track --init POSE.json``.

``{"joints": {name: degrees}, "root": {"position": [x, y, z], "rotation": 3x3 |
"quaternion_xyzw": [x, y, z, w]}}``; joints left out keep their rest angle, the root
left out keeps its rest pose.
"""

from __future__ import annotations

import os

import numpy as np
import pinocchio as pin

from ..errors import InputDataError, did_you_mean
from ..jsonfile import read_json
from ..robot import Robot, rotation_error

__all__ = ["read_pose_json"]


def _rotation(value, where: str) -> np.ndarray:
    R = np.asarray(value, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise InputDataError(f"{where}: root rotation must be a 3x3 matrix")
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
    model = robot.model
    joints = data.get("joints", {})
    if not isinstance(joints, dict):
        raise InputDataError(f"{where}: 'joints' must be an object {{name: degrees}}")
    names = {model.names[j]: j for j in range(1, model.njoints) if model.joints[j].nq == 1}
    for name, deg in joints.items():
        if name not in names:
            raise InputDataError(
                f"{where}: '{robot.system.name}' has no revolute joint '{name}'{did_you_mean(name, names)}"
            )
        if isinstance(deg, bool) or not isinstance(deg, (int, float)) or not np.isfinite(deg):
            raise InputDataError(f"{where}: joint '{name}': angle must be a number (degrees), not {deg!r}")
        q[model.joints[names[name]].idx_q] = np.radians(float(deg))
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
            p = pos
        if "rotation" in root and "quaternion_xyzw" in root:
            raise InputDataError(f"{where}: give the root's 'rotation' or 'quaternion_xyzw', not both")
        if "rotation" in root:
            R = _rotation(root["rotation"], where)
        elif "quaternion_xyzw" in root:
            if not _numbers(root["quaternion_xyzw"], 4):
                raise InputDataError(f"{where}: quaternion_xyzw must be [x, y, z, w]")
            x, y, z, w = map(float, root["quaternion_xyzw"])
            n = np.sqrt(x * x + y * y + z * z + w * w)
            if not n > 1e-9:
                raise InputDataError(f"{where}: quaternion_xyzw is zero")
            R = pin.Quaternion(w / n, x / n, y / n, z / n).toRotationMatrix()
        q[:7] = pin.SE3ToXYZQUAT(pin.SE3(R, p))
    return q


def _numbers(value, n: int) -> bool:
    return (
        isinstance(value, list)
        and len(value) == n
        and all(not isinstance(v, bool) and isinstance(v, (int, float)) and np.isfinite(v) for v in value)
    )
