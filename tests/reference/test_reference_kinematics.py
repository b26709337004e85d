"""Forward kinematics (eq. 2.12-2.16) against the constraints, the rest pose and Pinocchio."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

import kms2pin
from kms2pin.errors import RobotError
from kms2pin.reference import forward_kinematics, matrix_to_quat, quat_to_matrix, symbolic_model
from kms2pin.reference.rotations import axis_angle_matrix

from ._support import SPECS, load_system, moving_joints, random_configuration


def _spec(name: str):
    """A spec path of specs/, or the parsed conftest.MIXED_JOINTS for ``mixed``."""
    if name == "mixed":
        from conftest import MIXED_JOINTS

        return kms2pin.parse(MIXED_JOINTS)
    return SPECS / f"{name}.kms"

SEED = 7


def test_forward_kinematics_at_random_angles_satisfies_every_constraint(system, root, model):
    rng = np.random.default_rng(SEED)
    for _ in range(5):
        q, _, _ = random_configuration(system, rng, root)
        c = model.C(q)
        worst = int(np.argmax(np.abs(c)))
        assert abs(c[worst]) < 1e-10, model.labels[worst]


def test_forward_kinematics_without_angles_uses_the_spec_default_angles(system):
    defaults = {j.name: np.radians(j.default_angle) for j in system.joints if j.kind == "revolute"}
    np.testing.assert_array_equal(forward_kinematics(system), forward_kinematics(system, defaults))
    moved = dict(defaults)
    name = next(iter(moved))
    moved[name] += 0.3
    assert not np.allclose(forward_kinematics(system), forward_kinematics(system, moved))


def test_free_root_without_a_pose_sits_where_the_spec_root_joint_puts_it(system):
    np.testing.assert_allclose(forward_kinematics(system, root="free"), forward_kinematics(system), atol=1e-15)


def test_free_root_pose_places_the_root_body_and_carries_the_tree_rigidly(system):
    rng = np.random.default_rng(SEED + 1)
    base = forward_kinematics(system)
    mu = rng.normal(size=3)
    th = rng.normal(size=4)
    th /= np.linalg.norm(th)
    moved = forward_kinematics(system, root_pose=(mu, th), root="free")
    np.testing.assert_allclose(moved[0, :3], mu, atol=1e-15)
    np.testing.assert_allclose(moved[0, 3:], th, atol=1e-15)
    # the whole tree moves by the rigid motion that takes the root from base to moved
    R0, R1 = quat_to_matrix(base[0, 3:]), quat_to_matrix(th)
    G = R1 @ R0.T
    for i in range(len(system.bodies)):
        np.testing.assert_allclose(moved[i, :3], mu + G @ (base[i, :3] - base[0, :3]), atol=1e-12)
        np.testing.assert_allclose(quat_to_matrix(moved[i, 3:]), G @ quat_to_matrix(base[i, 3:]), atol=1e-12)


def test_turning_a_revolute_joint_turns_its_child_right_handedly_about_the_joint_axis_in_the_world():
    system = load_system("fullbody")
    joint = system.joint_of("leftShin")
    i, p = 2, 1  # leftShin, leftThigh
    assert system.bodies[i].name == "leftShin" and system.bodies[p].name == "leftThigh"
    q0 = forward_kinematics(system, {joint.name: 0.0})
    q1 = forward_kinematics(system, {joint.name: 0.4})
    axis_world = quat_to_matrix(q0[p, 3:]) @ np.asarray(joint.parent_bvec.orient)
    pivot = q0[p, :3] + quat_to_matrix(q0[p, 3:]) @ np.asarray(joint.parent_bvec.pos)
    G = axis_angle_matrix(axis_world, 0.4)
    np.testing.assert_allclose(quat_to_matrix(q1[i, 3:]), G @ quat_to_matrix(q0[i, 3:]), atol=1e-13)
    np.testing.assert_allclose(q1[i, :3], pivot + G @ (q0[i, :3] - pivot), atol=1e-13)
    np.testing.assert_allclose(q1[:i], q0[:i], atol=0)  # bodies before it do not move


def test_at_angle_zero_the_joint_axes_coincide_in_the_world(system):
    angles = {j.name: np.zeros(3) if j.kind == "spherical" else 0.0 for j in moving_joints(system)}
    q = forward_kinematics(system, angles)
    index = {b.name: k for k, b in enumerate(system.bodies)}
    for k, j in enumerate(system.joints):
        R_p = np.eye(3) if j.parent is None else quat_to_matrix(q[index[j.parent], 3:])
        R_c = quat_to_matrix(q[k, 3:])
        np.testing.assert_allclose(
            R_p @ np.asarray(j.parent_bvec.orient), R_c @ np.asarray(j.child_bvec.orient), atol=1e-14
        )


def test_reference_kinematics_agree_with_the_pinocchio_robot(spec_name, root):
    """Cross-check of conventions with the URDF/Pinocchio side (not used by the reference)."""
    robot = kms2pin.load(_spec(spec_name), root=root)
    rng = np.random.default_rng(SEED + 2)
    kinds = {j.name: j.kind for j in robot.system.joints}
    for _ in range(3):
        qp = robot.random_configuration(rng)
        angles = {}
        for name in robot.joint_names:
            joint = robot.model.joints[robot.model.getJointId(name)]
            if kinds.get(name) in ("revolute", "prismatic"):
                angles[name] = float(qp[joint.idx_q])
            elif kinds.get(name) == "spherical":  # Pinocchio's quaternion (x, y, z, w) as a rotation vector
                x, y, z, w = qp[joint.idx_q : joint.idx_q + 4]
                angles[name] = pin.log3(quat_to_matrix([w, x, y, z]))
        pose = None
        if root == "free":
            qp[3:7] = rng.normal(size=4)
            qp[3:7] /= np.linalg.norm(qp[3:7])
            M = robot.body_poses(qp)[0]
            pose = (M.translation, matrix_to_quat(M.rotation))
        ours = forward_kinematics(robot.system, angles, pose, root=root)
        theirs = robot.maximal_coordinates(qp)
        np.testing.assert_allclose(ours[:, :3], theirs[:, :3], atol=1e-12)
        sign = np.where(np.einsum("ij,ij->i", ours[:, 3:], theirs[:, 3:]) < 0, -1.0, 1.0)
        np.testing.assert_allclose(ours[:, 3:], sign[:, None] * theirs[:, 3:], atol=1e-12)


def test_unknown_or_fixed_joint_names_are_refused_with_a_suggestion():
    system = load_system("fullbody")
    with pytest.raises(RobotError, match="did you mean 'leftShin_knee'"):
        forward_kinematics(system, {"leftShin_kne": 0.1})
    with pytest.raises(RobotError, match="fixed joint"):
        forward_kinematics(system, {"head_neck": 0.1})
    with pytest.raises(RobotError, match="root='free'"):
        forward_kinematics(system, root_pose=(np.zeros(3), np.array([1.0, 0, 0, 0])))


def test_forward_kinematics_euler_parameters_are_unit_with_nonnegative_theta0(system):
    q, _, _ = random_configuration(system, np.random.default_rng(SEED + 3))
    np.testing.assert_allclose(np.linalg.norm(q[:, 3:], axis=1), 1.0, atol=1e-15)
    assert np.all(q[:, 3] >= 0)
    assert symbolic_model(system).C(q).shape == (symbolic_model(system).nc,)
