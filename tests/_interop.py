"""Helpers for the tests that load kms2pin's exports in other tools (Pinocchio's own
URDF parser, urdfdom, MuJoCo): configurations mapped between models by joint name."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin

from kms2pin import parse
from kms2pin.model import alignment_matrix
from kms2pin.robot import Robot

SPECS = Path(__file__).resolve().parents[1] / "specs"
#: Every spec of the repository: the thesis's four, the two with joint limits, ours (human,
#: gantry: spherical and prismatic joints; fourbar, delta, stewart: kinematic loops).
ALL_SPECS = sorted(SPECS.rglob("*.kms"))


def _one_joint_to_the_inertial_frame(path: Path) -> bool:
    return all(len(s.children(None)) == 1 for s in parse(path).systems)


#: The (spec, root) pairs the export tests run: every spec with its own root, and with a free
#: root where the spec has one joint to the inertial frame (the loop mechanisms are anchored
#: to it at several points).
EXPORT_CASES = [(p, "spec") for p in ALL_SPECS] + [(p, "free") for p in ALL_SPECS
                                                   if _one_joint_to_the_inertial_frame(p)]


def check_urdf_exe() -> str:
    """urdfdom's ``check_urdf`` (Debian liburdfdom-tools)."""
    exe = Path(sys.executable).with_name("check_urdf")
    return str(exe) if exe.exists() else (shutil.which("check_urdf") or "check_urdf")


def random_q(robot: Robot, rng: np.random.Generator) -> np.ndarray:
    """A random configuration of ``robot``: every revolute angle uniform in a full turn (within
    the spec's limits where it has them), a free root anywhere within 2 units, turned at random."""
    q = robot.random_configuration(rng, 180.0)
    limited = np.flatnonzero(np.isfinite(robot.lower_limits))
    q[limited] = rng.uniform(robot.lower_limits[limited], robot.upper_limits[limited])
    if robot.root == "free":
        axis = rng.normal(size=3)
        R = pin.exp3(axis / np.linalg.norm(axis) * rng.uniform(0.0, np.pi))
        q[:7] = pin.SE3ToXYZQUAT(pin.SE3(R, rng.uniform(-2.0, 2.0, 3)))
    return q


def angle_of(robot: Robot, name: str, q: np.ndarray) -> np.ndarray:
    """The coordinates in ``q`` of the exported joint ``name``: a kms2pin joint's own (the
    root's seven, an angle in radians, an offset), or one of a spherical joint's three URDF
    joints ``<joint>_x|y|z`` (its X-Y-Z angle, radians)."""
    if robot.model.existJointName(name):
        j = robot.model.joints[robot.model.getJointId(name)]
        if not (j.nq == 4 and j.nv == 3):  # not a spherical joint's quaternion
            return q[j.idx_q : j.idx_q + j.nq]
    k = list(robot.coordinate_names).index(name)
    return np.radians(np.atleast_2d(robot.coordinates(q))[0, k : k + 1])


def urdf_joint_names(robot: Robot) -> list[str]:
    """The exported URDF's movable joints, in kms2pin's order: a spherical joint's three."""
    return [n for j in robot.joints for n in ((j.name,) if j.kind != "spherical" else j.names)]


def pinocchio_q(model: pin.Model, robot: Robot, q: np.ndarray) -> np.ndarray:
    """``q`` of kms2pin's ``robot`` as a configuration of ``model``, an external Pinocchio
    model of the same joints (by name): a ``continuous`` joint there is revolute-unbounded,
    (cos, sin) of the angle."""
    out = pin.neutral(model)
    for jid in range(1, model.njoints):
        j = model.joints[jid]
        x = angle_of(robot, model.names[jid], q)
        out[j.idx_q : j.idx_q + j.nq] = [np.cos(x[0]), np.sin(x[0])] if j.nq == 2 and len(x) == 1 else x
    return out


def mujoco_qpos(mj_model, robot: Robot, q: np.ndarray) -> np.ndarray:
    """``q`` of kms2pin's ``robot`` as MuJoCo's qpos of the same joints (by name): a hinge's
    angle or a slide's offset, a free joint's x y z then quaternion w x y z (Pinocchio's is
    x y z w), a ball's rotation in the child's aligned frame, R_alignᵀ R R_align (the MJCF
    export's documented convention; R_align of eq. 2.12)."""
    import mujoco

    qpos = mj_model.qpos0.copy()
    spec = {j.name: j for j in robot.system.joints}
    for i in range(mj_model.njnt):
        joint = mj_model.joint(i)
        a = int(joint.qposadr[0])
        if mj_model.jnt_type[i] == mujoco.mjtJoint.mjJNT_BALL:
            j = robot.model.joints[robot.model.getJointId(joint.name)]
            x, y, z, w = q[j.idx_q : j.idx_q + 4] / np.linalg.norm(q[j.idx_q : j.idx_q + 4])
            R = pin.Quaternion(w, x, y, z).toRotationMatrix()
            A = alignment_matrix(np.asarray(spec[joint.name].parent_bvec.orient),
                                 np.asarray(spec[joint.name].child_bvec.orient))
            b = pin.Quaternion(A.T @ R @ A)
            qpos[a : a + 4] = [b.w, b.x, b.y, b.z]
            continue
        x = angle_of(robot, joint.name, q)
        if mj_model.jnt_type[i] == mujoco.mjtJoint.mjJNT_FREE:
            qpos[a : a + 7] = [*x[:3], x[6], *x[3:6]]
        else:
            qpos[a] = x[0]
    return qpos


def mujoco_kinematics(mj_model, qpos: np.ndarray):
    """MuJoCo's data after forward kinematics at ``qpos``."""
    import mujoco

    data = mujoco.MjData(mj_model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(mj_model, data)
    return data


def body_frame(robot: Robot, name: str) -> pin.SE3:
    """world_T_link of body ``name`` (its BODY frame) after ``robot.forward``."""
    return robot.data.oMf[robot.model.getFrameId(name, pin.FrameType.BODY)]
