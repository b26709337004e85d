"""kms2pin.ecm.evaluate: the accuracy figures of a track against the truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from conftest import PNG, set_csv_cell

from kms2pin.ecm.evaluate import evaluate, ray_parts
from kms2pin.ecm.motions import make_motion
from kms2pin.ecm.tracker import Trajectory
from kms2pin.errors import InputDataError
from kms2pin.robot import load

DIR = Path(__file__).resolve().parents[2] / "specs"
FAR = 1e6  # a camera this far off sees every body along (nearly) the same ray


@pytest.fixture(scope="module")
def hand():
    robot = load(DIR / "jplhand.kms", root="free")
    return robot, make_motion(robot, "random", 40, np.random.default_rng(0))


def _shifted(truth, step):
    """The truth with the whole body moved by ``step(k)`` on frame k."""
    q = truth.copy()
    for k in range(len(q)):
        q[k, :3] += step(k)
    return q


def test_a_body_moved_along_the_viewing_rays_is_all_depth_error(hand):
    """A camera far off along -u: every body moved by d along u moves along its own
    ray, so the centre error d is all depth, none across the rays."""
    robot, truth = hand
    u = np.array([0.2, -0.3, 1.0]) / np.linalg.norm([0.2, -0.3, 1.0])
    centre = robot.q_rest[:3] - FAR * u
    d = 0.01 * robot.height * np.linspace(1.0, 3.0, len(truth))  # 1 % of the height, growing to 3 %
    tracked = Trajectory(robot, _shifted(truth, lambda k: d[k] * u))
    rep = evaluate(robot, tracked, Trajectory(robot, truth), centre)
    np.testing.assert_allclose(rep["per_frame_centre_error_pct"], d / robot.height * 100, rtol=1e-9)
    assert rep["depth_error_pct"] == pytest.approx(rep["mean_centre_error_pct"], rel=1e-9)
    assert rep["centre_error_across_rays_pct"] < 1e-4 * rep["mean_centre_error_pct"]
    assert rep["first_vs_last_ratio"] == pytest.approx(d[-30:].mean() / d[:30].mean())
    assert rep["revolute_rmse_deg"] < 1e-9


def test_a_body_moved_across_the_viewing_rays_has_no_depth_error(hand):
    robot, truth = hand
    u = np.array([0.0, 0.0, 1.0])
    centre = robot.q_rest[:3] - FAR * u
    tracked = Trajectory(robot, _shifted(truth, lambda k: 0.02 * robot.height * np.array([1.0, 0.0, 0.0])))
    rep = evaluate(robot, tracked, Trajectory(robot, truth), centre)
    assert rep["mean_centre_error_pct"] == pytest.approx(2.0, rel=1e-9)
    assert rep["depth_error_pct"] < 1e-4
    assert rep["centre_error_across_rays_pct"] == pytest.approx(2.0, rel=1e-6)
    assert rep["first_vs_last_ratio_across_rays"] == pytest.approx(1.0)


def test_the_depth_and_across_parts_are_orthogonal(hand):
    """Random joint and root errors, a camera near the hand: per body the two parts
    are orthogonal (the error is their hypotenuse), so the centre error lies between
    the hypotenuse of their means and their sum."""
    robot, truth = hand
    rng = np.random.default_rng(3)
    q = truth.copy()
    q[:, 7:] += rng.normal(0.0, 0.2, q[:, 7:].shape)
    q[:, :3] += rng.normal(0.0, 0.05 * robot.height, (len(q), 3))
    centre = robot.q_rest[:3] - [0.0, 0.0, 10.0]
    rep = evaluate(robot, Trajectory(robot, q), Trajectory(robot, truth), centre)
    total, depth, across = rep["mean_centre_error_pct"], rep["depth_error_pct"], rep["centre_error_across_rays_pct"]
    # each body's own ray, not one ray for the whole hand: the part along it by the cosine rule
    a = np.array([robot.maximal_coordinates(x)[:, :3] for x in q])
    b = np.array([robot.maximal_coordinates(x)[:, :3] for x in truth])
    ra, rb, e = (np.linalg.norm(x, axis=2) for x in (a - centre, b - centre, a - b))
    along = (ra**2 - rb**2 - e**2) / (2 * rb)
    assert depth == pytest.approx(np.abs(along).mean() / robot.height * 100, rel=1e-9)
    assert 0.0 < depth < total and 0.0 < across < total < depth + across
    assert np.hypot(depth, across) <= total * (1 + 1e-12)  # the norm of a mean is at most the mean of norms


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


def test_the_angle_errors_are_the_offsets_put_in(hand):
    """10° added to m of the hand's n revolute joints on every frame (alternately + and -):
    those joints' RMSE 10°, the others' 0, the revolute RMSE sqrt(m 10² / n); on the human,
    a spherical joint turned 7° about a fixed axis on every frame: its RMSE 7°; the worst
    frame is the one the root was moved on, its error the bodies' mean distance there."""
    robot, truth = hand
    revolute = [j for j in robot.joints if j.kind == "revolute"]
    moved = revolute[::3]
    q = truth.copy()
    for n, j in enumerate(moved):
        q[:, j.idx_q] += np.radians(10.0) * (1 if n % 2 else -1)
    q[17, :3] += [0.5 * robot.height, 0.0, 0.0]  # the root moved on one frame only: the worst frame
    rep = evaluate(robot, Trajectory(robot, q), Trajectory(robot, truth))
    for j in revolute:
        assert rep["joint_rmse_deg"][j.name] == pytest.approx(10.0 if j in moved else 0.0, abs=1e-9)
    assert rep["revolute_rmse_deg"] == pytest.approx(np.sqrt(len(moved) * 100.0 / len(revolute)), rel=1e-9)
    # each frame's error: the mean over the bodies of the centres' distance, % of the height
    a = np.array([robot.maximal_coordinates(x)[:, :3] for x in q])
    b = np.array([robot.maximal_coordinates(x)[:, :3] for x in truth])
    per_frame = np.linalg.norm(a - b, axis=2).mean(axis=1) / robot.height * 100
    np.testing.assert_allclose(rep["per_frame_centre_error_pct"], per_frame, rtol=1e-9)
    assert rep["worst_frame"] == int(np.argmax(per_frame)) == 17
    assert rep["worst_frame_error_pct"] == pytest.approx(per_frame[17], rel=1e-12)

    human = load(DIR / "human.kms", root="free")
    truth_h = make_motion(human, "random", 6, np.random.default_rng(1))
    (j,) = [j for j in human.joints if j.kind == "spherical"][:1]
    turn = pin.Quaternion(pin.exp3(np.radians(7.0) * np.array([0.6, 0.0, 0.8]))).coeffs()
    qh = truth_h.copy()
    for k in range(len(qh)):  # the joint's rotation turned by 7° after its own: R' = R exp(7° axis)
        r = pin.Quaternion(*np.roll(qh[k, j.idx_q : j.idx_q + 4], 1)) * pin.Quaternion(*np.roll(turn, 1))
        qh[k, j.idx_q : j.idx_q + 4] = r.coeffs()
    rep = evaluate(human, Trajectory(human, qh), Trajectory(human, truth_h))
    assert rep["joint_rmse_deg"][j.name] == pytest.approx(7.0, abs=1e-9)
    n_sph = sum(1 for x in human.joints if x.kind == "spherical")
    assert rep["spherical_rmse_deg"] == pytest.approx(np.sqrt(49.0 / n_sph), rel=1e-9)


def test_trajectories_of_different_lengths_are_compared_on_the_common_frames(hand):
    """The shorter one sets ``frames``; both counts are reported for the caller to warn about."""
    robot, truth = hand
    rep = evaluate(robot, Trajectory(robot, truth[:25]), Trajectory(robot, truth))
    assert (rep["frames"], rep["tracked_frames"], rep["truth_frames"]) == (25, 25, 40)
    assert len(rep["per_frame_centre_error_pct"]) == 25
    rep = evaluate(robot, Trajectory(robot, truth), Trajectory(robot, truth[:4]))
    assert (rep["frames"], rep["tracked_frames"], rep["truth_frames"]) == (4, 40, 4)


def test_an_empty_trajectory_is_an_error_saying_which(hand):
    robot, truth = hand
    with pytest.raises(InputDataError, match="the true trajectory has no frames"):
        evaluate(robot, Trajectory(robot, truth), Trajectory(robot, truth[:0]))
    with pytest.raises(InputDataError, match="the tracked trajectory has no frames"):
        evaluate(robot, Trajectory(robot, truth[:0]), Trajectory(robot, truth))


def _csv_with_cell(robot, truth, path, line, column, value):
    """``truth`` as a trajectory CSV with the cell on (1-based) ``line`` under ``column`` set to ``value``."""
    Trajectory(robot, truth[:3]).to_csv(path)
    set_csv_cell(path, line, column, value)


@pytest.mark.parametrize("value", ["nan", "NaN", "inf", "-inf", "1e999", "", "ten"])
def test_a_csv_cell_that_is_not_a_finite_number_is_reported_with_its_line_and_column(hand, tmp_path, value):
    robot, truth = hand
    path = tmp_path / "t.csv"
    _csv_with_cell(robot, truth, path, 3, "tip1_joint", value)
    with pytest.raises(InputDataError) as err:
        Trajectory.from_csv(robot, path)
    assert str(err.value) == f"{path}:3: column 'tip1_joint': '{value}' is not a finite number"


def test_a_csv_column_named_twice_is_refused_naming_both(hand, tmp_path):
    """Two columns called tip1_joint: which holds the joint is not clear, so neither is taken."""
    robot, truth = hand
    path = tmp_path / "t.csv"
    Trajectory(robot, truth[:3]).to_csv(path)
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    k = header.index("tip1_joint")
    lines = [f"{line},{line.split(',')[k]}" for line in lines]  # the column again, at the end
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputDataError) as err:
        Trajectory.from_csv(robot, path)
    assert str(err.value) == (f"{path}:1: column 'tip1_joint' appears 2 times (columns {k + 1}, {len(header) + 1}): "
                              "which one holds the joint is not clear")


def test_a_short_csv_row_is_reported_with_its_line(hand, tmp_path):
    robot, truth = hand
    path = tmp_path / "t.csv"
    Trajectory(robot, truth[:3]).to_csv(path)
    lines = path.read_text().splitlines()
    lines[2] = "1,0.5"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputDataError) as err:
        Trajectory.from_csv(robot, path)
    assert str(err.value).startswith(f"{path}:3: malformed row: 2 fields, the header has ")


def test_a_binary_csv_is_an_input_data_error_saying_it_is_not_text(hand, tmp_path):
    robot, _ = hand
    path = tmp_path / "trajectory.csv"
    path.write_bytes(PNG)
    with pytest.raises(InputDataError) as err:
        Trajectory.from_csv(robot, path)
    assert str(err.value) == f"{path}: not a text (CSV) file"


def test_a_header_only_csv_is_an_empty_trajectory(hand, tmp_path):
    robot, truth = hand
    path = tmp_path / "t.csv"
    Trajectory(robot, truth[:0]).to_csv(path)
    assert len(Trajectory.from_csv(robot, path)) == 0


def test_ray_parts_split_an_error_along_and_across_the_camera_ray():
    """A displacement along the ray through the true point is all depth (signed: away
    from the camera positive), one at right angles to it all across; in general the two
    parts are orthogonal, |e|² = along² + across²."""
    rng = np.random.default_rng(2)
    centre = np.array([-5.0, 2.0, 1.0])
    truth = rng.normal(size=(4, 13, 3))
    ray = (truth - centre) / np.linalg.norm(truth - centre, axis=-1, keepdims=True)
    side = np.cross(ray, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side, axis=-1, keepdims=True)
    along, across = ray_parts(truth - 0.1 * ray, truth, centre)
    np.testing.assert_allclose(along, -0.1)
    np.testing.assert_allclose(across, 0.0, atol=1e-12)
    along, across = ray_parts(truth + 0.2 * side, truth, centre)
    np.testing.assert_allclose(along, 0.0, atol=1e-12)
    np.testing.assert_allclose(across, 0.2)
    e = rng.normal(size=truth.shape)
    along, across = ray_parts(truth + e, truth, centre)
    np.testing.assert_allclose(along**2 + across**2, np.sum(e**2, axis=-1))
