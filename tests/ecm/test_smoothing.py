"""kms2pin.ecm.smoothing: the zero-lag low-pass of a finished track, checked against the
Butterworth filter's analytic response, rotations kept rotations, limits and loops kept."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from scipy.signal import butter, filtfilt

import kms2pin
from kms2pin.ecm import Trajectory
from kms2pin.ecm.smoothing import smooth

DIR = Path(__file__).resolve().parents[2] / "specs"
FPS = 30.0


@pytest.fixture(scope="module")
def human():
    return kms2pin.load(DIR / "human.kms", root="free")


@pytest.fixture(scope="module")
def lower():  # revolute joints without limits
    return kms2pin.load(DIR / "lowerbody.kms", root="free")


def _revolute(robot):
    return next(j for j in robot.joints if j.kind == "revolute" and not np.isfinite(robot.lower_limits[j.idx_q]))


def _spherical(robot):
    return next(j for j in robot.joints if j.kind == "spherical")


def _about(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(frames, 4) quaternions (x, y, z, w) of turns by ``angles`` about the unit ``axis``."""
    return np.column_stack([np.outer(np.sin(angles / 2), axis), np.cos(angles / 2)])


def test_a_still_track_is_left_as_it_is(human):
    q = np.tile(pin.randomConfiguration(human.model, -np.ones(human.nq), np.ones(human.nq)), (40, 1))
    q = human.clamp(q)
    assert np.allclose(smooth(human, q, FPS, 6.0), q, atol=1e-12)


def test_a_revolute_angle_follows_the_butterworth_magnitude_response(lower):
    # forwards and backwards, a digital second-order Butterworth filter (the bilinear
    # transform's, frequencies warped by tan(pi f / fs)) passes a sine of frequency f with
    # gain 1 / (1 + (tan(pi f / fs) / tan(pi fc / fs))^4) and no phase: a slow sine
    # nearly whole, a fast one cut
    j = _revolute(lower)
    t = np.arange(600) / FPS
    q = np.tile(lower.q_rest, (len(t), 1))
    for f in (0.5, 12.0):
        q[:, j.idx_q] = 0.3 * np.sin(2 * np.pi * f * t)
        out = smooth(lower, q, FPS, 6.0)[:, j.idx_q]
        mid = slice(150, 450)  # away from the ends' padding
        gain = np.abs(np.fft.rfft(out[mid] * np.hanning(300))).max() / np.abs(np.fft.rfft(q[mid, j.idx_q] * np.hanning(300))).max()
        ratio = np.tan(np.pi * f / FPS) / np.tan(np.pi * 6.0 / FPS)
        assert gain == pytest.approx(1.0 / (1.0 + ratio**4), rel=0.02, abs=1e-3)
        lag = np.argmax(np.correlate(out[mid], q[mid, j.idx_q], "full")) - (300 - 1)
        assert lag == 0 or f > 6.0


def test_a_turn_about_a_fixed_axis_stays_about_it_and_its_angle_is_the_angles_low_pass(human):
    j = _spherical(human)
    rng = np.random.default_rng(3)
    t = np.arange(120) / FPS
    angle = np.radians(40.0) * np.sin(2 * np.pi * 0.7 * t) + np.radians(3.0) * rng.standard_normal(len(t))
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    q = np.tile(human.q_rest, (len(t), 1))
    q[:, j.idx_q : j.idx_q + 4] = _about(axis, angle)
    out = smooth(human, q, FPS, 6.0)[:, j.idx_q : j.idx_q + 4]
    assert np.allclose(np.linalg.norm(out, axis=1), 1.0)
    assert np.allclose(np.cross(out[:, :3], axis), 0.0, atol=1e-12)  # no part off the axis
    got = 2 * np.arctan2(out[:, :3] @ axis, out[:, 3])
    b, a = butter(2, 6.0 / (FPS / 2))
    expected = filtfilt(b, a, angle)  # the angle itself low-passed
    assert np.degrees(np.abs(got - expected)).max() < 0.3
    assert np.degrees(np.abs(got - angle)).std() > 1.0  # and the noise is gone, not kept


def test_a_quaternion_sign_does_not_matter(human):
    # q and -q are the same rotation: a track whose quaternions flip sign from frame to
    # frame smooths to the same rotations
    j = _spherical(human)
    t = np.arange(60) / FPS
    q = np.tile(human.q_rest, (len(t), 1))
    q[:, j.idx_q : j.idx_q + 4] = _about(np.array([0.0, 0.0, 1.0]), 1.2 * np.sin(2 * np.pi * t))
    flipped = q.copy()
    signs = np.random.default_rng(0).choice([-1.0, 1.0], len(t))
    flipped[:, j.idx_q : j.idx_q + 4] *= signs[:, None]
    a = smooth(human, q, FPS, 6.0)[:, j.idx_q : j.idx_q + 4]
    b = smooth(human, flipped, FPS, 6.0)[:, j.idx_q : j.idx_q + 4]
    assert np.allclose(np.abs(np.einsum("ij,ij->i", a, b)), 1.0, atol=1e-12)


def test_the_free_roots_position_is_filtered_as_a_plain_series(human):
    rng = np.random.default_rng(1)
    q = np.tile(human.q_rest, (50, 1))
    q[:, :3] += np.cumsum(rng.normal(0, 0.01, (50, 3)), axis=0)
    b, a = butter(2, 6.0 / (FPS / 2))
    assert np.allclose(smooth(human, q, FPS, 6.0)[:, :3], filtfilt(b, a, q[:, :3], axis=0), atol=1e-12)


def test_the_joint_limits_are_kept(human):
    limited = [j for j in human.joints if j.kind == "revolute" and np.isfinite(human.upper_limits[j.idx_q])]
    assert limited
    q = np.tile(human.q_rest, (40, 1))
    for j in limited:  # a joint driven against its upper limit: a filter's overshoot would cross it
        q[:, j.idx_q] = np.where(np.arange(40) % 10 < 5, human.upper_limits[j.idx_q], human.lower_limits[j.idx_q])
    out = smooth(human, q, FPS, 6.0)
    for j in limited:
        assert human.lower_limits[j.idx_q] <= out[:, j.idx_q].min() and out[:, j.idx_q].max() <= human.upper_limits[j.idx_q]


def test_a_closed_loop_stays_closed():
    robot = kms2pin.load(DIR / "fourbar.kms", root="spec")
    rng = np.random.default_rng(2)
    crank = next(j for j in robot.joints if j.kind == "revolute")
    q, x = [], robot.q_rest.copy()
    for a in np.linspace(0.8, 1.3, 40) + rng.normal(0, 0.03, 40):  # a noisy track of a turning crank
        x = x.copy()
        x[crank.idx_q] = a
        x = robot.project(x, hold=np.array([crank.idx_v]))  # from the frame before: one assembly mode
        q.append(x)
    out = smooth(robot, np.array(q), FPS, 6.0)
    assert max(np.abs(robot.closure_residual(x)).max() for x in out) < 1e-8
    assert np.abs(np.diff(out[:, crank.idx_q], 2)).mean() < np.abs(np.diff(np.array(q)[:, crank.idx_q], 2)).mean()


@pytest.mark.parametrize("cutoff", [0.0, -1.0, 15.0, 20.0, float("nan")])
def test_a_cutoff_outside_zero_to_nyquist_is_an_option_error(human, cutoff):
    with pytest.raises(kms2pin.OptionError, match="cutoff"):
        smooth(human, np.tile(human.q_rest, (5, 1)), FPS, cutoff)


def test_short_tracks_and_the_trajectory_method(human):
    one = np.tile(human.q_rest, (1, 1))
    assert np.array_equal(smooth(human, one, FPS, 6.0), one)
    q = np.tile(human.q_rest, (3, 1))
    q[:, 0] += [0.0, 0.01, 0.0]
    traj = Trajectory(human, q, scales=np.ones((len(human.bodies), 3)))
    out = traj.smoothed(FPS, 6.0)
    assert out.q.shape == q.shape and out.results == [] and np.array_equal(out.scales, traj.scales)
    assert np.isfinite(out.q).all()
