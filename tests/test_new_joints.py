"""Spherical and prismatic joints (kms2pin's extension of the language) outside the
kinematics and the static update: the language's values, the URDF's three revolute
joints per spherical joint, ``check``, trajectory CSV columns, ``--pose``, the
synthetic motions, ``evaluate`` and ``synth``."""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest
from conftest import MIXED_JOINTS, SPECS

import kms2pin
from kms2pin.cli import main
from kms2pin.ecm import Trajectory, evaluate, make_motion
from kms2pin.viewer import PoseError, joint_sliders, parse_pose, pose_string

TOL = 1e-12


def rot(axis, angle: float) -> np.ndarray:
    """Eq. 2.4: right-handed rotation by ``angle`` (radians) about the unit ``axis``."""
    x, y, z = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    c, s, t = math.cos(angle), math.sin(angle), 1 - math.cos(angle)
    return np.array([[t * x * x + c, t * x * y - s * z, t * x * z + s * y],
                     [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
                     [t * x * z - s * y, t * y * z + s * x, t * z * z + c]])


def xyz(a: float, b: float, c: float) -> np.ndarray:
    """Rx(a) Ry(b) Rz(c), degrees."""
    e = np.eye(3)
    return rot(e[0], math.radians(a)) @ rot(e[1], math.radians(b)) @ rot(e[2], math.radians(c))


def quaternion_matrix(q) -> np.ndarray:
    """Pinocchio's quaternion (x, y, z, w) as a matrix (eq. 2.7 with theta = (w, x, y, z))."""
    x, y, z, w = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


@pytest.fixture(scope="module")
def mixed() -> kms2pin.Robot:
    return kms2pin.load(kms2pin.parse(MIXED_JOINTS))


@pytest.fixture(scope="module")
def human() -> kms2pin.Robot:
    return kms2pin.load(SPECS / "human.kms", root="free")


# ----------------------------------------------------------------------------- the language


def test_rest_rotation_offset_and_limits_are_parsed(mixed):
    joints = {j.name: j for j in mixed.system.joints}
    ball = joints["b_ball"]
    assert (ball.kind, ball.parent, ball.dof, ball.default_rotation, ball.limits) == (
        "spherical", "a", 3, (30.0, -20.0, 45.0), None)
    slide = joints["c_slide"]  # written child first: the tree makes c the child (a hangs from the origin)
    assert (slide.kind, slide.parent, slide.child, slide.dof, slide.default_offset, slide.limits) == (
        "prismatic", "a", "c", 1, 0.15, (-0.4, 0.6))
    assert joints["d_slide"].limits is None and joints["d_slide"].default_offset == -0.1


def test_the_tree_not_the_argument_order_picks_parent_and_child():
    swapped = MIXED_JOINTS.replace("prismatic(c.slide, a.slide, 0.15, -0.4, 0.6)",
                                   "prismatic(a.slide, c.slide, 0.15, -0.4, 0.6)")
    assert swapped != MIXED_JOINTS
    a, b = (kms2pin.parse(t).system() for t in (MIXED_JOINTS, swapped))
    assert a.joint_of("c") == b.joint_of("c")
    assert a.joint_of("c").parent == "a" and a.joint_of("c").parent_bvec.qualified_name == "a.slide"


def test_the_rest_rotation_is_a_rotation_vector_in_the_parent_frame(mixed):
    """R_ij = Exp(r) R_align with |r| the angle in degrees; a revolute joint about u at
    angle theta is the spherical joint with r = theta u."""
    ball = mixed.system.joint_of("b")
    R_a = mixed.body_pose(mixed.q_rest, "a").rotation
    R_b = mixed.body_pose(mixed.q_rest, "b").rotation
    r = np.radians(ball.default_rotation)
    R_align = rot(np.cross(ball.child_bvec.orient, ball.parent_bvec.orient),
                  math.acos(np.dot(ball.parent_bvec.orient, ball.child_bvec.orient)))
    np.testing.assert_allclose(R_a.T @ R_b, rot(r, np.linalg.norm(r)) @ R_align, atol=TOL)
    hinge = MIXED_JOINTS.replace("revolute(e.hinge, a.hinge, 25, -90, 90)", "spherical(e.hinge, a.hinge, 0, 0, 25)")
    as_ball = kms2pin.load(kms2pin.parse(hinge))
    np.testing.assert_allclose(as_ball.body_pose(as_ball.q_rest, "e").homogeneous,
                               mixed.body_pose(mixed.q_rest, "e").homogeneous, atol=TOL)


NAME_CLASH = """
bvec origin { pos(0, 0, 0); orient(0, 1, 0); }
rigidBodySystem s {
    ellipsoidBody a { innerLam(1, 1, 1); outerLam(1, 1, 1); bvec base { pos(0, 0, 0); orient(0, 1, 0); }
        bvec p { pos(1, 0, 0); orient(1, 0, 0); } bvec q { pos(-1, 0, 0); orient(1, 0, 0); }
        bvec r { pos(0, 1, 0); orient(1, 0, 0); } }
    ellipsoidBody b_ball { innerLam(1, 1, 1); outerLam(1, 1, 1); bvec x { pos(0, 0, 0); orient(1, 0, 0); } }
    ellipsoidBody b_ball_2_x_link { innerLam(1, 1, 1); outerLam(1, 1, 1); bvec t { pos(0, 0, 0); orient(1, 0, 0); } }
    ellipsoidBody b { innerLam(1, 1, 1); outerLam(1, 1, 1); bvec ball { pos(0, 0, 0); orient(1, 0, 0); } }
    constraint revolute(a.p, b_ball.x);
    constraint fixed(a.r, b_ball_2_x_link.t);
    constraint spherical(a.q, b.ball);
}
constraint fixed(origin, s.a.base);
"""


def test_a_spherical_joint_keeps_the_names_of_its_urdf_joints_and_links_free():
    """Joint b_ball would take b_ball_x|y|z and links b_ball_x_link, b_ball_y_link: joint
    b_ball_x (named first) makes it b_ball_2, and body b_ball_2_x_link then b_ball_3."""
    names = [j.name for j in kms2pin.parse(NAME_CLASH).system().joints]
    assert names == ["a_base", "b_ball_x", "b_ball_2_x_link_t", "b_ball_3"]
    robot = kms2pin.load(NAME_CLASH)
    links = [link.get("name") for link in ET.fromstring(robot.urdf).iter("link")]
    urdf_joints = [j.get("name") for j in ET.fromstring(robot.urdf).iter("joint")]
    assert len(links) == len(set(links)) and len(urdf_joints) == len(set(urdf_joints))
    assert {"b_ball_3_x_link", "b_ball_3_y_link"} <= set(links)
    assert len(robot.coordinate_names) == len(set(robot.coordinate_names)) == 4


# ----------------------------------------------------------------------------- URDF, SRDF, check


def test_urdf_spherical_joint_is_three_continuous_joints_through_two_massless_links(mixed):
    root = ET.fromstring(mixed.urdf)
    joints = {j.get("name"): j for j in root.iter("joint")}
    chain = [joints[f"b_ball_{a}"] for a in "xyz"]
    assert [j.get("type") for j in chain] == ["continuous"] * 3  # unlimited, as an unlimited revolute joint
    assert [(j.find("parent").get("link"), j.find("child").get("link")) for j in chain] == [
        ("a", "b_ball_x_link"), ("b_ball_x_link", "b_ball_y_link"), ("b_ball_y_link", "b")]
    assert [j.find("axis").get("xyz") for j in chain[:2]] == ["1 0 0", "0 1 0"]
    for name in ("b_ball_x_link", "b_ball_y_link"):
        (link,) = [link for link in root.iter("link") if link.get("name") == name]
        assert len(link) == 0  # no inertial, visual or collision
    assert "b_ball" not in joints
    slide = joints["c_slide"]
    assert slide.get("type") == "prismatic"
    limit = slide.find("limit")
    assert (float(limit.get("lower")), float(limit.get("upper"))) == (-0.4, 0.6)
    assert float(limit.get("effort")) > 0 and float(limit.get("velocity")) > 0
    assert "A spherical joint J is three continuous joints J_x, J_y, J_z" in mixed.urdf.splitlines()[1]


def test_existing_urdf_output_has_no_new_words():
    """The thesis's models' URDF header says nothing about joints they do not have."""
    robot = kms2pin.load(SPECS / "fullbody.kms")
    assert "spherical" not in robot.urdf and "prismatic" not in robot.urdf


def test_check_prints_each_joints_type_and_degrees_of_freedom(capsys):
    assert main(["check", str(SPECS / "gantry.kms")]) == 0
    out = capsys.readouterr().out
    assert "4 degrees of freedom (1 revolute, 3 prismatic, 1 fixed joints)" in out.splitlines()[0]
    assert "quill  [prismatic 'quill_top', 1 DoF, axis (0, -1, 0) in carriage, rest offset 0.2, limits 0..0.6]" in out
    assert main(["check", "--json", str(SPECS / "human.kms")]) == 0
    (system,) = json.loads(capsys.readouterr().out)["systems"]
    assert (system["dof"], system["spherical_joints"], system["revolute_joints"], system["prismatic_joints"]) == (
        25, 6, 7, 0)
    shoulder = next(b["joint"] for b in system["bodies"] if b["name"] == "rightUpperArm")
    assert (shoulder["type"], shoulder["dof"], shoulder["default_rotation_deg"]) == ("spherical", 3, [0.0, 0.0, 8.0])


# ----------------------------------------------------------------------------- coordinates and CSV


def test_coordinate_names_are_the_urdf_joints(human):
    root = ET.fromstring(human.urdf)
    urdf_joints = [j.get("name") for j in root.iter("joint") if j.get("type") not in ("fixed", "floating")]
    assert human.coordinate_names[:7] == ("root_x", "root_y", "root_z", "root_qx", "root_qy", "root_qz", "root_qw")
    assert sorted(human.coordinate_names[7:]) == sorted(urdf_joints)
    assert human.nq == 7 + 6 * 4 + 6 and len(human.coordinate_names) == 7 + 6 * 3 + 6


def test_coordinates_are_the_xyz_angles_in_degrees(human, mixed):
    rng = np.random.default_rng(3)
    for robot in (human, mixed):
        q = robot.random_configuration(rng, 150)
        c = dict(zip(robot.coordinate_names, robot.coordinates(q)))
        for j in robot.joints:
            if j.kind == "spherical":
                a, b, cc = (c[f"{j.name}_{k}"] for k in "xyz")
                assert -90 <= b <= 90
                np.testing.assert_allclose(xyz(a, b, cc), quaternion_matrix(q[j.idx_q : j.idx_q + 4]), atol=1e-12)
            elif j.kind == "revolute":
                assert c[j.name] == pytest.approx(math.degrees(q[j.idx_q]))
            elif j.kind == "prismatic":
                assert c[j.name] == q[j.idx_q]


def test_trajectory_csv_round_trip_to_its_printed_precision(human, mixed, tmp_path):
    for robot in (human, mixed):
        q = make_motion(robot, "random", 25, np.random.default_rng(4))
        path = tmp_path / f"{robot.system.name}.csv"
        Trajectory(robot, q).to_csv(path)
        header = path.read_text().splitlines()[0].split(",")
        assert header == ["frame", *robot.coordinate_names]
        back = Trajectory.from_csv(robot, path)
        for a, b in zip(back.q, q):  # the same body poses (a quaternion and its negative are one rotation)
            for Ma, Mb in zip(robot.body_poses(a), robot.body_poses(b)):
                np.testing.assert_allclose(Ma.homogeneous, Mb.homogeneous, atol=1e-8)


def test_evaluate_scores_a_spherical_joint_by_the_angle_between_the_rotations(mixed):
    q = mixed.q_rest.copy()
    ball = next(j for j in mixed.joints if j.name == "b_ball")
    turned = q.copy()
    dv = np.zeros(mixed.nv)
    dv[ball.idx_v : ball.idx_v + 3] = np.radians(12.0) * np.array([0.6, 0.0, 0.8])
    turned = pin.integrate(mixed.model, q, dv)
    slide = next(j for j in mixed.joints if j.name == "c_slide")
    turned[slide.idx_q] += 0.05
    rep = evaluate(mixed, Trajectory(mixed, turned[None]), Trajectory(mixed, q[None]))
    assert rep["joint_rmse_deg"]["b_ball"] == pytest.approx(12.0, abs=1e-9)
    assert rep["spherical_rmse_deg"] == pytest.approx(math.sqrt(12.0**2 / 2), abs=1e-9)  # and a_base at 0
    assert rep["prismatic_rmse"]["c_slide"] == pytest.approx(0.05, abs=1e-12)
    assert rep["revolute_rmse_deg"] == pytest.approx(0.0, abs=1e-9)


# ----------------------------------------------------------------------------- sliders and --pose


def test_three_sliders_per_spherical_joint_one_per_prismatic_joint(mixed):
    sliders = {s.name: s for s in joint_sliders(mixed)}
    assert [n for n in sliders if n.startswith("b_ball")] == ["b_ball_x", "b_ball_y", "b_ball_z"]
    assert (sliders["b_ball_y"].lower, sliders["b_ball_y"].upper) == (-90.0, 90.0)
    assert (sliders["c_slide"].lower, sliders["c_slide"].upper, sliders["c_slide"].unit) == (-0.4, 0.6, "length")
    assert "d_slide" in sliders and sliders["d_slide"].lower < 0 < sliders["d_slide"].upper


def test_pose_sets_xyz_angles_and_offsets(mixed):
    q = parse_pose(mixed, "b_ball_x=20 b_ball_y=-35 b_ball_z=100 c_slide=0.25")
    ball = next(j for j in mixed.joints if j.name == "b_ball")
    np.testing.assert_allclose(quaternion_matrix(q[ball.idx_q : ball.idx_q + 4]), xyz(20, -35, 100), atol=1e-12)
    slide = next(j for j in mixed.joints if j.name == "c_slide")
    assert q[slide.idx_q] == 0.25
    text = pose_string(mixed, q)
    assert {"b_ball_x=20", "b_ball_y=-35", "b_ball_z=100", "c_slide=0.25"} <= set(text.split())
    np.testing.assert_allclose(parse_pose(mixed, text), q, atol=2e-5)  # the string has 0.001 deg
    # one angle of three: the others keep their values
    q2 = parse_pose(mixed, "b_ball_y=10", q)
    np.testing.assert_allclose(quaternion_matrix(q2[ball.idx_q : ball.idx_q + 4]), xyz(20, 10, 100), atol=1e-12)


@pytest.mark.parametrize(("pose", "message"), [
    ("b_ball=10", r"joint 'b_ball' is spherical: set b_ball_x, b_ball_y and b_ball_z"),
    ("b_ball_y=95", r"'b_ball_y' \(95 deg\) is outside the range of the middle X-Y-Z angle -90..90 deg"),
    ("c_slide=0.7", r"offset of joint 'c_slide' \(0.7\) is outside its limits -0.4..0.6"),
    ("c_slide=abc", "offset of joint 'c_slide' is not a number"),
    ("b_ball_x=1 b_ball_x=2", "given twice"),
    ("b_bal_x=3", "did you mean 'b_ball_x'"),
])
def test_bad_poses_of_the_new_joints(mixed, pose, message):
    with pytest.raises(PoseError, match=message):
        parse_pose(mixed, pose)


def test_view_pose_option_takes_the_new_coordinates(tmp_path, capsys):
    html = tmp_path / "gantry.html"
    assert main(["view", str(SPECS / "gantry.kms"), "--pose", "quill_top=0.5", "bridge_shoe=-0.3",
                 "--no-serve", "--html", str(html)]) == 0
    assert html.stat().st_size > 1000
    assert main(["view", str(SPECS / "gantry.kms"), "--pose", "quill_top=0.9", "--no-serve", "--html",
                 str(html)]) == 2
    assert "outside its limits 0..0.6" in capsys.readouterr().err


# ----------------------------------------------------------------------------- motions and synth


@pytest.mark.parametrize("motion", ["sweep", "random"])
def test_motions_move_spherical_and_prismatic_joints_within_their_limits(mixed, motion):
    q = make_motion(mixed, motion, 90, np.random.default_rng(5))
    np.testing.assert_array_equal(q[0], mixed.q_rest)
    assert np.all(q >= mixed.lower_limits - 1e-12) and np.all(q <= mixed.upper_limits + 1e-12)
    c = mixed.coordinates(q)
    spread = dict(zip(mixed.coordinate_names, np.ptp(c, axis=0)))
    for name in ("b_ball_x", "b_ball_y", "b_ball_z", "a_base_x", "a_base_y", "a_base_z"):
        assert spread[name] > 5.0, name  # degrees
    assert spread["c_slide"] > 0.05 and spread["d_slide"] > 0.05
    for j in mixed.joints:  # quaternions stay unit (composed, not added to)
        if j.kind == "spherical":
            np.testing.assert_allclose(np.linalg.norm(q[:, j.idx_q : j.idx_q + 4], axis=1), 1.0, atol=1e-12)


def test_synth_renders_the_human_moving_out_of_the_sagittal_plane(tmp_path, capsys):
    out = tmp_path / "synth"
    assert main(["synth", str(SPECS / "human.kms"), "--root", "free", "--motion", "random", "--frames", "4",
                 "-o", str(out)]) == 0
    robot = kms2pin.load(SPECS / "human.kms", root="free")
    truth = Trajectory.from_csv(robot, out / "truth.csv")
    assert len(truth) == 4
    import cv2

    masks = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) > 0 for p in sorted((out / "cam0").glob("frame_*.png"))]
    assert len(masks) == 4
    area = [m.sum() for m in masks]
    assert min(area) > 0.02 * masks[0].size  # the human is in the picture ...
    assert (masks[0] ^ masks[-1]).sum() > 0.01 * area[0]  # ... and moves


# ----------------------------------------------------------------------------- big models


def chain_spec(n: int) -> str:
    """A chain of ``n`` bodies, each a revolute joint below the last."""
    body = ("ellipsoidBody Link(double k) {{ innerLam(0.1, 0.5, 0.1); outerLam(0.1, 0.5, 0.1);\n"
            "    bvec top {{ pos(0, 0.5, 0); orient(1, 0, 0); }} bvec bottom {{ pos(0, -0.5, 0); orient(1, 0, 0); }} }}\n")
    parts = [body.format(), "bvec origin { pos(0, 0, 0); orient(1, 0, 0); }", "rigidBodySystem chain {"]
    parts += [f"    Link b{k}({k});" for k in range(n)]
    parts += [f"    constraint revolute(b{k}.bottom, b{k + 1}.top, 1);" for k in range(n - 1)]
    parts += ["}", "constraint revolute(origin, chain.b0.top);"]
    return "\n".join(parts)


def test_a_thousand_body_chain_compiles_exports_and_loads(tmp_path, capsys):
    """No recursion limit: the compiler's tree walk, check's tree and Pinocchio's model
    are built without recursion (a chain of 1000 was 'too deep to traverse')."""
    path = tmp_path / "chain.kms"
    path.write_text(chain_spec(1000))
    assert main(["check", str(path)]) == 0
    out = capsys.readouterr().out
    assert "1000 bodies, 1000 degrees of freedom" in out
    lines = out.splitlines()
    assert len(lines) == 1002 and lines[-1].strip().startswith("└─ (depth 1000) b999  [revolute")
    assert max(map(len, lines)) < 200  # the indentation stops growing (else 3000 spaces)
    assert main(["export", str(path), "-o", str(tmp_path / "out")]) == 0
    robot = kms2pin.load(path)  # without Pinocchio's Data, which grows as nv^3 (60 GB here)
    assert robot.nq == 1000 and robot.model.parents[1000] == 999 and "data" not in vars(robot)
    assert len(ET.parse(tmp_path / "out" / "chain.urdf").getroot().findall("joint")) == 1000


def test_the_human_has_the_proportions_of_the_anthropometric_table():
    """specs/human.kms against the Drillis and Contini table (fractions of the height H,
    anatomical position: straight knees and elbows, arms down): standing height, joint
    heights above the floor and foot length, each within 1 % of H."""
    robot = kms2pin.load(SPECS / "human.kms")
    straight = ("leftShin_knee=0 rightShin_knee=0 leftForeArm_elbow=0 rightForeArm_elbow=0 "
                "leftUpperArm_shoulder_z=0 rightUpperArm_shoulder_z=0")
    q = parse_pose(robot, straight)
    poses = {n: (M.translation, M.rotation) for n, M in zip(robot.bodies, robot.body_poses(q))}
    extent = {n: np.abs(R) @ robot.inner(n) for n, (_, R) in poses.items()}  # half box sizes
    floor = min(p[1] - extent[n][1] for n, (p, _) in poses.items())
    crown = max(p[1] + extent[n][1] for n, (p, _) in poses.items())
    H = 1.75
    assert crown - floor == pytest.approx(H, abs=0.01 * H)

    def height(body: str) -> float:
        """Height above the floor of the joint point of ``body`` to its parent."""
        p, R = poses[body]
        return float((p + R @ np.asarray(robot.system.joint_of(body).child_bvec.pos))[1] - floor)

    table = {"leftThigh": 0.530, "rightShin": 0.285, "leftFoot": 0.039, "rightUpperArm": 0.818,
             "leftForeArm": 0.630, "rightHand": 0.485}  # hip, knee, ankle, shoulder, elbow, wrist
    for body, fraction in table.items():
        assert height(body) == pytest.approx(fraction * H, abs=0.01 * H), body
    foot = 2 * robot.inner("leftFoot")[2]
    assert foot == pytest.approx(0.152 * H, abs=0.01 * H)
    # left at -x: the subject faces -z with y up, so its right hand side is +x
    assert poses["leftHand"][0][0] < 0 < poses["rightHand"][0][0]


def test_a_pose_file_sets_xyz_angles_and_offsets(mixed, tmp_path):
    """track --init POSE.json names the trajectory CSV's coordinates."""
    from kms2pin.errors import InputDataError
    from kms2pin.video.init import read_pose_json

    path = tmp_path / "pose.json"
    path.write_text(json.dumps({"joints": {"b_ball_x": 10, "b_ball_z": -40, "c_slide": 0.3, "e_hinge": 15}}))
    q = read_pose_json(mixed, path)
    c = dict(zip(mixed.coordinate_names, mixed.coordinates(q)))
    rest = dict(zip(mixed.coordinate_names, mixed.coordinates(mixed.q_rest)))
    assert (c["b_ball_x"], c["b_ball_y"], c["b_ball_z"]) == pytest.approx((10, rest["b_ball_y"], -40))
    assert (c["c_slide"], c["e_hinge"], c["d_slide"]) == pytest.approx((0.3, 15, rest["d_slide"]))
    path.write_text(json.dumps({"joints": {"b_ball": 10}}))
    with pytest.raises(InputDataError, match="joint 'b_ball' is spherical: give b_ball_x, b_ball_y and b_ball_z"):
        read_pose_json(mixed, path)
    path.write_text(json.dumps({"joints": {"c_slide": "far"}}))
    with pytest.raises(InputDataError, match="value must be a number \\(spec length units\\)"):
        read_pose_json(mixed, path)
