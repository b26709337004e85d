"""The compiled Pinocchio models obey the thesis's kinematics (§2.2).

* every joint constraint (eq. 2.13, 2.15, and their forms for spherical and prismatic
  joints) holds in Pinocchio's body poses;
* forward kinematics equal an independent NumPy implementation of eq. 2.4, 2.12,
  2.14 and 2.16 written here (it does not use kms2pin.model's helpers), with a
  spherical joint's R_ij = R(quaternion) R_align and a prismatic joint's child point
  d o_ij from the parent's;
* default angles: the tree, not the argument order, picks parent and child; the
  angle is a right-handed rotation of the child about the parent end's axis;
* maximal coordinates satisfy eq. 2.6-2.8 (and eq. 2.9-2.10 as printed do not);
* body Jacobians equal finite differences taken with pin.integrate;
* the SRDF rest state holds the spec's default angles.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest
from conftest import MIXED_JOINTS, OUR_SPECS, SPEC_NAMES, SPECS

import kms2pin

TOL = 1e-10
N_CONFIGS = 20


@pytest.fixture(scope="module", params=(*SPEC_NAMES, *OUR_SPECS, "mixed"))
def robots(request):
    """(spec robot, free-root robot) of one spec (``mixed``: conftest.MIXED_JOINTS)."""
    spec = kms2pin.parse(MIXED_JOINTS) if request.param == "mixed" else SPECS / f"{request.param}.kms"
    return kms2pin.load(spec), kms2pin.load(spec, root="free")


# ----------------------------------------------------------------------------- independent maths


def rot(v, theta: float) -> np.ndarray:
    """Eq. 2.4: right-handed rotation by theta (radians) about the unit axis v."""
    v1, v2, v3 = v
    c, s = math.cos(theta), math.sin(theta)
    t = 1.0 - c
    return np.array([
        [v1 * v1 * t + c, v2 * v1 * t - v3 * s, v3 * v1 * t + v2 * s],
        [v1 * v2 * t + v3 * s, v2 * v2 * t + c, v3 * v2 * t - v1 * s],
        [v1 * v3 * t - v2 * s, v2 * v3 * t + v1 * s, v3 * v3 * t + c],
    ])  # fmt: skip


def perpendicular(o) -> np.ndarray:
    """o x e_k / |.|, e_k the basis vector least aligned with o (lowest index on ties)."""
    a = np.abs(np.asarray(o, dtype=float))
    k = min(range(3), key=lambda i: (a[i], i))
    e = np.zeros(3)
    e[k] = 1.0
    w = np.cross(o, e)
    return w / np.linalg.norm(w)


def r_align(o_ij, o_ji) -> np.ndarray:
    """Eq. 2.12: the rotation taking the child's axis o_ji onto the parent's axis o_ij:
    about v = o_ji x o_ij / |.| by acos(o_ij . o_ji); antiparallel: 180 deg about
    ``perpendicular(o_ji)``; parallel: identity."""
    o_ij, o_ji = np.asarray(o_ij, float), np.asarray(o_ji, float)
    cross = np.cross(o_ji, o_ij)
    n = np.linalg.norm(cross)
    dot = float(np.dot(o_ij, o_ji))
    if n < 1e-12:
        return np.eye(3) if dot > 0 else rot(perpendicular(o_ji), math.pi)
    return rot(cross / n, math.acos(max(-1.0, min(1.0, dot))))


def euler_to_matrix(t0, t1, t2, t3) -> np.ndarray:
    """Eq. 2.7."""
    return np.array([
        [1 - 2 * t2 * t2 - 2 * t3 * t3, 2 * (t1 * t2 - t0 * t3), 2 * (t1 * t3 + t0 * t2)],
        [2 * (t1 * t2 + t0 * t3), 1 - 2 * t1 * t1 - 2 * t3 * t3, 2 * (t2 * t3 - t0 * t1)],
        [2 * (t1 * t3 - t0 * t2), 2 * (t2 * t3 + t0 * t1), 1 - 2 * t1 * t1 - 2 * t2 * t2],
    ])  # fmt: skip


def preorder(system) -> list:
    """The system's joints, parents before children, by our own tree walk."""
    children: dict = {}
    for j in system.joints:
        children.setdefault(j.parent, []).append(j)
    out, stack = [], list(reversed(children.get(None, [])))
    while stack:
        j = stack.pop()
        out.append(j)
        stack.extend(reversed(children.get(j.child, [])))
    assert len(out) == len(system.joints)
    return out


def joint_values(robot, q) -> dict[str, object]:
    """Each moving joint's value read from Pinocchio's q: a revolute angle (radians), a
    prismatic offset, a spherical joint's rotation matrix (eq. 2.7 of its quaternion,
    stored x, y, z, w)."""
    out = {}
    kinds = {j.name: j.kind for j in robot.system.joints}
    for name in robot.joint_names:
        jm = robot.model.joints[robot.model.getJointId(name)]
        if kinds.get(name) in ("revolute", "prismatic"):
            out[name] = float(q[jm.idx_q])
        elif kinds.get(name) == "spherical":
            x, y, z, w = q[jm.idx_q : jm.idx_q + 4] / np.linalg.norm(q[jm.idx_q : jm.idx_q + 4])
            out[name] = euler_to_matrix(w, x, y, z)
    return out


def forward_kinematics(robot, q) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """(mu_0j, R_0j) of every body by eq. 2.4, 2.12, 2.14, 2.16 (no Pinocchio)."""
    values = joint_values(robot, q)
    poses = {None: (np.zeros(3), np.eye(3))}
    for j in preorder(robot.system):
        a_ij, o_ij = np.array(j.parent_bvec.pos), np.array(j.parent_bvec.orient)
        a_ji, o_ji = np.array(j.child_bvec.pos), np.array(j.child_bvec.orient)
        if j.parent is None and robot.root == "free":
            # the free flyer places the root's LINK frame, which sits at its joint point a_ji
            p, (x, y, z, w) = q[:3], q[3:7] / np.linalg.norm(q[3:7])
            R_j = euler_to_matrix(w, x, y, z)
            poses[j.child] = (p - R_j @ a_ji, R_j)
            continue
        mu_i, R_i = poses[j.parent]
        R_ij = r_align(o_ij, o_ji)  # eq. 2.12: fixed and prismatic joints
        if j.kind == "revolute":
            R_ij = rot(o_ij, values[j.name]) @ R_ij  # eq. 2.16
        elif j.kind == "spherical":
            R_ij = values[j.name] @ R_ij
        elif j.kind == "prismatic":
            a_ij = a_ij + values[j.name] * o_ij  # the child's point slides along o_ij
        R_j = R_i @ R_ij  # eq. 2.11
        poses[j.child] = (mu_i + R_i @ a_ij - R_j @ a_ji, R_j)  # eq. 2.14
    return poses


def random_q(robot, rng: np.random.Generator) -> np.ndarray:
    """Every revolute angle anywhere in +-180 deg, every prismatic offset within its limits
    (+-1 without), every spherical joint and a free flyer any rotation (a free flyer
    anywhere within +-5)."""
    q = robot.q_rest.copy()
    kinds = {j.name: j.kind for j in robot.system.joints}
    for name in robot.joint_names:
        jm = robot.model.joints[robot.model.getJointId(name)]
        kind, i = kinds.get(name, "free"), jm.idx_q
        if kind == "revolute":
            q[i] = rng.uniform(-math.pi, math.pi)
        elif kind == "prismatic":
            lo, hi = (robot.lower_limits[i], robot.upper_limits[i]) if np.isfinite(robot.lower_limits[i]) else (-1, 1)
            q[i] = rng.uniform(lo, hi)
        elif kind in ("spherical", "free"):
            quat = rng.normal(size=4)
            k = i + (3 if kind == "free" else 0)
            q[k : k + 4] = quat / np.linalg.norm(quat)
            if kind == "free":
                q[:3] = rng.uniform(-5, 5, 3)
    return q


def configurations(robot, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [robot.q_rest] + [random_q(robot, rng) for _ in range(N_CONFIGS)]


def poses_of(robot, q) -> dict:
    return {name: (M.translation.copy(), M.rotation.copy()) for name, M in zip(robot.bodies, robot.body_poses(q))}


# ----------------------------------------------------------------------------- a. constraints


@pytest.mark.parametrize("root", ["spec", "free"])
def test_every_joint_constraint_holds(robots, root):
    robot = robots[root == "free"]
    checked = 0
    for q in configurations(robot, seed=1):
        poses, values = poses_of(robot, q), joint_values(robot, q)
        poses[None] = (np.zeros(3), np.eye(3))
        for j in robot.system.joints:
            if j.parent is None and root == "free":
                continue  # the free flyer replaces the joint to the inertial frame
            (mu_i, R_i), (mu_j, R_j) = poses[j.parent], poses[j.child]
            a_ij, o_ij = np.array(j.parent_bvec.pos), np.array(j.parent_bvec.orient)
            a_ji, o_ji = np.array(j.child_bvec.pos), np.array(j.child_bvec.orient)
            p_i, p_j = mu_i + R_i @ a_ij, mu_j + R_j @ a_ji  # the two ends' points in the world
            if j.kind == "prismatic":
                # the child's point on the line through the parent's along R_i o_ij, at the offset
                u = R_i @ o_ij
                np.testing.assert_allclose(np.cross(u, p_j - p_i), 0.0, atol=TOL, rtol=0)
                assert (p_j - p_i) @ u == pytest.approx(values[j.name], abs=TOL)
            else:  # eq. 2.13 / 2.15: both ends of the joint at one world point
                np.testing.assert_allclose(p_i, p_j, atol=TOL, rtol=0)
            if j.kind == "revolute":  # eq. 2.15: the joint axes aligned
                np.testing.assert_allclose(R_i @ o_ij, R_j @ o_ji, atol=TOL, rtol=0)
            if j.kind in ("fixed", "prismatic"):  # eq. 2.12 / 2.13: the whole relative rotation is fixed
                np.testing.assert_allclose(R_i.T @ R_j, r_align(o_ij, o_ji), atol=TOL, rtol=0)
            if j.kind == "spherical":  # any relative rotation: the quaternion's, then R_align
                np.testing.assert_allclose(R_i.T @ R_j, values[j.name] @ r_align(o_ij, o_ji), atol=TOL, rtol=0)
            checked += 1
    assert checked >= (N_CONFIGS + 1) * (len(robot.system.joints) - 1)


def test_pose_rotations_are_proper(robots):
    robot = robots[0]
    for q in configurations(robot, seed=2)[:5]:
        for _, R in poses_of(robot, q).values():
            np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
            assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)


# ----------------------------------------------------------------------------- b. forward kinematics


@pytest.mark.parametrize("root", ["spec", "free"])
def test_forward_kinematics_match_an_independent_implementation(robots, root):
    robot = robots[root == "free"]
    for q in configurations(robot, seed=3):
        ours = forward_kinematics(robot, q)
        theirs = poses_of(robot, q)
        for name in robot.bodies:
            np.testing.assert_allclose(theirs[name][0], ours[name][0], atol=TOL, rtol=0, err_msg=name)
            np.testing.assert_allclose(theirs[name][1], ours[name][1], atol=TOL, rtol=0, err_msg=name)


def test_our_perpendicular_axis_rule_is_the_compilers():
    from kms2pin.model import perpendicular_axis

    rng = np.random.default_rng(4)
    vectors = [np.eye(3)[k] * s for k in range(3) for s in (1, -1)]
    vectors += [
        np.array(v, float) / np.linalg.norm(v) for v in ((1, 1, 0), (0, 1, 1), (1, 0, 1), (1, 1, 1), (1, -1, 1))
    ]
    vectors += [v / np.linalg.norm(v) for v in rng.normal(size=(20, 3))]
    for v in vectors:
        np.testing.assert_allclose(perpendicular_axis(v), perpendicular(v), atol=1e-15)
        assert abs(np.dot(perpendicular(v), v)) < 1e-15


ANTIPARALLEL = """
bvec origin {{ pos(0, 0, 0); orient(0, 0, 1); }}
rigidBodySystem s {{
    ellipsoidBody a {{ innerLam(1, 1, 1); outerLam(1, 1, 1);
        bvec base {{ pos(0, 0, 0); orient(0, 0, 1); }}
        bvec j {{ pos(1, 0, 0); orient({parent}); }} }}
    ellipsoidBody b {{ innerLam(1, 1, 1); outerLam(1, 1, 1);
        bvec j {{ pos(0, 0, -1); orient({child}); }} }}
    constraint fixed(b.j, a.j);
}}
constraint fixed(origin, s.a.base);
"""


@pytest.mark.parametrize("axis", ["0, 0, 1", "1, 2, 3", "0, -1, 0", "1, 1, 0", "-2, 0.5, 0.1"])
def test_fixed_joint_between_antiparallel_axes(axis):
    o = np.array([float(x) for x in axis.split(",")])
    o /= np.linalg.norm(o)
    neg = ", ".join(str(-float(x)) for x in axis.split(","))
    parallel = kms2pin.load(ANTIPARALLEL.format(parent=axis, child=axis))
    anti = kms2pin.load(ANTIPARALLEL.format(parent=axis, child=neg))
    R_par = parallel.body_pose(parallel.q_rest, "b").rotation
    R_anti = anti.body_pose(anti.q_rest, "b").rotation
    np.testing.assert_allclose(R_par, np.eye(3), atol=TOL)
    # the child's axis lies on the parent's ...
    np.testing.assert_allclose(R_anti @ -o, o, atol=TOL)
    # ... so the direction o of the child frame is exactly reversed relative to the parallel case
    np.testing.assert_allclose(R_anti @ o, -(R_par @ o), atol=TOL)
    # by the documented rule: 180 deg about o_ji x e_k
    np.testing.assert_allclose(R_anti, rot(perpendicular(-o), math.pi), atol=TOL)
    mu, _ = forward_kinematics(anti, anti.q_rest)["b"]
    np.testing.assert_allclose(anti.body_pose(anti.q_rest, "b").translation, mu, atol=TOL)


def test_antiparallel_z_axes_by_hand():
    """o_ji = -z: e_x is the least aligned (tie with e_y, lower index); o_ji x e_x = -y;
    180 deg about y maps x -> -x, z -> -z."""
    robot = kms2pin.load(ANTIPARALLEL.format(parent="0, 0, 1", child="0, 0, -1"))
    M = robot.body_pose(robot.q_rest, "b")
    np.testing.assert_allclose(M.rotation, np.diag([-1.0, 1.0, -1.0]), atol=TOL)
    # centre = joint point (1, 0, 0) - R (0, 0, -1) = (1, 0, -1)
    np.testing.assert_allclose(M.translation, [1, 0, -1], atol=TOL)


# ----------------------------------------------------------------------------- c. default angles

TWO_BODIES = """
bvec origin {{ pos(0, 0, 0); orient(0, 0, 1); }}
rigidBodySystem s {{
    ellipsoidBody a {{ innerLam(1, 1, 1); outerLam(1, 1, 1);
        bvec base {{ pos(0, 0, 0); orient(0, 0, 1); }}
        bvec j {{ pos(1, 0, 0); orient({parent_axis}); }} }}
    ellipsoidBody b {{ innerLam(1, 1, 1); outerLam(1, 1, 1);
        bvec j {{ pos(-1, 0, 0); orient({child_axis}); }} }}
    constraint revolute({first}, {second}, 90);
}}
constraint fixed(s.a.base, origin);
"""


@pytest.mark.parametrize("order", [("a.j", "b.j"), ("b.j", "a.j")])
@pytest.mark.parametrize(
    "parent_axis, child_axis, x_axis, centre",
    [
        # +90 deg about +z: b's x axis -> world +y; centre = (1,0,0) - Rz(90) (-1,0,0) = (1, 1, 0)
        ("0, 0, 1", "0, 0, 1", [0, 1, 0], [1, 1, 0]),
        # the parent end's axis is -z: +90 deg about -z: x -> -y, centre (1, -1, 0)
        ("0, 0, -1", "0, 0, -1", [0, -1, 0], [1, -1, 0]),
        # the child's own axis does not matter for the sense of rotation: about the parent's +z
        ("0, 0, 1", "0, 0, 2", [0, 1, 0], [1, 1, 0]),
    ],
)
def test_default_angle_is_a_right_handed_rotation_of_the_child_about_the_parent_axis(
    order, parent_axis, child_axis, x_axis, centre
):
    text = TWO_BODIES.format(parent_axis=parent_axis, child_axis=child_axis, first=order[0], second=order[1])
    robot = kms2pin.load(text)
    M = robot.body_pose(robot.q_rest, "b")
    np.testing.assert_allclose(M.rotation[:, 0], x_axis, atol=TOL)
    np.testing.assert_allclose(M.translation, centre, atol=TOL)
    # a: the root, at the origin, unrotated
    np.testing.assert_allclose(robot.body_pose(robot.q_rest, "a").homogeneous, np.eye(4), atol=TOL)


def test_argument_order_of_a_constraint_does_not_change_the_model():
    text = (SPECS / "lowerbody.kms").read_text()
    old = "revolute(leftShin.knee, leftThigh.knee, 2*postureDelta)"
    swapped = text.replace(old, "revolute(leftThigh.knee, leftShin.knee, 2*postureDelta)")
    assert swapped != text
    a, b = kms2pin.load(text), kms2pin.load(swapped)
    assert a.system.joint_of("leftShin") == b.system.joint_of("leftShin")
    assert a.urdf == b.urdf and a.srdf == b.srdf
    np.testing.assert_array_equal(a.q_rest, b.q_rest)


def sagittal_mirror_error(robot) -> float:
    """Largest difference between each left body and the mirror image (across the pelvis's
    x = 0 plane) of its right twin: centres, and the direction from the body's joint to its
    parent towards its centre, both in the pelvis frame."""
    poses = poses_of(robot, robot.q_rest)
    mu_p, R_p = poses["pelvis"]

    def in_pelvis(name):
        mu, R = poses[name]
        a_ji = np.array(robot.system.joint_of(name).child_bvec.pos)
        return np.concatenate([R_p.T @ (mu - mu_p), R_p.T @ (-R @ a_ji)])

    mirror = np.diag([-1.0, 1, 1, -1, 1, 1])
    lefts = [n for n in robot.bodies if n.startswith("left")]
    assert len(lefts) >= 3
    return max(np.abs(in_pelvis(n) - mirror @ in_pelvis("right" + n[4:])).max() for n in lefts)


@pytest.mark.parametrize("name", ["lowerbody", "fullbody"])
def test_left_and_right_limbs_are_mirror_images_at_rest(name):
    """Both knees bend the same way although the left knee's constraint is written
    child first and the right knee's parent first (see specs/README.md)."""
    robot = kms2pin.load(SPECS / f"{name}.kms")
    assert sagittal_mirror_error(robot) < 1e-10
    # not trivially: the knee is bent (the shin is not parallel to the thigh) ...
    poses = poses_of(robot, robot.q_rest)
    thigh_z, shin_z = poses["leftThigh"][1][:, 2], poses["leftShin"][1][:, 2]
    assert np.degrees(np.arccos(np.clip(thigh_z @ shin_z, -1, 1))) == pytest.approx(20, abs=1e-9)
    # ... and bending one knee the other way breaks the symmetry
    text = (SPECS / f"{name}.kms").read_text()
    bent = text.replace(
        "revolute(leftShin.knee, leftThigh.knee, 2*postureDelta)",
        "revolute(leftShin.knee, leftThigh.knee, -2*postureDelta)",
    )
    assert bent != text
    assert sagittal_mirror_error(kms2pin.load(bent)) > 0.01


# ----------------------------------------------------------------------------- d. maximal coordinates


@pytest.mark.parametrize("root", ["spec", "free"])
def test_maximal_coordinates_are_centres_and_euler_parameters(robots, root):
    robot = robots[root == "free"]
    for q in configurations(robot, seed=5):
        poses = poses_of(robot, q)
        qm = robot.maximal_coordinates(q)
        qt = robot.maximal_coordinates(q, convention="thesis")
        assert qm.shape == qt.shape == (len(robot.bodies), 7)
        for i, name in enumerate(robot.bodies):
            mu, R = poses[name]
            for row in (qm[i], qt[i]):
                np.testing.assert_allclose(row[:3], mu, atol=TOL)  # eq. 2.8
                assert np.dot(row[3:], row[3:]) == pytest.approx(1.0, abs=1e-12)  # eq. 2.6
                np.testing.assert_allclose(euler_to_matrix(*row[3:]), R, atol=TOL)  # eq. 2.7
            assert qm[i, 3] >= 0  # default convention: theta0 >= 0
            np.testing.assert_allclose(np.abs(qm[i, 3:]), np.abs(qt[i, 3:]), atol=1e-12)
        assert_thesis_convention(qt)


def assert_thesis_convention(qt: np.ndarray) -> None:
    """§2.2.1: the first nonzero of theta1, theta2, theta3 is positive (|x| <= 1e-12 is zero)."""
    for row in qt:
        big = np.flatnonzero(np.abs(row[4:]) > 1e-12)
        if len(big):
            assert row[4 + big[0]] > 0, row
        else:
            assert row[3] > 0, row


def test_thesis_convention_ignores_rounding_noise():
    """PUMA link2 at rest is a half turn about (0, -1, 1)/sqrt2: theta1 is 1e-15 of rounding."""
    robot = kms2pin.load(SPECS / "puma600.kms")
    assert_thesis_convention(robot.maximal_coordinates(robot.q_rest, convention="thesis"))


def test_euler_parameters_of_simple_rotations():
    e = kms2pin.euler_parameters(rot([0, 0, 1], -math.pi / 2))
    np.testing.assert_allclose(e, [math.cos(math.pi / 4), 0, 0, -math.sin(math.pi / 4)], atol=1e-15)
    e = kms2pin.euler_parameters(rot([0, 0, 1], -math.pi / 2), "thesis")
    np.testing.assert_allclose(e, [-math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)], atol=1e-15)
    np.testing.assert_allclose(kms2pin.euler_parameters(np.eye(3), "thesis"), [1, 0, 0, 0])


@pytest.mark.parametrize(
    "R,match",
    [
        (np.diag([1.0, 1.0, -1.0]), r"det R = -1"),  # a reflection: orthogonal, det -1
        (-rot([1, 2, 3] / np.linalg.norm([1, 2, 3]), 0.7), r"det R = -1"),  # minus a rotation
        (2.0 * np.eye(3), r"R R\^T differs from the identity by 3"),  # R R^T = 4 I
        (rot([0, 0, 1], 0.3) + 1e-3, r"differs from the identity"),  # not orthogonal
        (np.eye(4), r"3 x 3"),
        (np.full((3, 3), np.nan), "not finite"),
    ],
)
def test_euler_parameters_refuse_a_matrix_that_is_not_a_rotation(R, match):
    with pytest.raises(kms2pin.RobotError, match=match):
        kms2pin.euler_parameters(R)


def test_euler_parameters_accept_a_rotation_with_rounding_noise():
    R = rot([0, 1, 0], 1.2) + 1e-9 * np.random.default_rng(3).standard_normal((3, 3))
    e = kms2pin.euler_parameters(R)
    np.testing.assert_allclose(e, [math.cos(0.6), 0, math.sin(0.6), 0], atol=1e-8)


def euler_by_eq_2_9_2_10(R) -> np.ndarray:
    """Eq. 2.9 and 2.10 exactly as printed (the first x case that is nonzero)."""
    r = lambda i, j: R[i - 1, j - 1]  # noqa: E731
    x = np.array([
        r(1, 3) - r(1, 3) * r(2, 2) + r(1, 2) * r(2, 3),
        r(1, 3) * r(2, 1) + r(2, 3) - r(1, 1) * r(2, 3),
        1 - r(1, 1) - r(1, 2) * r(2, 1) - r(2, 2) + r(1, 1) * r(2, 2),
    ])  # fmt: skip
    if np.linalg.norm(x) < 1e-12:
        x = np.array([r(1, 2), 1 - r(1, 1), 0.0])
    if np.linalg.norm(x) < 1e-12:
        x = np.array([1.0, 0.0, 0.0])
    v = x / np.linalg.norm(x)
    tr = np.trace(R)
    s = math.sqrt(max(0.0, 3 - tr)) / 2
    return np.array([math.sqrt(max(0.0, 1 + tr)) / 2, v[0] * s, v[1] * s, v[2] * s])


def test_eq_2_9_2_10_as_printed_lose_the_sense_of_rotation():
    """Why kms2pin does not use eq. 2.9-2.10: theta = acos((tr R - 1)/2) is never negative
    and the axis x of eq. 2.9 does not depend on the sense of rotation, so a rotation of
    -90 deg about z comes out as +90 deg about z (no sign change of all four fixes it)."""
    R = rot([0, 0, 1], -math.pi / 2)
    e = euler_by_eq_2_9_2_10(R)
    np.testing.assert_allclose(e, [math.sqrt(0.5), 0, 0, math.sqrt(0.5)], atol=1e-15)
    wrong = euler_to_matrix(*e)
    np.testing.assert_allclose(wrong, rot([0, 0, 1], math.pi / 2), atol=1e-15)
    assert np.abs(wrong - R).max() > 1.9
    assert np.abs(euler_to_matrix(*-e) - R).max() > 1.9
    # the formula is right for +90 deg, and kms2pin's parameters are right for both
    np.testing.assert_allclose(euler_to_matrix(*euler_by_eq_2_9_2_10(R.T)), R.T, atol=1e-15)
    np.testing.assert_allclose(euler_to_matrix(*kms2pin.euler_parameters(R)), R, atol=1e-15)


# ----------------------------------------------------------------------------- e. Jacobians


@pytest.mark.parametrize("root", ["spec", "free"])
def test_body_jacobian_matches_finite_differences(robots, root):
    robot = robots[root == "free"]
    model, eps = robot.model, 1e-6
    for q in configurations(robot, seed=6)[:3]:
        J = {name: robot.body_jacobian(q, name) for name in robot.bodies}
        fd = {name: np.zeros((6, model.nv)) for name in robot.bodies}
        for k in range(model.nv):
            dq = np.zeros(model.nv)
            dq[k] = eps
            plus = poses_of(robot, pin.integrate(model, q, dq))
            minus = poses_of(robot, pin.integrate(model, q, -dq))
            for name in robot.bodies:
                (mu1, R1), (mu0, R0) = plus[name], minus[name]
                fd[name][:3, k] = (mu1 - mu0) / (2 * eps)  # d mu / dq
                fd[name][3:, k] = pin.log3(R1 @ R0.T) / (2 * eps)  # world angular velocity
        for name in robot.bodies:
            assert J[name].shape == (6, model.nv)
            np.testing.assert_allclose(J[name], fd[name], atol=1e-6, err_msg=name)


# ----------------------------------------------------------------------------- f. rest state


def rotation_vector(r_deg) -> np.ndarray:
    """Exp(r): |r| degrees about r / |r| (eq. 2.4)."""
    r = np.radians(np.asarray(r_deg, dtype=float))
    n = np.linalg.norm(r)
    return np.eye(3) if n == 0 else rot(r / n, n)


def test_srdf_rest_state_holds_the_default_angles(robots):
    """Revolute joints: the default angle; prismatic: the default offset; spherical: three
    angles (a, b, c) of its URDF joints with Rx(a) Ry(b) Rz(c) = Exp(r); q_rest the same."""
    e = np.eye(3)
    for robot in robots:
        state = ET.fromstring(robot.srdf).find("group_state[@name='rest']")
        values = {j.get("name"): float(j.get("value")) for j in state.findall("joint") if j.get("name") != "root_joint"}
        assert (state.find("joint[@name='root_joint']") is not None) == (robot.root == "free")  # test_export_urdf
        moving = [j for j in robot.system.joints if j.kind != "fixed" and not (robot.root == "free" and j.parent is None)]
        expected_names = set()
        for j in moving:
            jm = robot.model.joints[robot.model.getJointId(j.name)]
            if j.kind == "spherical":
                names = [f"{j.name}_{a}" for a in "xyz"]
                expected_names.update(names)
                a, b, c = (values[n] for n in names)
                R = rotation_vector(j.default_rotation)
                np.testing.assert_allclose(rot(e[0], a) @ rot(e[1], b) @ rot(e[2], c), R, atol=1e-13)
                x, y, z, w = robot.q_rest[jm.idx_q : jm.idx_q + 4]
                np.testing.assert_allclose(euler_to_matrix(w, x, y, z), R, atol=1e-13)
                continue
            expected_names.add(j.name)
            rest = math.radians(j.default_angle) if j.kind == "revolute" else j.default_offset
            assert values[j.name] == pytest.approx(rest, abs=1e-14)
            assert robot.q_rest[jm.idx_q] == pytest.approx(rest, abs=1e-14)
        assert values.keys() == expected_names


def test_free_root_rest_pose_equals_the_spec_rest_pose(robots):
    spec, free = robots
    root_nq = {"fixed": 0, "revolute": 1, "prismatic": 1, "spherical": 4}[spec.system.joints[0].kind]
    assert free.nq == spec.nq + 7 - root_nq
    a, b = spec.body_poses(spec.q_rest), free.body_poses(free.q_rest)
    for name, Ma, Mb in zip(spec.bodies, a, b):
        np.testing.assert_allclose(Mb.translation, Ma.translation, atol=TOL, err_msg=name)
        np.testing.assert_allclose(Mb.rotation, Ma.rotation, atol=TOL, err_msg=name)


def test_rest_pose_root_joint_with_a_default_angle():
    """The joint to the inertial frame may have a default angle too; free root keeps it."""
    text = TWO_BODIES.format(parent_axis="0, 0, 1", child_axis="0, 0, 1", first="a.j", second="b.j")
    text = text.replace("constraint fixed(s.a.base, origin);", "constraint revolute(s.a.base, origin, 30);")
    text = text.replace(
        "bvec origin { pos(0, 0, 0); orient(0, 0, 1); }", "bvec origin { pos(1, 2, 3); orient(1, 0, 0); }"
    )
    spec, free = kms2pin.load(text), kms2pin.load(text, root="free")
    for name, Ma, Mb in zip(spec.bodies, spec.body_poses(spec.q_rest), free.body_poses(free.q_rest)):
        np.testing.assert_allclose(Mb.homogeneous, Ma.homogeneous, atol=TOL, err_msg=name)
    ours = forward_kinematics(spec, spec.q_rest)
    for name, M in zip(spec.bodies, spec.body_poses(spec.q_rest)):
        np.testing.assert_allclose(M.translation, ours[name][0], atol=TOL)
        np.testing.assert_allclose(M.rotation, ours[name][1], atol=TOL)


# ----------------------------------------------------------------------------- g. malformed q


def q_methods(robot, q) -> dict:
    """Every Robot method that takes a configuration, applied to q."""
    name = robot.bodies[-1]
    return {
        "forward": lambda: robot.forward(q),
        "body_pose": lambda: robot.body_pose(q, name),
        "body_poses": lambda: robot.body_poses(q),
        "maximal_coordinates": lambda: robot.maximal_coordinates(q),
        "body_jacobian": lambda: robot.body_jacobian(q, name),
    }


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_non_finite_configuration_is_refused_naming_the_first_bad_coordinate_and_its_joint(bad):
    robot = kms2pin.load(SPECS / "lowerbody.kms", root="free")
    q = np.full(robot.nq, bad)
    for call in q_methods(robot, q).values():
        with pytest.raises(kms2pin.RobotError, match=r"^q\[0\] \(x of joint 'root_joint'\) of 'lowerBodyBipedal' is "):
            call()
    knee = robot.model.joints[robot.model.getJointId("rightShin_knee")].idx_q
    q = robot.q_rest.copy()
    q[knee] = bad
    q[knee + 1] = bad
    for call in q_methods(robot, q).values():
        with pytest.raises(kms2pin.RobotError, match=rf"^q\[{knee}\] \(joint 'rightShin_knee'\)"):
            call()
    with pytest.raises(ValueError):  # what code catching bad arguments expects, as for OptionError
        robot.body_poses(q)


def test_a_zero_root_quaternion_is_refused():
    robot = kms2pin.load(SPECS / "lowerbody.kms", root="free")
    q = robot.q_rest.copy()
    q[3:7] = 0.0
    for call in q_methods(robot, q).values():
        with pytest.raises(kms2pin.RobotError, match=r"quaternion q\[3:7\].*\(x, y, z, w; scalar last\).*zero norm"):
            call()


def test_a_non_unit_root_quaternion_is_used_normalized():
    """q[3:7] is Pinocchio's (x, y, z, w): its rotation, by our eq. 2.7 with (w, x, y, z)."""
    robot = kms2pin.load(SPECS / "lowerbody.kms", root="free")
    unit = np.array([0.3, 0.2, -0.1, 0.9]) / np.linalg.norm([0.3, 0.2, -0.1, 0.9])
    q = robot.q_rest.copy()
    q[3:7] = unit
    scaled = q.copy()
    scaled[3:7] *= 2.5
    x, y, z, w = unit
    root_body = robot.bodies[0]
    rest = robot.body_pose(robot.q_rest, root_body)
    np.testing.assert_allclose(
        robot.body_pose(scaled, root_body).rotation, euler_to_matrix(w, x, y, z) @ rest.rotation, atol=TOL
    )
    np.testing.assert_allclose(robot.maximal_coordinates(scaled), robot.maximal_coordinates(q), atol=TOL)
    assert np.all(scaled[3:7] == 2.5 * unit)  # the caller's array is left alone
