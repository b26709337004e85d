"""kms2pin.ecm.evaluate: the accuracy figures of a track against the truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kms2pin.ecm.evaluate import evaluate
from kms2pin.ecm.motions import make_motion
from kms2pin.ecm.tracker import Trajectory
from kms2pin.robot import load

DIR = Path(__file__).resolve().parents[2] / "specs"
CENTRE = np.array([0.3, -0.2, 0.0])  # a camera's centre


@pytest.fixture(scope="module")
def hand():
    robot = load(DIR / "jplhand.kms", root="free")
    return robot, make_motion(robot, "random", 40, np.random.default_rng(0))


def _shifted(robot, truth, step):
    """The truth with the whole body moved by ``step(k, true mean centre)`` on frame k."""
    q = truth.copy()
    for k in range(len(q)):
        q[k, :3] += step(k, robot.maximal_coordinates(truth[k])[:, :3].mean(axis=0))
    return q


def test_a_body_moved_along_the_viewing_ray_is_all_depth_error(hand):
    """Every body moved by d along the ray from the camera through the true mean centre:
    the centre error is d on every body, all of it depth; without it nothing is left."""
    robot, truth = hand
    d = 0.01 * robot.height * np.linspace(1.0, 3.0, len(truth))  # 1 % of the height, growing to 3 %

    def along(k, mean):
        ray = mean - CENTRE
        return d[k] * ray / np.linalg.norm(ray)

    rep = evaluate(robot, Trajectory(robot, _shifted(robot, truth, along)), Trajectory(robot, truth), CENTRE)
    np.testing.assert_allclose(rep["per_frame_centre_error_pct"], d / robot.height * 100, rtol=1e-9)
    assert rep["depth_error_pct"] == pytest.approx(rep["mean_centre_error_pct"], rel=1e-9)
    assert rep["centre_error_without_depth_pct"] < 1e-9
    assert rep["first_vs_last_ratio"] == pytest.approx(d[-30:].mean() / d[:30].mean())
    assert rep["revolute_rmse_deg"] < 1e-9


def test_a_body_moved_across_the_ray_has_no_depth_error(hand):
    """Moved at right angles to that ray, the error is all left without the depth."""
    robot, truth = hand

    def across(k, mean):
        ray = mean - CENTRE
        side = np.cross(ray, [0.0, 1.0, 0.0])
        return 0.02 * robot.height * side / np.linalg.norm(side)

    rep = evaluate(robot, Trajectory(robot, _shifted(robot, truth, across)), Trajectory(robot, truth), CENTRE)
    assert rep["mean_centre_error_pct"] == pytest.approx(2.0, rel=1e-9)
    assert rep["depth_error_pct"] < 1e-9
    assert rep["centre_error_without_depth_pct"] == pytest.approx(2.0, rel=1e-9)
    assert rep["first_vs_last_ratio_without_depth"] == pytest.approx(1.0)


def test_without_a_camera_there_is_no_depth_split_and_angles_wrap(hand):
    """No camera, no depth figures; a revolute angle a full turn off is no error."""
    robot, truth = hand
    q = truth.copy()
    j = robot.model.joints[robot.model.getJointId("tip1_joint")]
    q[:, j.idx_q] += 2 * np.pi
    rep = evaluate(robot, Trajectory(robot, q), Trajectory(robot, truth))
    assert "depth_error_pct" not in rep
    assert rep["joint_rmse_deg"]["tip1_joint"] == pytest.approx(0.0, abs=1e-9)
    assert rep["mean_centre_error_pct"] < 1e-9
