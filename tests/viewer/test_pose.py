"""--pose strings <-> configurations (no browser)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kms2pin.viewer import PoseError, joint_angles_deg, parse_pose, pose_string, revolute_joints

from ._util import joint_q, load


def test_revolute_joints_are_the_sliders(lowerbody):
    names = [j.name for j in revolute_joints(lowerbody)]
    assert names == list(lowerbody.joint_names)  # all 7 lower-body joints are revolute
    assert all(j.lower == -180 and j.upper == 180 for j in revolute_joints(lowerbody))


def test_pose_string_round_trip(lowerbody):
    q = parse_pose(lowerbody, "leftThigh_hip=33.5 rightShin_knee=-12.25")
    assert math.degrees(q[joint_q(lowerbody, "leftThigh_hip")]) == pytest.approx(33.5)
    assert math.degrees(q[joint_q(lowerbody, "rightShin_knee")]) == pytest.approx(-12.25)
    text = pose_string(lowerbody, q)
    assert "leftThigh_hip=33.5" in text.split()
    np.testing.assert_allclose(parse_pose(lowerbody, text), q, atol=1e-9)
    np.testing.assert_allclose(parse_pose(lowerbody, text.split()), q, atol=1e-9)  # as argv tokens


def test_rest_pose_and_other_joints_kept(lowerbody):
    np.testing.assert_array_equal(parse_pose(lowerbody, None), lowerbody.q_rest)
    q = parse_pose(lowerbody, ["leftShin_knee=5,rightShin_knee=6"])
    changed = np.flatnonzero(q != lowerbody.q_rest)
    assert sorted(changed) == sorted([joint_q(lowerbody, "leftShin_knee"), joint_q(lowerbody, "rightShin_knee")])
    assert joint_angles_deg(lowerbody, q)["leftFoot_ankle"] == pytest.approx(80)


def test_angles_wrap(lowerbody):
    q = parse_pose(lowerbody, "leftShin_knee=270")
    assert math.degrees(q[joint_q(lowerbody, "leftShin_knee")]) == pytest.approx(-90)


@pytest.mark.parametrize(("pose", "message"), [
    ("leftShin_kne=10", "did you mean 'leftShin_knee'"),
    ("leftShin_knee=ten", "not a number"),
    ("leftShin_knee=nan", "finite"),
    ("leftShin_knee", "JOINT=DEGREES"),
    ("trunk_waist=10", "fixed"),
    ("leftShin_knee=1 leftShin_knee=2", "twice"),
])
def test_bad_poses(lowerbody, pose, message):
    with pytest.raises(PoseError, match=message):
        parse_pose(lowerbody, pose)


def test_free_root_skips_the_free_flyer():
    robot = load("puma600", root="free")
    names = [j.name for j in revolute_joints(robot)]
    assert "root_joint" not in names and len(names) == robot.nq - 7
    with pytest.raises(PoseError, match="free flyer"):
        parse_pose(robot, "base_inertialAnchor=10")
    with pytest.raises(PoseError, match="free flyer"):
        parse_pose(robot, "root_joint=10")
    q = parse_pose(robot, pose_string(robot, robot.q_rest))
    np.testing.assert_allclose(q, robot.q_rest, atol=1e-9)


def test_sliders_and_poses_follow_the_spec_limits():
    from pathlib import Path

    from kms2pin.robot import load as load_spec

    robot = load_spec(Path(__file__).resolve().parents[2] / "specs" / "anatomical" / "lowerbody.kms")
    ranges = {j.name: (j.lower, j.upper) for j in revolute_joints(robot)}
    assert ranges["leftShin_knee"] == (0.0, 150.0)
    assert ranges["leftThigh_hip"] == (-30.0, 120.0)
    assert ranges["pelvis_inertialAnchor"] == (-180.0, 180.0)  # no limits in the spec
    q = parse_pose(robot, "leftShin_knee=140")  # within the limits, kept as given
    assert math.degrees(q[joint_q(robot, "leftShin_knee")]) == pytest.approx(140)
    with pytest.raises(PoseError, match=r"'leftShin_knee' \(-30 deg\) is outside its limits 0..150 deg"):
        parse_pose(robot, "leftShin_knee=-30")
    with pytest.raises(PoseError, match="outside its limits -30..120 deg"):
        parse_pose(robot, "leftThigh_hip=270")  # not wrapped to -90 either
    q = parse_pose(robot, "pelvis_inertialAnchor=270")  # unlimited joints still wrap
    assert math.degrees(q[joint_q(robot, "pelvis_inertialAnchor")]) == pytest.approx(-90)
