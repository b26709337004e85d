"""kms2pin.ecm.trajectory: shapes accepted, NPZ round trip, quaternion conventions;
and the small API edges around it (single camera, str mask folders, exported errors)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import kms2pin
from kms2pin.ecm import Camera, FrameResult, Trajectory, make_motion, synthesize
from kms2pin.video import write_mask
from kms2pin.video.io import read_image

DIR = Path(__file__).resolve().parents[2] / "specs"


@pytest.fixture(scope="module")
def lower():
    robot = kms2pin.load(DIR / "lowerbody.kms", root="free")
    return robot, make_motion(robot, "walk", 3)


def test_a_transposed_trajectory_is_rejected_with_the_expected_shape(lower):
    robot, q = lower
    with pytest.raises(kms2pin.InputDataError) as err:
        Trajectory(robot, q.T)
    assert str(err.value) == "q must have shape (frames, nq) with nq = 13, not (13, 3)"


def test_a_wrong_number_of_coordinates_is_rejected(lower):
    robot, q = lower
    with pytest.raises(kms2pin.InputDataError, match=r"nq = 13, not \(3, 5\)"):
        Trajectory(robot, q[:, :5])


def test_one_configuration_is_a_trajectory_of_one_frame(lower):
    robot, q = lower
    assert Trajectory(robot, q[1]).q.shape == (1, 13)
    assert len(Trajectory(robot, q[:0])) == 0


def test_a_non_finite_frame_is_named(lower):
    robot, q = lower
    q = q.copy()
    q[2, 8] = np.nan
    with pytest.raises(kms2pin.InputDataError, match="^q of frame 2 is not finite"):
        Trajectory(robot, q)


def _results(robot, q):
    return [
        FrameResult(q[0], robot.maximal_coordinates(q[0]), 7, 0.91, True),
        FrameResult(q[1], robot.maximal_coordinates(q[1]), 40, 0.25, False, ("poor fit (0.25)", "empty mask in camera 1")),
        FrameResult(q[2], robot.maximal_coordinates(q[2]), 12, 0.5, True, ("lost: kept the last pose",)),
    ]


def test_results_must_be_one_per_frame(lower):
    robot, q = lower
    with pytest.raises(kms2pin.InputDataError, match=r"one per frame \(3\), not 2"):
        Trajectory(robot, q, _results(robot, q)[:2])


def test_npz_round_trip_keeps_q_scales_fits_and_flags(lower, tmp_path):
    robot, q = lower
    scales = np.linspace(0.8, 1.2, len(robot.bodies) * 3).reshape(-1, 3)
    Trajectory(robot, q, _results(robot, q), scales=scales).to_npz(tmp_path / "t.npz")
    back = Trajectory.from_npz(robot, tmp_path / "t.npz")
    np.testing.assert_array_equal(back.q, q)
    np.testing.assert_array_equal(back.scales, scales)
    assert [r.fit for r in back.results] == [0.91, 0.25, 0.5]
    assert [r.iterations for r in back.results] == [7, 40, 12]
    assert [r.converged for r in back.results] == [True, False, True]
    assert [r.flags for r in back.results] == [(), ("poor fit (0.25)", "empty mask in camera 1"),
                                               ("lost: kept the last pose",)]
    assert back.results[1].body_poses.shape == (len(robot.bodies), 7)


def test_npz_without_results_reads_back_plain(lower, tmp_path):
    robot, q = lower
    Trajectory(robot, q).to_npz(tmp_path / "t.npz")
    back = Trajectory.from_npz(robot, tmp_path / "t.npz")
    np.testing.assert_array_equal(back.q, q)
    assert back.results == []
    np.testing.assert_array_equal(back.scales, np.ones((len(robot.bodies), 3)))


def test_npz_of_another_model_or_not_npz_is_an_input_error(lower, tmp_path):
    robot, q = lower
    hand = kms2pin.load(DIR / "jplhand.kms", root="free")
    Trajectory(hand, hand.q_rest).to_npz(tmp_path / "hand.npz")
    with pytest.raises(kms2pin.InputDataError, match="hand.npz: saved for the bodies"):
        Trajectory.from_npz(robot, tmp_path / "hand.npz")
    (tmp_path / "t.npz").write_text("q,1,2\n")
    with pytest.raises(kms2pin.InputDataError, match="t.npz: not an NPZ file"):
        Trajectory.from_npz(robot, tmp_path / "t.npz")


def test_quaternion_is_scalar_last_in_q_and_scalar_first_in_body_poses(lower, tmp_path):
    """The pelvis is the root body, upright at rest: turning the root by a about z is
    q[3:7] = (0, 0, sin a/2, cos a/2) and pelvis Euler parameters (cos a/2, 0, 0, sin a/2)."""
    robot, _ = lower
    a = 0.6
    q = robot.q_rest.copy()
    q[3:7] = [0.0, 0.0, np.sin(a / 2), np.cos(a / 2)]
    Trajectory(robot, q).to_npz(tmp_path / "t.npz")
    with np.load(tmp_path / "t.npz") as z:
        pelvis = z["body_poses"][0, list(z["bodies"]).index("pelvis")]
    np.testing.assert_allclose(pelvis[3:], [np.cos(a / 2), 0.0, 0.0, np.sin(a / 2)], atol=1e-12)


def test_synthesize_accepts_one_camera(lower):
    robot, q = lower
    cam = Camera.default()
    frame, masks = next(synthesize(robot, q, cam))
    assert frame == 0 and len(masks) == 1
    assert masks[0].shape == (cam.height, cam.width) and masks[0].any()


def test_write_mask_accepts_a_str_folder(tmp_path):
    mask = np.zeros((4, 6), bool)
    mask[1:3, 2:5] = True
    path = write_mask(str(tmp_path), 3, mask)
    assert path == tmp_path / "frame_00003.png"
    np.testing.assert_array_equal(read_image(path, 0), np.where(mask, 255, 0))


def test_every_error_type_is_exported_from_the_package():
    for name in ("Kms2pinError", "SpecError", "InputDataError", "CameraError", "ExportError", "RobotError",
                 "TargetError", "OptionError"):
        assert name in kms2pin.__all__
        assert issubclass(getattr(kms2pin, name), kms2pin.Kms2pinError)
